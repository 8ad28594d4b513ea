"""The ``stepdamp-bench v1`` protocol: its specification and settings.

Protocol ``stepdamp-bench`` version ``v1`` (frozen: any change of a value below,
of the motor draws, the speed grids, the settling, the scoring or the
statistics makes it a new version; v0 stays in :mod:`.v0`)
=============================================================================

Training distribution (what agents and tuning may use)
    Around each of the four presets ``patent``, ``qsh4218-51-10-049``,
    ``qsh5718-56-28-126``, ``qsh6018-65-28-210``: R, L scaled by U(0.8, 1.25),
    Km by U(0.85, 1.15), J by U(0.5, 2.0), Kd1, Kd2, Kd4 and Fs by
    U(0.5, 1.5); phases phi1, phi2 drawn U(-pi, pi) rad; everything else the
    preset's (Nr = 50, no load torque, the preset's bus voltage), with the
    protocol's sensors. This is the env's ``randomize=True`` (its
    ``DEFAULT_RANDOMIZATION``, copied here so that v1 does not follow it).
    Training uses seeds below ``TRAINING_SEED_LIMIT`` = 1_000_000 and never
    the motors below.

Splits (in the manner of CARL: a context distribution to train on, test sets
inside and outside it)
    ``interpolation``: ``interpolation_per_preset`` = 4 fresh draws around each
    preset from the training distribution (16 motors, named
    ``<preset>~i<k>``), from ``numpy.random.default_rng(motor_seed)``, preset
    by preset, each field in the order R, L, Km, J, Kd1, Kd2, Kd4, Fs, phi1,
    phi2. The presets themselves are not in it (agents train on them).
    ``extrapolation``: for each shift below and each preset (20 motors, named
    ``<preset>~x-<shift>``), a draw from the training distribution (the same
    generator, continuing after the interpolation draws) with the shift
    applied on top; every one lies outside the training distribution:

    ============  ==========================================  ==============
    shift         change                                      drive knows it
    ============  ==========================================  ==============
    inertia       J = the preset's x U(2.5, 4.0)              no
                  (training: x 0.5-2.0)
    detent        Kd1, Kd2, Kd4 each the preset's x           no
                  U(1.6, 2.2) (training: x 0.5-1.5)
    0.9-degree    Nr = 100 (training: 50)                     yes
    low-bus       bus voltage Vdc = the preset's / 2          yes
    load-torque   a constant load torque of U(0.1, 0.25) x    no
                  the holding torque Km*holding_current
                  (training: none)
    ============  ==========================================  ==============

    ``custom`` (``stepdamp leaderboard --motors FILE.json``): the user's motors
    (:func:`load_motors_file`), nominal = the file's values.

    No motor is filtered on how the undamped drive does. A draw is excluded
    only by this physics rule, stated up front: the holding torque
    Km*holding_current must be at least ``holding_margin`` = 3 times the sum
    of the peak detent (Kd1 + Kd2 + Kd4), the friction Fs and the load torque
    (a motor that cannot hold its own detent and load is not a stepper drive);
    or by ``SystemParams`` validation. An excluded draw is redrawn from the
    same stream (at most 100 attempts), so the set is the same on every
    machine. A run that loses steps or terminates is scored as lost (below).

Nominal model (``MotorKnowledge.nominal``)
    Interpolation: the preset. Extrapolation: the preset with the shifts the
    drive knows (Nr, Vdc: set on the drive like any motor's datasheet); the
    hidden ones (inertia, detent, load) are found only by identification.
    Custom: the file's values. ``identified`` as in v0 (the patent's
    iteration in servo at 0.1 and 0.2 rev/s, noise seed = the evaluation
    seed); where that run loses steps (a heavy load torque can), the drive
    falls back to its nominal model, as a drive whose commissioning fails
    would, and the board's ``identification`` record says so. ``exact``, the
    options a policy may set (``POLICY_OPTIONS``) and the oracle flag are as
    in v0.

Sensors
    Current-sensor noise 0.01 A per sample, encoder 4000 counts/rev (a custom
    motor file may set its own ``current_noise_a`` / ``encoder_cpr``).

Suites and speeds
    ``open-loop`` (eqs. 7-8): as v0, the three predicted resonant speeds f4,
    f2, f1 and the off-resonance speeds 0.6*f4, sqrt(2)*f4, sqrt(2)*f2, 1.3*f1.
    ``servo`` (eqs. 14-15): the low-speed grid ``servo_factors`` x f4 =
    (0.1, 0.18, 0.3, 0.5) x f4, f4 the motor's lowest predicted open-loop
    resonance, log-spaced. How it is derived: the undamped servo has no peak
    at the open-loop resonances; its RMS ripple relative to the command speed
    falls monotonically with speed on every preset (measured, noise seed 0, at
    0.1, 0.18, 0.3, 0.5, 1 and 2 x f4: patent 93, 68, 52, 34, 12, 3 %;
    qsh4218 89, 70, 53, 39, 17, 5 %; qsh5718 49, 29, 22, 16, 9, 3 %; qsh6018
    51, 26, 19, 13, 8, 2 %). The grid spans the speeds below the first
    resonance where it exceeds 10 % on every preset (0.1 to 0.5 x f4; at f4
    two of the four are under it). It
    stops at 0.1 x f4, where the measuring window (rounded up to a whole
    first-harmonic period 1/(Nr*v)) stays under 0.6 s on the presets. Every
    servo speed is a headline speed.

Runs
    As v0 (ramp 50 rev/s^2, ``StepperDampEnv`` with the policy's options,
    reset with the evaluation seed, stepped to the end of the window), but
    the window opens after each motor's own settling, with no upper clip:
    open loop four decay times of its undamped resonance, 4/(zeta*wn) =
    8*J/D; servo ten time constants of the servo loop's slowest pole (the
    roots of J*s^3 + Kp_vel*s^2 + Kp_pos*s + Ki_pos with the motor's servo
    gains; 0.08 s with the default gains, a triple pole at ws); both at least
    0.1 s. Measured on the full v1 motors: the undamped ripple in the window
    is within 5 % of that in windows 0.5-2 s later in 99 % of the open-loop
    runs (the outlier, a parametric h2 case, varies 4 % between later
    windows); servo within 5 %. Measuring window 0.3 s rounded up to whole
    periods of the first detent harmonic. The servo gains follow each plant's
    own J (``SystemParams.servo_gains``), as in the training distribution:
    the hidden inertia shift reaches the drive's servo tuning, not its
    feedforward or damping laws.

Seeds
    One evaluation seed per motor, 1_000_000 (motors carry the variance:
    motor-to-motor SD 0.0116 against 0.0009 between sensor-noise seeds on v0;
    more motors, fewer seeds). Learned entries run every training seed they
    pool; ``MIN_TRAINING_SEEDS`` = 5 is what a claim needs (the reference agent
    has 5; the report marks learned entries with fewer).

Scores (per cell: motor x evaluation seed x training seed)
    ``headline``: mean RMS velocity ripple over the suite's headline speeds
    (open loop: the three resonances; servo: the whole grid) over the mean of
    the undamped one (policy ``none``, same motor and seed). A run that loses
    steps or terminates counts with ``FAILURE_RATIO`` = 10 times the undamped
    ripple (its own if larger); ``none`` itself is scored so. The undamped
    reference is taken as measured, step losses included; where it ended
    before its window opened, the mean of its measured headline ripples on
    that motor and suite stands in, so every run of every entry is scored. ``sweep_mean_ratio``,
    ``sweep_worst_ratio``, ``rms_injected_current_a`` as v0.

Statistics (per split and suite)
    Headline: the IQM over all cells, with a 95 % percentile interval from a
    two-level stratified bootstrap (:func:`.stats.two_level_bootstrap`):
    2000 resamples, ``numpy.random.default_rng(2000)``; level 1 draws motors
    with replacement within their stratum (interpolation: the preset a motor
    was drawn around; extrapolation: its shift; custom: one stratum), level 2
    draws each drawn motor's cells with replacement. For every pair of
    entries: the probability of improvement P(X < Y) (per motor, every pair of
    their cells, ties half; the mean over motors) with its two-level interval
    (:func:`.stats.probability_of_improvement`). A performance profile (the
    fraction of cells at or below each score) per split and suite.

``--quick`` (variant ``quick``, for CI): one interpolation draw per preset and
one extrapolation motor per preset (the shifts in turn: patent inertia,
qsh4218 0.9-degree, qsh5718 load-torque, qsh6018 low-bus), the resonant speeds
and two servo speeds (0.1, 0.3 x f4), a 0.1 s window, 500 resamples. Its
numbers are not comparable with the full protocol's.
"""

from __future__ import annotations

from dataclasses import dataclass

from .drawn import (MIN_TRAINING_SEEDS, QUICK_SETTINGS, SHIFTS, SPLITS, DrawnProtocol, Shift,
                    in_training_distribution, load_motors_file, servo_grid)

__all__ = ["ProtocolV1", "SPLITS", "MIN_TRAINING_SEEDS", "Shift", "SHIFTS", "full_protocol_v1",
           "quick_protocol_v1", "QUICK_SETTINGS", "servo_grid", "in_training_distribution",
           "load_motors_file"]


@dataclass(frozen=True)
class ProtocolV1(DrawnProtocol):
    """Every setting of ``stepdamp-bench v1`` (see the module docstring;
    :class:`.drawn.DrawnProtocol` holds them, its motors and v1's scoring).

    Use :func:`full_protocol_v1` or :func:`quick_protocol_v1`; other values are
    for tests and make results that are not v1's.
    """

    version: str = "v1"


def full_protocol_v1() -> ProtocolV1:
    """``stepdamp-bench v1``, the full protocol."""
    return ProtocolV1()


def quick_protocol_v1() -> ProtocolV1:
    """The reduced CI variant (see the module docstring)."""
    return ProtocolV1(**QUICK_SETTINGS)


PROTOCOL = {"version": "v1", "full": full_protocol_v1, "quick": quick_protocol_v1,
            "about": "frozen; interpolation and extrapolation splits",
            "quick_about": "8 motors, resonant speeds, two servo speeds, 0.1 s window"}
