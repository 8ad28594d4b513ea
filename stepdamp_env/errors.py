"""The error of every bad input: a one-line message naming the parameter and its
allowed range (the CLI prints it and exits with status 2)."""

from __future__ import annotations

from typing import Any

__all__ = ["ParameterError", "show_value"]


class ParameterError(ValueError):
    """A parameter is outside its allowed range or unknown."""


def show_value(value: Any) -> str:
    """A value for a one-line message (a 300-digit integer in short)."""
    text = repr(value)
    if len(text) <= 40:
        return text
    try:
        return f"{float(value):.6g}"
    except (OverflowError, TypeError, ValueError):
        return text[:37] + "..."
