"""The registered ``stepdamp-bench`` versions, by name.

Each version is one module here (v0, v1, v2, v3) whose docstring is its
specification and whose ``PROTOCOL`` dict registers it: ``{"version": ...,
"full": factory, "quick": factory}``. ``--protocol`` offers what is registered;
:func:`protocol_for` builds one. Adding a version: docs/architecture.md,
"Adding a protocol".
"""

from __future__ import annotations

from typing import Any, Callable, Mapping

from ...params import ParameterError
from ..protocol import Protocol
from . import v0, v1, v2, v3

__all__ = ["register_protocol", "protocol_versions", "protocol_for", "protocol_class",
           "DEFAULT_VERSION"]

# What `stepdamp leaderboard` runs without --protocol.
DEFAULT_VERSION = "v3"

_REGISTRY: dict[str, dict[str, Callable[[], Protocol]]] = {}


def register_protocol(entry: Mapping[str, Any]) -> None:
    """Register a version: ``{"version": name, "full": factory, "quick": factory}``."""
    version = str(entry["version"])
    if version in _REGISTRY:
        raise ParameterError(f"protocol version {version!r} is registered twice")
    _REGISTRY[version] = {"full": entry["full"], "quick": entry["quick"]}


for _module in (v0, v1, v2, v3):
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
