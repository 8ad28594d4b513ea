"""``stepdamp-bench v4``: verdicts that decide, on real catalogue motors too.

v0-v3 stay frozen. v4 keeps v3's drawn motors, suites, speeds, reference rows,
sensors, windows and scores in dB, and changes who is ranked, how, on which
cells and seeds. The specification with the measurements behind each rule is
``docs/protocol_v4.md``; in short:

Splits
    v3's ``interpolation`` and ``extrapolation`` draws, and ``catalogue``:
    real motors from public datasheets (``catalogue.json`` beside this package
    module; the source of every value in each motor's ``source`` and
    ``notes``; where a source gives no rotor inertia it is estimated from the
    holding torque by a fit stated in docs/motors.md). A catalogue motor is
    the drive's own model (its nominal = its plant) and keeps the file's
    encoder (else 4000 counts/rev). ``dev`` as v3 (never scored by default).

Evaluation seeds
    ``eval_seeds`` = three noise seeds from 1,000,000 (``--eval-seeds N`` sets
    how many). A motor's score is its mean over speeds, seeds and training
    seeds, as v3's.

Runs (a held run never scores below a lost run of the same cell)
    Where ``none`` held the run: attenuation in dB against its ripple,
    bounded below at ``failure_db`` = -20 dB; a lost run scores -20 dB.
    Where ``none`` lost it (or ended before its window): a lost run scores
    0 dB (as bad as no damping), a held one its attenuation against the mean
    ripple of ``none``'s held headline runs on that motor and seed, bounded
    below at 0 dB (holding where ``none`` did not is never worse than no
    damping); no such runs: the cell has no score.

Eligibility, per cell
    A cell is (motor, headline speed, its label: the moves suite has two
    cells, a trapezoid and an S-curve, at each speed). A learned entry's coverage is the
    share of the split's cells whose speed its card's ``trained_on`` covers
    for the suite; it is ranked where coverage >= ``coverage_min`` = 0.9,
    else its row is ``zero_shot``. Every row of a table is scored on the
    table's common cells: those every ranked learned row covers (all cells if
    none is). ``coverage`` and ``cells`` are columns.

Ranks (paired)
    Among ranked rows: J beats K when, on their common motors (>= 3), the IQM
    of the per-motor difference in dB is above 0 and either its 95 % lower
    bound is above 0 or J scores higher on >= 95 % of the motors, or the
    board's P(J improves on K) is >= 0.95 (:func:`..stats.paired_ranks`);
    rank = 1 + the number of rows that beat it, made monotone in the
    headline (no inversion). Ranks are also computed per evaluation seed
    (the same rule without P, which the board gives over all seeds):
    ``rank_stability`` says whether the rank-1 rows keep rank 1 on every
    seed and how far ranks move.

Tables (``tables`` of the board, per suite and split)
    ``headroom_db``: the bound's IQM minus the best ranked row's
    (``bound_entry`` = ``plant-bound``, which supersedes v3's
    ``privileged-bound``: that one leaves v4's default entries,
    ``retired_entries``); ``bound_check``: the share of
    motors on which the bound scores at least every non-privileged row, and
    where it does not; ``saturated`` (with ``saturated_why``): where the bound
    holds on >= ``bound_share_min`` = 95 % of the motors, less than
    ``saturation_db`` = 3 dB of headroom or a best row the paired rule cannot
    tell from the bound; None where the bound does not hold (no headroom to
    measure); ``told_apart``: whether the paired rule tells the best row from
    the reference and from the bound.

The moves suite (v4 on; :mod:`..moves`)
    Point-to-point moves on the open-loop current drive: per motor a
    trapezoid and an S-curve (half-cosine ramps) cruising at each of the two
    fastest open-loop headline speeds, so that the ramps pass the lower
    resonances. Acceleration (peak for the S-curve) ``move_accel_rps2`` = 100
    and ``move_s_curve_accel_rps2`` = 200 rev/s^2 (4,000 and 8,000 mm/s^2 on a
    40 mm/rev belt pulley), at most ``move_torque_share`` = 0.3 of the holding
    torque over the inertia. Scored: the velocity ripple over the cruise
    (``window_s`` rounded up to whole detent periods, from the end of the
    first ramp); the position column the RMS position error about the command
    over the whole move and its settling (``run_position_error_steps``; the
    open-loop settling after the stop); step loss by the final slip.
    Entries tuned per suite use their open-loop settings (``Suite.tuning``).

``--quick`` (CI): v3's quick motors, three catalogue motors, two evaluation
seeds, 500 resamples.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from .paired import (CATALOGUE_PATH, QUICK_CATALOGUE, SPLITS, PairedProtocol, catalogue_systems,
                     coverage, evaluation_seeds, quick_settings)

__all__ = ["ProtocolV4", "PUBLISHED_ENTRIES_V4", "SPLITS", "CATALOGUE_PATH", "QUICK_CATALOGUE",
           "full_protocol_v4", "quick_protocol_v4", "coverage", "evaluation_seeds",
           "catalogue_systems"]

#: The default entries of the published v4 board (0.18.0); a later entry (the
#: agents trained for moves, 0.19.0) runs on v4 with ``--entries``/``--policy``
#: and joins the defaults of the next version. Written out rather than derived
#: from v3's list: a version reads no other version's settings.
PUBLISHED_ENTRIES_V4 = (
    "none", "patent-ff-oracle", "patent-ff-identified", "ff-delay-comp", "adaptive-ff",
    "velocity-feedback", "sensorless-damping", "calibrated-table", "repetitive-control",
    "tuned-constant-gain", "tuned-gain-pair", "oracle-floor", "plant-bound",
    "ars-mid-band", "ars-open-loop", "ars-per-step", "ars-per-step-25hz", "ars-servo",
    "ppo-gain-selector", "ppo-mid-band", "ppo-open-loop", "ppo-open-loop-long",
    "ppo-per-step", "td3-per-step")


@dataclass(frozen=True)
class ProtocolV4(PairedProtocol):
    """Every setting of ``stepdamp-bench v4`` (module docstring, docs/protocol_v4.md)."""

    version: str = "v4"

    published_entries: ClassVar[tuple[str, ...] | None] = PUBLISHED_ENTRIES_V4


def full_protocol_v4() -> ProtocolV4:
    """``stepdamp-bench v4``, the full protocol."""
    return ProtocolV4()


def quick_protocol_v4() -> ProtocolV4:
    """v4's CI variant (module docstring)."""
    return ProtocolV4(**quick_settings())


PROTOCOL = {"version": "v4", "full": full_protocol_v4, "quick": quick_protocol_v4,
            "about": "paired ranks, three evaluation seeds, per-cell eligibility, a catalogue "
                     "split of real motors, a moves suite",
            "quick_about": "v3's quick motors, three catalogue motors, two evaluation seeds"}
