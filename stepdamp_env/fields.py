"""Packed vectors declared once.

The kernel and the compiled env pass their data as flat float64 vectors (numba
loops over arrays, not objects). Each vector's layout is declared once, as an
ordered list of field names, each with what it holds and its SI unit:

    STATE = layout("State", '''
        THETA   shaft angle (rad)
        OMEGA   shaft speed (rad/s)
    ''')

A name ``NAME[n]`` declares n fields: ``NAME`` (described), then ``NAME_1`` ..
``NAME_{n-1}``, so that ``v[STATE.NAME + j]`` is entry j.
``STATE.OMEGA`` is the field's position (1), ``len(STATE)`` the vector's length,
``describe(STATE)`` the names with their descriptions. numba reads a
module-level layout as a constant, so ``s[STATE.OMEGA]`` compiles exactly as
``s[1]`` does. Enumerations (the codes a float field holds) are declared the
same way.
"""

from __future__ import annotations

import textwrap
from collections import namedtuple
from typing import Any

__all__ = ["layout", "describe", "slice_of"]


def layout(name: str, fields: str) -> Any:
    """The positions of a packed vector: ``fields`` holds one field a line, its
    name, then (optional) what it holds and its unit; a deeper-indented line
    continues the description above it. Returns a namedtuple instance whose
    attributes are the positions, in order from 0."""
    rows: list[list[str]] = []
    for line in textwrap.dedent(fields).strip("\n").splitlines():
        if not line.strip():
            continue
        if line[0].isspace():
            if not rows:
                raise ValueError(f"layout {name}: a continuation line before any field")
            rows[-1][1] = (rows[-1][1] + " " + line.strip()).strip()
            continue
        parts = line.split(None, 1)
        field, text = parts[0], parts[1].strip() if len(parts) > 1 else ""
        base, bracket, count = field.partition("[")
        if not bracket:
            rows.append([field, text])
            continue
        if not (count.endswith("]") and count[:-1].isdigit() and int(count[:-1]) >= 1):
            raise ValueError(f"layout {name}: {field!r} is not NAME[n] with n >= 1")
        rows.append([base, text])
        rows.extend([f"{base}_{j}", ""] for j in range(1, int(count[:-1])))
    names = [r[0] for r in rows]
    if len(set(names)) != len(names):
        raise ValueError(f"layout {name}: a field name repeats")
    cls = namedtuple(name, names)
    cls.__doc__ = f"Positions in the {name} vector (see stepdamp_env.fields)."
    for field_name, text in rows:
        getattr(cls, field_name).__doc__ = text
    return cls(*range(len(names)))


def describe(fields: Any) -> dict[str, str]:
    """Field name -> its description (with the unit), in order."""
    cls = type(fields)
    return {name: getattr(cls, name).__doc__ or "" for name in cls._fields}


def slice_of(fields: Any, first: str, last: str) -> slice:
    """The positions ``first`` .. ``last`` (both included) as a slice."""
    return slice(getattr(fields, first), getattr(fields, last) + 1)
