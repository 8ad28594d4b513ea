"""A dataclass's fields as command-line options: declared once, with their help,
choices and allowed range in the field's metadata (in the manner of CleanRL's
``tyro`` arguments, without the dependency).

    @dataclass
    class Args:
        seed: int = option(1, "torch/numpy seed", low=0, high=999)

    add_arguments(parser, Args)            # --seed N
    args = from_namespace(Args, parser.parse_args())
    check_ranges(args)                     # one-line ParameterError naming --seed
"""

from __future__ import annotations

import argparse
import dataclasses
from typing import Any, Callable

from stepdamp_env.params import ParameterError

__all__ = ["option", "add_arguments", "from_namespace", "check_ranges"]


def option(default: Any, help: str, *, metavar: str | None = None,
           choices: tuple[Any, ...] | None = None, low: float | None = None,
           high: float | None = None, many: bool = False, negate: str | None = None,
           parse: Callable[[Any], Any] | None = None, flag: str | None = None,
           repeat: bool = False, default_factory: Callable[[], Any] | None = None) -> Any:
    """A field and its option. ``low``/``high``: an integer's allowed range (None
    allowed when the default is None); ``many``: several values (a tuple);
    ``negate``: a boolean set False by the flag ``--<negate>``; ``parse``: turns the
    command line's value into the field's; ``flag``: the option's name when it is
    not the field's; ``repeat``: the option may be given several times (a list
    for ``parse``)."""
    meta = {"help": help, "metavar": metavar, "choices": choices, "low": low, "high": high,
            "many": many, "negate": negate, "parse": parse, "flag": flag, "repeat": repeat}
    if default_factory is not None:
        return dataclasses.field(default_factory=default_factory, metadata=meta)
    return dataclasses.field(default=default, metadata=meta)


def _flag(f: dataclasses.Field) -> str:
    return f.metadata.get("flag") or "--" + f.name.replace("_", "-")


def add_arguments(p: argparse.ArgumentParser, cls: type) -> None:
    """One option per field of the dataclass ``cls``, its default shown in --help."""
    for f in dataclasses.fields(cls):
        m = f.metadata
        if "help" not in m:
            continue
        default = f.default if f.default is not dataclasses.MISSING else f.default_factory()
        if m["negate"]:
            p.add_argument("--" + m["negate"], dest=f.name, action="store_false",
                           default=argparse.SUPPRESS, help=m["help"])
            continue
        kwargs: dict[str, Any] = {"dest": f.name, "help": m["help"], "metavar": m["metavar"]}
        if m["repeat"]:
            kwargs.update(action="append", default=[])
        elif m["many"]:
            kwargs.update(nargs="+", default=list(default))
        else:
            kwargs["default"] = None if m["parse"] else default
        if m["choices"] is not None:
            kwargs["choices"] = m["choices"]
        if m["low"] is not None and not m["parse"] and not m["many"]:
            kwargs["type"] = int
        p.add_argument(_flag(f), **kwargs)


def from_namespace(cls: type, ns: argparse.Namespace) -> Any:
    """The dataclass from parsed options (``parse`` applied, lists as tuples)."""
    values = {}
    for f in dataclasses.fields(cls):
        if "help" not in f.metadata or not hasattr(ns, f.name):
            continue
        value = getattr(ns, f.name)
        m = f.metadata
        if m["parse"] is not None:
            if value is None or value == []:
                continue                    # the field's default
            value = m["parse"](value)
        elif m["many"]:
            value = tuple(value)
        values[f.name] = value
    return cls(**values)


def check_ranges(obj: Any) -> None:
    """Every integer field with a range inside it (each entry of a tuple), and
    every field with choices one of them (as the CLI checks, for objects built in
    code), else a one-line ``ParameterError`` that names the option and what it
    allows."""
    for f in dataclasses.fields(obj):
        choices, value = f.metadata.get("choices"), getattr(obj, f.name)
        if choices is not None and not (value is None and f.default is None) \
                and value not in choices:
            raise ParameterError(f"{_flag(f)} {value!r} is not one of {list(choices)}")
        low, high = f.metadata.get("low"), f.metadata.get("high")
        if low is None:
            continue
        value = getattr(obj, f.name)
        for v in (value if isinstance(value, tuple) else (value,)):
            if v is None and f.default is None:
                continue
            if isinstance(v, bool) or not isinstance(v, int) or not low <= v <= high:
                raise ParameterError(f"{_flag(f)} {v!r} is outside its allowed range "
                                     f"[{low:g}, {high:g}] (integer)")
