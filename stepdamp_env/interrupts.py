"""Ctrl-C that is never lost.

Python ignores an exception raised inside a weakref callback or a ``__del__``
method: it prints "Exception ignored in ..." and carries on. The import system
runs such a callback (``_get_module_lock``'s) while modules load, so a Ctrl-C
that lands there during the package's first seconds was swallowed and the
command ran on (CI saw a double Ctrl-C, coalesced into one, lost this way under
load). :func:`interrupts_kept` records every Ctrl-C of its block and raises
:class:`KeyboardInterrupt` at the block's end if none got out.
"""

from __future__ import annotations

import contextlib
import signal
import threading
from typing import Any, Iterator

__all__ = ["interrupts_kept"]


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
