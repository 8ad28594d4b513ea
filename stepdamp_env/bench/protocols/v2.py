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
from typing import Any, ClassVar

from ... import fixedmath as fm
from ...analysis import MIDBAND_SCAN_RPS, midband
from ...params import ParameterError, SystemParams
from ..protocol import ALL_SUITES
from .v1 import QUICK_SETTINGS, ProtocolV1

__all__ = ["ProtocolV2", "full_protocol_v2", "quick_protocol_v2", "midband_grid"]


@dataclass(frozen=True)
class ProtocolV2(ProtocolV1):
    """Every setting of ``stepdamp-bench v2``: v1 unchanged plus the ``mid-band``
    suite (the voltage-mode drive, docs/protocol_v2.md).

    ``midband_factors``: the suite's speeds, log-spaced through each motor's
    predicted unstable band [f_lo, f_hi] (:func:`stepdamp_env.analysis.midband`
    of the motor with ``drive_mode="voltage"``): f_lo*(f_hi/f_lo)**k for k in
    the factors. A motor without an unstable band uses
    [f_min/1.5, 1.5*f_min] around its least damped speed f_min.
    """

    version: str = "v2"
    suites: tuple[str, ...] = ALL_SUITES
    midband_factors: tuple[float, ...] = (0.1, 0.3, 0.5, 0.7, 0.9)

    def __post_init__(self) -> None:
        super().__post_init__()
        if not self.midband_factors or not all(0.0 <= f <= 1.0 for f in self.midband_factors):
            raise ParameterError(f"midband_factors={self.midband_factors!r}: each must be in "
                                 "[0, 1]")

    def to_dict(self) -> dict[str, Any]:
        out = super().to_dict()
        out["headline"] += ("; mid-band: the voltage-mode drive (drive_mode='voltage') at "
                            "speeds through its predicted unstable band, all headline")
        return out

    known_suites: ClassVar[tuple[str, ...]] = ALL_SUITES

    def suite_grids(self, system: SystemParams
                    ) -> tuple[tuple[str, tuple[float, ...], tuple[str, ...]], ...]:
        return super().suite_grids(system) + (("mid-band", *midband_grid(system, self)),)

    def settle_times(self, system: SystemParams) -> dict[str, float]:
        out = super().settle_times(system)
        out["mid-band"] = out["open-loop"]       # the open-loop rule, for the voltage drive
        return out


def full_protocol_v2() -> ProtocolV2:
    """``stepdamp-bench v2``, the full protocol."""
    return ProtocolV2()


def quick_protocol_v2() -> ProtocolV2:
    """v2's CI variant: v1's quick variant plus two mid-band speeds."""
    return ProtocolV2(**QUICK_SETTINGS, midband_factors=(0.3, 0.7))


PROTOCOL = {"version": "v2", "full": full_protocol_v2, "quick": quick_protocol_v2,
            "about": "frozen; v1 plus the voltage-mode drive's mid-band suite",
            "quick_about": "v1's quick variant plus two mid-band speeds"}


def midband_grid(system: SystemParams, protocol: ProtocolV2,
                 scan: tuple[float, float, float] = MIDBAND_SCAN_RPS,
                 first_band_only: bool = False
                 ) -> tuple[tuple[float, ...], tuple[str, ...]]:
    """v2's mid-band speeds (rev/s), labelled ``m<factor>``: log-spaced through the
    predicted unstable band of ``system`` in voltage mode (see :class:`ProtocolV2`),
    found on the speed grid ``scan`` (:func:`stepdamp_env.analysis.midband`)."""
    band = midband(system.replace(drive_mode="voltage"), scan, first_band_only)
    if band.unstable_rps is not None:
        lo, hi = band.unstable_rps
    else:
        lo, hi = band.at_rps / 1.5, band.at_rps * 1.5
    return (tuple(float(lo * fm.exp(f * fm.log(hi / lo))) for f in protocol.midband_factors),
            tuple(f"m{f:g}" for f in protocol.midband_factors))
