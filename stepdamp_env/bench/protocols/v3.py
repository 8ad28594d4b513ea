"""``stepdamp-bench v3``: suites that measure damping, scored in decibels from "no
damping" (0 dB) to "no torque ripple" (gap closed = 1). The default protocol
until 0.18.0 (now v4), frozen.

v1 and v2 stay frozen. v3 keeps v2's motors (the same draws, seed 7_733_052),
suites (open-loop, servo, mid-band), ramp, window, settling and identification,
and changes what a row means. The full specification, with the measurements
behind each choice, is ``docs/protocol_v3.md``; in short:

Reference rows
    Every suite has an unranked row ``reference``: policy ``none`` on the same
    motor, speeds, drive and sensors without the phenomenon the suite scores
    (:meth:`ProtocolV3.reference_motor`). Open loop and servo: the motor with
    Kd1 = Kd2 = Kd4 = 0 (no torque harmonics). Mid-band: the same motor (detent
    included) on the current-mode drive with ``reference_bus_factor`` = 4 times
    its bus voltage, so that its current loops never saturate: a stiff current
    source, the drive in which the voltage-fed instability (the current lagging
    the back-EMF-modulated winding) cannot arise.

Sensors
    Each drawn motor's encoder is drawn from ``encoder_choices`` (1000-line =
    4000 counts/rev to 17 bit = 131072), by a hash of the motor seed and its
    name; current noise 0.01 A as v1. A custom motor keeps its file's encoder
    (else 4000).

Speeds (per motor, from the motor's own plant; "headline" speeds are scored)
    A speed is a headline speed only where the phenomenon dominates: the
    reference ripples at most ``dominance`` = 0.5 times ``none`` there
    (policy ``none`` and the reference simulated once on the motor, noise seed
    the first evaluation seed: the "nominal sweep"); other speeds are labelled
    ``off-...`` and count only in ``full_sweep``. Open loop: v1's grid (the
    resonances f4, f2, f1 headline, the off-resonance speeds). Servo: the
    candidates ``servo_factors`` x f4 (0.2 to 1.6); the servo-controlled
    motor's resonance is where ``none`` ripples most (the velocity loop's
    disturbance response peaks there: measured on the presets, it peaks at
    0.4-1.1 x f4), so the ``servo_headline`` = 3 candidates with the largest
    ``none`` ripple that pass the dominance rule are its headline speeds.
    Mid-band: v2's rule, five speeds log-spaced through the predicted unstable
    band (its analysis on a 0.25 rev/s grid up to where the first band closes,
    edges bisected to 1e-4 rev/s).

Splits
    ``dev``: ``dev_per_preset`` = 4 fresh draws per preset from the training
    distribution (``numpy.random.default_rng(dev_motor_seed)``, named
    ``<preset>~d<k>``), for all tuning, ablations and model selection
    (``stepdamp leaderboard --split dev``); never in a scored board.
    ``interpolation``, ``extrapolation``, ``custom``: v1's.

Step loss
    In open loop a run is lost when the rotor ends a whole electrical cycle
    (2*pi/Nr rad, four full steps) away from its command: its final slip
    rounds to 1 or more (|slip| >= 0.5 cycles). In servo the drive commutates
    on the encoder angle and cannot slip whole cycles. In either mode a run
    the env ends (over-current, a non-finite state) is lost. A lag past a full
    step that the rotor recovers from is no loss: the env's lag limit is
    ``lag_limit_steps`` = 1e9 full steps (in effect none), and the run goes on
    to the end of its window.

Scores (per motor; every motor weighs the same)
    Per run: attenuation = 20 log10(ripple of ``none`` / ripple of the entry)
    (dB; 0 dB = no damping), bounded below at ``failure_db`` = -20 dB. A lost
    run (a step loss or termination) scores -20 dB, or 0 dB where ``none``
    lost the same run too (as bad as no damping, no worse). Where ``none`` lost
    a run the entry held, or ended before its window, ``none``'s ripple there
    is no measure of the resonance (a stalled rotor's error is its command
    speed). The mean headline ripple of ``none``'s runs on that motor that held
    stands in; a motor on which every ``none`` run was lost has no such cell.
    Per motor and training seed: the mean over the
    headline speeds and evaluation seeds; per motor: the mean over training
    seeds; the headline is the IQM over motors of ``attenuation_db``.
    ``gap_closed`` = attenuation(entry) / attenuation(reference) per motor (1:
    as good as removing the phenomenon). ``ratio``: 10^(-dB/20) of the
    motor's mean attenuation, the geometric mean of its runs' ripple over
    ``none``'s, bounded as the dB are. ``success_rate``: runs
    not lost. ``full_sweep``: the mean and the worst ratio over every speed of
    the suite (headline and off).

Statistics (per split and suite)
    Intervals: a two-level bootstrap (motors, then each motor's training seeds,
    with replacement; one stratum per split), 2000 resamples, seed 2000, the
    95 % percentile interval widened about the estimate by
    sqrt(n/(n-1)) t(n-1)/z for n motors (:func:`..stats.widening_factor`; a
    simulation in the tests shows at least 93 % coverage). Ranks: among the
    ranked rows, an entry's rank is 1 + the number of entries whose interval
    lies wholly above its own (overlapping intervals share a rank). For every
    pair: P(improvement) (per motor, Mann-Whitney over their training seeds'
    dB; the mean over motors) and ``effect_db``, the median over motors of the
    difference in dB, with its interval.

Eligibility (one rule for every entry)
    An entry runs in the suites its card lists. The ``reference`` row and
    privileged entries (``oracle`` cards: the true state or exact model) are
    shown unranked. A learned entry is ranked in a suite only if its card's
    ``trained_on`` covers the suite and every headline speed of the split's
    motors in it; otherwise its row is ``zero_shot`` and unranked.

``--quick`` (CI): v2's quick motors, one dev motor per preset, three servo
candidates (0.28, 0.56, 1.1 x f4, two headline), the resonances, two mid-band
speeds, a 0.1 s window, 500 resamples.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from .decibels import (ENCODER_CPRS, FAILURE_DB, SPLITS, DecibelProtocol, attenuation_db,
                       eligible, improvement_interval, ratio_of_db)
from .drawn import QUICK_SETTINGS

__all__ = ["ProtocolV3", "SPLITS", "ENCODER_CPRS", "FAILURE_DB", "full_protocol_v3",
           "quick_protocol_v3", "attenuation_db", "ratio_of_db", "eligible",
           "improvement_interval"]

#: The default entries of the published v3 board (0.17.0); later entries join v4.
PUBLISHED_ENTRIES_V3 = (
    "none", "patent-ff-oracle", "patent-ff-identified", "ff-delay-comp", "adaptive-ff",
    "velocity-feedback", "sensorless-damping", "calibrated-table", "repetitive-control",
    "tuned-constant-gain", "tuned-gain-pair", "oracle-floor", "privileged-bound",
    "ars-mid-band", "ars-open-loop", "ars-per-step", "ars-per-step-25hz", "ars-servo",
    "ppo-gain-selector", "ppo-mid-band", "ppo-open-loop", "ppo-open-loop-long",
    "ppo-per-step", "td3-per-step")


@dataclass(frozen=True)
class ProtocolV3(DecibelProtocol):
    """Every setting of ``stepdamp-bench v3`` (see the module docstring and
    docs/protocol_v3.md; :class:`.decibels.DecibelProtocol` holds them)."""

    version: str = "v3"

    published_entries: ClassVar[tuple[str, ...] | None] = PUBLISHED_ENTRIES_V3


def full_protocol_v3() -> ProtocolV3:
    """``stepdamp-bench v3``, the full protocol."""
    return ProtocolV3()


def quick_protocol_v3() -> ProtocolV3:
    """v3's CI variant (see the module docstring)."""
    return ProtocolV3(**{**QUICK_SETTINGS, "servo_factors": (0.28, 0.56, 1.1)},
                      servo_headline=2, midband_factors=(0.3, 0.7), dev_per_preset=1)


PROTOCOL = {"version": "v3", "full": full_protocol_v3, "quick": quick_protocol_v3,
            "about": "frozen; scored in dB with reference rows, a dev split for tuning",
            "quick_about": "v2's quick motors and one dev motor per preset, 0.1 s window"}
