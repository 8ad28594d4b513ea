"""``stepdamp-bench v0``: its specification and settings (frozen).

Protocol ``stepdamp-bench`` version ``v0`` (frozen: any change of a value below,
of the motor draw, the speed grid, the scoring or the statistics makes it v1)
=============================================================================

Suites
    ``open-loop`` (eqs. 7-8, microstepping at the holding current) and ``servo``
    (eqs. 14-15, encoder feedback). Every policy runs both (``--suite`` picks one).

Motors
    The four presets ``patent``, ``qsh4218-51-10-049``, ``qsh5718-56-28-126``,
    ``qsh6018-65-28-210`` plus three randomised motors drawn around each preset
    (16 motors). The draws come from one ``numpy.random.default_rng(7733051)``
    stream, preset by preset in that order, each field in the order R, L, Km, J,
    Kd1, Kd2, Kd4, Fs, phi1, phi2: magnitudes scaled by U(low, high) factors
    (R, L: 0.8-1.25; Km: 0.85-1.15; J: 0.5-2.0; Kd1, Kd2, Kd4, Fs: 0.5-1.5, the
    env's ``DEFAULT_RANDOMIZATION``, copied here so that v0 does not follow it),
    phases phi1, phi2 drawn U(-pi, pi) rad, validated by ``SystemParams``. A draw
    is usable only if the undamped drive (no feedforward, noise seed 0) keeps its
    position lag below half a full step at every speed of its grid in both
    suites; unusable draws are rejected and the stream moves on (at most 100
    attempts per motor), so the set is the same on every machine. Every motor,
    preset or drawn, carries the protocol's sensors: current-sensor noise
    ``current_noise_a`` = 0.01 A (standard deviation per sample) and an encoder
    of ``encoder_cpr`` = 4000 counts/rev. The drawn motors are named
    ``<preset>~r<k>``. Training must never use these motors (nor the protocol
    seed 7733051 to draw motors).

Speeds
    Per motor: its three predicted resonant speeds f4, f2, f1
    (``predicted_resonances``) and four off-resonance speeds 0.6*f4,
    sqrt(2)*f4, sqrt(2)*f2 and 1.3*f1 (between 0.6x the lowest and 1.3x the
    highest resonance, halfway between resonances on a log scale).

Runs
    Each run: ``StepperDampEnv(motor=<true motor>, mode=<suite>, speed_rps=v,
    accel_rps2=50, measure_from_s=<window start>, **policy options)`` reset
    with the evaluation seed (which also seeds the current-sensor noise), the
    policy reset with its :class:`~stepdamp_env.bench.policy.PolicyContext`, stepped with
    ``policy.act(obs)`` until the agent step in which the simulated time
    reaches the end of the measuring window, or until the env terminates (step
    loss, over-current); then ``env.run_metrics()``.
    Ramp 50 rev/s^2; settling: the simulation core's default
    (``simulation.measuring_window``: four decay times 1/(zeta*wn), clipped to
    [0.1, 0.6] s, after the ramp); measuring window 0.3 s rounded up to whole
    periods of the first detent harmonic. Per run the core's metrics
    (``RunMetrics.to_dict()``) are kept.

Seeds
    Evaluation seeds 1_000_000 + k, k = 0..4. Training must use seeds below
    1_000_000 (``TRAINING_SEED_LIMIT``).

Knowledge
    ``MotorKnowledge.nominal``: the preset the motor was drawn around (with the
    protocol's sensors); ``identified``: ``identify(true motor,
    method="iterative", noise_seed=<eval seed>).model``, once per (motor,
    seed) and shared by all policies; ``exact``: the plant's own model (oracle
    baselines only; entries that use it are flagged ``oracle``). The env option
    ``estimate="nominal"`` is resolved against the nominal preset, never the
    true motor, and unset action scales (``harmonic_scale_nm``,
    ``current_scale_a``) come from the nominal motor as in training with
    ``randomize=True``. A policy may set only ``POLICY_OPTIONS``; everything
    that defines the plant, the operating point or what is observed is fixed.

Scores (per motor and seed)
    ``headline``: the mean RMS velocity ripple (``rms_velocity_error_rad_s``)
    at the three resonant speeds divided by the mean of the undamped one
    (policy ``none``, same motor, seed and speeds); lower is better, ``none``
    scores 1. ``sweep_mean_ratio``: the mean over the whole speed grid of the
    per-speed ratio to ``none``; ``sweep_worst_ratio``: its maximum.
    ``rms_injected_current_a``: the mean over the grid of the RMS injected q
    current. A run that loses steps or is terminated counts with a ripple of
    ``FAILURE_RATIO`` = 10 times the undamped one (its own if larger); the
    step losses are also counted beside the score.

Aggregates (over motors and seeds)
    Interquartile mean (IQM: the mean of the middle 50 % of the per-(motor,
    seed) scores, fractional weights at the quartiles) with a 95 % percentile
    interval from a stratified bootstrap: 2000 resamples, strata = motors
    (each motor's seeds are resampled with replacement within it), generator
    ``numpy.random.default_rng(2000)``. The raw per-run numbers are kept.

``--quick`` (variant ``quick``, for CI): the four presets only, one seed
(1_000_000), the resonant speeds only, a 0.1 s measuring window. Its numbers
are not comparable with the full protocol's.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any, Mapping, Sequence

import numpy as np

from ...params import RESONANCE_HARMONICS, ParameterError, SystemParams
from ...presets import get_preset
from ...simulation import RunSettings, SpeedProfile, simulate
from ..motors import ProtocolMotor, draw_around, speed_grid, with_sensors
from ..protocol import (FAILURE_RATIO, POLICY_OPTIONS, PROTOCOL_NAME, REFERENCE_POLICY, SUITES,
                        TRAINING_SEED_LIMIT, Protocol, rank)
from ..scoring import make_entry, reference_index

__all__ = ["ProtocolV0", "full_protocol", "quick_protocol"]

# v0's randomisation ranges: a frozen copy of the env's DEFAULT_RANDOMIZATION.
_V0_RANDOMIZATION: tuple[tuple[str, float, float], ...] = (
    ("R", 0.8, 1.25), ("L", 0.8, 1.25), ("Km", 0.85, 1.15), ("J", 0.5, 2.0),
    ("Kd1", 0.5, 1.5), ("Kd2", 0.5, 1.5), ("Kd4", 0.5, 1.5), ("Fs", 0.5, 1.5),
    ("phi1", -math.pi, math.pi), ("phi2", -math.pi, math.pi),
)
_V0_PRESETS = ("patent", "qsh4218-51-10-049", "qsh5718-56-28-126", "qsh6018-65-28-210")
# Off-resonance speeds: (harmonic whose resonance anchors it, factor).
_V0_OFF_RESONANCE = ((4, 0.6), (4, math.sqrt(2.0)), (2, math.sqrt(2.0)), (1, 1.3))


@dataclass(frozen=True)
class ProtocolV0(Protocol):
    """Every setting of ``stepdamp-bench v0`` (see the module docstring).

    Use :func:`full_protocol` or :func:`quick_protocol`; other values are for
    tests and make results that are not v0's.
    """

    name: str = PROTOCOL_NAME
    version: str = "v0"
    variant: str = "full"
    suites: tuple[str, ...] = SUITES
    presets: tuple[str, ...] = _V0_PRESETS
    randomized_per_preset: int = 3
    motor_seed: int = 7733051
    randomization: tuple[tuple[str, float, float], ...] = _V0_RANDOMIZATION
    max_draw_attempts: int = 100
    usable_max_lag_steps: float = 0.5
    validation_noise_seed: int = 0
    eval_seeds: tuple[int, ...] = tuple(TRAINING_SEED_LIMIT + k for k in range(5))
    resonance_harmonics: tuple[int, ...] = RESONANCE_HARMONICS
    off_resonance: tuple[tuple[int, float], ...] = _V0_OFF_RESONANCE
    accel_rps2: float = 50.0          # frozen: not the core's default, which may change
    window_s: float = 0.3
    settle: str = "core default: simulation.default_settle_s (4/(zeta*wn) in [0.1, 0.6] s)"
    current_noise_a: float = 0.01
    encoder_cpr: int = 4000
    identification_method: str = "iterative"
    failure_ratio: float = FAILURE_RATIO
    bootstrap_resamples: int = 2000
    bootstrap_seed: int = 2000
    confidence: float = 0.95

    def __post_init__(self) -> None:
        self.check_suites_and_seeds()
        if not (isinstance(self.randomized_per_preset, int) and self.randomized_per_preset >= 0):
            raise ParameterError(f"randomized_per_preset={self.randomized_per_preset!r} is "
                                 "outside its allowed range [0, inf) (integer)")
        if not (math.isfinite(self.window_s) and self.window_s > 0):
            raise ParameterError(f"window_s={self.window_s!r} is outside (0, inf) s")

    def to_dict(self) -> dict[str, Any]:
        out = dataclasses.asdict(self)
        out["randomization"] = {n: [lo, hi] for n, lo, hi in self.randomization}
        out["off_resonance"] = [{"harmonic": h, "factor": f} for h, f in self.off_resonance]
        out["training_seed_limit"] = TRAINING_SEED_LIMIT
        out["policy_options"] = list(POLICY_OPTIONS)
        out["headline"] = ("mean RMS velocity ripple at the resonant speeds / the same for "
                           "policy 'none' (same motor, seed); IQM over motors and seeds")
        return out

    def with_suites(self, suites: Sequence[str]) -> "ProtocolV0":
        return dataclasses.replace(self, suites=self.checked_suites(suites))

    def motors(self) -> tuple[ProtocolMotor, ...]:
        """Presets first, then the draws (deterministic)."""
        return _motors(self)

    def entries(self, names: Mapping[str, tuple[str, str]],
                by_entry: Mapping[tuple[str, str], list[dict[str, Any]]],
                motors: Sequence[ProtocolMotor],
                meta: Mapping[str, dict[str, Any]], *, workers: int = 1
                ) -> list[dict[str, Any]]:
        """One entry per policy and suite, ranked in its suite."""
        out = []
        for suite in self.suites:
            reference = reference_index(by_entry[(REFERENCE_POLICY, suite)])
            group = [make_entry(name, spec_text, suite, by_entry[(spec, suite)], reference,
                                self, meta[spec])
                     for spec, (name, spec_text) in names.items() if (spec, suite) in by_entry]
            out += rank(group)
        return out


def full_protocol() -> ProtocolV0:
    """``stepdamp-bench v0``, the full protocol."""
    return ProtocolV0()


def quick_protocol() -> ProtocolV0:
    """The reduced CI variant: presets only, one seed, resonant speeds, 0.1 s window."""
    return ProtocolV0(variant="quick", randomized_per_preset=0,
                      eval_seeds=(TRAINING_SEED_LIMIT,), off_resonance=(), window_s=0.1)


def _usable(system: SystemParams, speeds: Sequence[float], protocol: ProtocolV0) -> bool:
    """No undamped run of the grid lags by half a full step or more (both suites)."""
    for mode in SUITES:
        settings = RunSettings(mode=mode, base_controller="none", window_s=protocol.window_s,
                               noise_seed=protocol.validation_noise_seed)
        for v in speeds:
            try:
                res = simulate(system, profile=SpeedProfile(speed_rps=v,
                                                            accel_rps2=protocol.accel_rps2),
                               settings=settings)
            except ParameterError:      # the run diverged: as unusable as a NaN lag was
                return False
            if not res.metrics.max_position_lag_steps < protocol.usable_max_lag_steps:
                return False
    return True


def _motors(protocol: ProtocolV0) -> tuple[ProtocolMotor, ...]:
    motors: list[ProtocolMotor] = []
    nominals = {name: with_sensors(get_preset(name), protocol) for name in protocol.presets}
    for name, nom in nominals.items():
        speeds, labels = speed_grid(nom, protocol)
        motors.append(ProtocolMotor(name, nom, nom, speeds, labels))
    rng = np.random.default_rng(protocol.motor_seed)
    for name, nom in nominals.items():
        for k in range(protocol.randomized_per_preset):
            for attempt in range(1, protocol.max_draw_attempts + 1):
                changes = {"name": f"{name}~r{k}",
                           **draw_around(nom, rng, protocol.randomization)}
                try:
                    system = nom.replace(**changes)
                except ParameterError:
                    continue
                speeds, labels = speed_grid(system, protocol)
                if _usable(system, speeds, protocol):
                    motors.append(ProtocolMotor(system.name, system, nom, speeds, labels,
                                                attempt))
                    break
            else:
                raise RuntimeError(f"no usable draw around {name!r} in "
                                   f"{protocol.max_draw_attempts} attempts")
    return tuple(motors)


PROTOCOL = {"version": "v0", "full": full_protocol, "quick": quick_protocol,
            "about": "frozen, the first published numbers",
            "quick_about": "the four presets, one seed"}
