"""``stepdamp-bench v2``: v1 unchanged, plus the ``mid-band`` suite (frozen).

The mid-band suite runs the voltage-mode drive (``drive_mode="voltage"``, the
winding-model voltages of a drive without current loops) at speeds through
each motor's predicted unstable band (:func:`stepdamp_env.analysis.midband`),
all of them headline speeds; its settling is v1's open-loop rule. Everything
else (motors, splits, the other suites, scoring, statistics) is v1's
(:mod:`.v1`); the full specification is ``docs/protocol_v2.md``.
"""

from __future__ import annotations

from dataclasses import dataclass

from .drawn import QUICK_SETTINGS, MidBandProtocol, midband_grid

__all__ = ["ProtocolV2", "full_protocol_v2", "quick_protocol_v2", "midband_grid"]


@dataclass(frozen=True)
class ProtocolV2(MidBandProtocol):
    """Every setting of ``stepdamp-bench v2``: v1 unchanged plus the ``mid-band``
    suite (the voltage-mode drive, docs/protocol_v2.md;
    :class:`.drawn.MidBandProtocol` has its settings).
    """

    version: str = "v2"


def full_protocol_v2() -> ProtocolV2:
    """``stepdamp-bench v2``, the full protocol."""
    return ProtocolV2()


def quick_protocol_v2() -> ProtocolV2:
    """v2's CI variant: v1's quick variant plus two mid-band speeds."""
    return ProtocolV2(**QUICK_SETTINGS, midband_factors=(0.3, 0.7))


PROTOCOL = {"version": "v2", "full": full_protocol_v2, "quick": quick_protocol_v2,
            "about": "frozen; v1 plus the voltage-mode drive's mid-band suite",
            "quick_about": "v1's quick variant plus two mid-band speeds"}
