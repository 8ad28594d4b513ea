"""Ctrl-C that is never lost.

Python ignores an exception raised inside a weakref callback or a ``__del__``
method: it prints "Exception ignored in ..." and carries on. The import system
runs such a callback (``_get_module_lock``'s) while modules load, so a Ctrl-C
that lands there during the package's first seconds was swallowed and the
command ran on (CI saw a double Ctrl-C, coalesced into one, lost this way under
load). :func:`interrupts_kept` records every Ctrl-C of its block and raises
:class:`KeyboardInterrupt` at the block's end if none got out.

``os.fork`` runs such callbacks too (logging's lock is released in one): a
Ctrl-C that landed while a process pool forked its workers was swallowed and
the command ran on (CI, once). :func:`signals_deferred` only records Ctrl-C
and SIGTERM over a block and acts on them after it.
"""

from __future__ import annotations

import contextlib
import os
import signal
import threading
from typing import Any, Iterator

__all__ = ["interrupts_kept", "signals_deferred"]


@contextlib.contextmanager
def interrupts_kept() -> Iterator[None]:
    """Run the block with Ctrl-C recorded as well as raised; raise
    :class:`KeyboardInterrupt` at its end if one was swallowed inside it. Does
    nothing outside the main thread or under a Ctrl-C handler other than
    Python's default (the caller's handler stays in charge)."""
    if (threading.current_thread() is not threading.main_thread()
            or signal.getsignal(signal.SIGINT) is not signal.default_int_handler):
        yield
        return
    pressed: list[int] = []

    def record(signum: int, frame: Any) -> None:
        pressed.append(signum)
        raise KeyboardInterrupt

    try:
        signal.signal(signal.SIGINT, record)
    except ValueError:                  # signals are not this interpreter's
        yield
        return
    try:
        yield
    finally:
        if signal.getsignal(signal.SIGINT) is record:   # a handler set inside stays
            signal.signal(signal.SIGINT, signal.default_int_handler)
    if pressed:                         # only reached when no KeyboardInterrupt got out
        raise KeyboardInterrupt


@contextlib.contextmanager
def signals_deferred(signums: tuple[int, ...] = (signal.SIGINT, signal.SIGTERM)
                     ) -> Iterator[None]:
    """Run the block with these signals only recorded (a handler that raises could
    run inside code whose exceptions Python ignores, such as fork's callbacks);
    after it, hand each recorded signal, once, to the handler that was in place
    (those whose default action ends the process first), also when the block
    raises. Does nothing outside the main thread."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    pressed: list[int] = []

    def record(signum: int, frame: Any) -> None:
        if signum not in pressed:
            pressed.append(signum)

    previous: dict[int, Any] = {}
    try:
        for signum in signums:
            previous[signum] = signal.signal(signum, record)
    except ValueError:                  # signals are not this interpreter's
        for signum, handler in previous.items():
            signal.signal(signum, handler)
        yield
        return
    try:
        yield
    finally:
        for signum, handler in previous.items():
            # None: a handler installed from C, which Python cannot put back.
            signal.signal(signum, signal.SIG_DFL if handler is None else handler)
        for signum in sorted(pressed, key=lambda n: previous[n] != signal.SIG_DFL):
            handler = previous[signum]
            if handler in (signal.SIG_DFL, None):
                os.kill(os.getpid(), signum)
            elif callable(handler):
                handler(signum, None)
