"""The registered ``stepdamp-bench`` versions, by name.

Each version is one module here (v0 to v5) whose docstring is its
specification and whose ``PROTOCOL`` dict registers it: ``{"version": ...,
"full": factory, "quick": factory, "about": text, "quick_about": text}`` (the
texts are the command line's help). ``--protocol`` offers what is registered;
:func:`protocol_for` builds one. Adding a version: docs/architecture.md,
"Adding a protocol".
"""

from __future__ import annotations

from typing import Any, Mapping

from ...params import ParameterError
from ..protocol import Protocol
from . import v0, v1, v2, v3, v4, v5

__all__ = ["register_protocol", "protocol_versions", "protocol_for", "protocol_class",
           "protocol_about", "known_suites", "DEFAULT_VERSION"]

# What `stepdamp leaderboard` runs without --protocol.
DEFAULT_VERSION = "v5"

_REGISTRY: dict[str, dict[str, Any]] = {}


def register_protocol(entry: Mapping[str, Any]) -> None:
    """Register a version: ``{"version": name, "full": factory, "quick": factory,
    "about": text, "quick_about": text}``."""
    version = str(entry["version"])
    if version in _REGISTRY:
        raise ParameterError(f"protocol version {version!r} is registered twice")
    _REGISTRY[version] = {key: entry[key] for key in ("full", "quick", "about", "quick_about")}


for _module in (v0, v1, v2, v3, v4, v5):
    register_protocol(_module.PROTOCOL)


def protocol_versions() -> tuple[str, ...]:
    """The registered versions, in registration order."""
    return tuple(_REGISTRY)


def protocol_for(version: str, quick: bool = False) -> Protocol:
    """The protocol of ``--protocol VERSION`` (``--quick``: its CI variant)."""
    if version not in _REGISTRY:
        raise ParameterError(f"--protocol {version!r}: allowed {list(_REGISTRY)}")
    return _REGISTRY[version]["quick" if quick else "full"]()


def protocol_class(version: str) -> type[Protocol]:
    """The class of a registered version (what a board's record is read with)."""
    return type(protocol_for(version))


def protocol_about(version: str, quick: bool = False) -> str:
    """A registered version in a few words (or its ``--quick`` variant's)."""
    return str(_REGISTRY[version]["quick_about" if quick else "about"])


def known_suites() -> tuple[str, ...]:
    """Every suite some registered version scores, in registration order."""
    return tuple(dict.fromkeys(s for v in _REGISTRY for s in protocol_class(v).known_suites))
