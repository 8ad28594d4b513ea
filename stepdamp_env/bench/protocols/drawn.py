"""What every version of stepdamp-bench from v1 shares: drawn motors, their
splits, grids and settling, the user's motor files, the mid-band suite.

Frozen versions run on this code (v1, v2 and v3 subclass these classes and add
their own values and scoring; v4 too): a change here must leave every
version's numbers as they are (their fingerprints in the tests, under the
emulated CPUs). The specification of what is here is v1's and v2's module
docstrings (:mod:`.v1`, :mod:`.v2`).
"""

from __future__ import annotations

import dataclasses
import math
import os
from collections import Counter
from dataclasses import dataclass
from typing import Any, ClassVar, Mapping, Sequence

import numpy as np

from ... import fixedmath as fm
from ...analysis import MIDBAND_SCAN_RPS, midband
from ...limits import LIMITS
from ...motorfile import load_system, read_json_file
from ...params import ALL_FIELDS, ParameterError, SystemParams
from ...presets import get_preset
from ..motors import (ProtocolMotor, draw_around, holds_its_load, slowest_decay_rate,
                      speed_grid, with_sensors)
from ..protocol import (ALL_SUITES, FAILURE_RATIO, PHASE_FIELDS, POLICY_OPTIONS,
                        PROTOCOL_NAME, REFERENCE_POLICY, SUITES, TRAINING_SEED_LIMIT,
                        Protocol, rank)
from ..scoring import add_probability_of_improvement, make_entry_v1, reference_index

__all__ = ["DrawnProtocol", "MidBandProtocol", "SPLITS", "MIN_TRAINING_SEEDS", "Shift",
           "SHIFTS", "QUICK_SETTINGS", "servo_grid", "in_training_distribution",
           "load_motors_file", "midband_grid", "SENSOR_FIELDS", "with_protocol_sensors"]

SPLITS = ("interpolation", "extrapolation", "custom")
# An entry with fewer training seeds makes no claim (the report says so).
MIN_TRAINING_SEEDS = 5

_PRESETS = ("patent", "qsh4218-51-10-049", "qsh5718-56-28-126", "qsh6018-65-28-210")
_TRAINING_RANDOMIZATION: tuple[tuple[str, float, float], ...] = (
    ("R", 0.8, 1.25), ("L", 0.8, 1.25), ("Km", 0.85, 1.15), ("J", 0.5, 2.0),
    ("Kd1", 0.5, 1.5), ("Kd2", 0.5, 1.5), ("Kd4", 0.5, 1.5), ("Fs", 0.5, 1.5),
    ("phi1", -math.pi, math.pi), ("phi2", -math.pi, math.pi),
)
_OFF_RESONANCE = ((4, 0.6), (4, math.sqrt(2.0)), (2, math.sqrt(2.0)), (1, 1.3))


@dataclass(frozen=True)
class Shift:
    """One extrapolation shift: ``changes`` are (field, low, high, how) with how
    "factor" (the preset's value times U(low, high), replacing the drawn
    one, so the motor leaves the training box), "value" (set to low) or
    "holding" (U(low, high) times the holding torque Km*holding_current);
    ``declared``: the drive knows it (it is in the nominal model)."""

    name: str
    changes: tuple[tuple[str, float, float, str], ...]
    declared: bool


SHIFTS: tuple[Shift, ...] = (
    Shift("inertia", (("J", 2.5, 4.0, "factor"),), declared=False),
    Shift("detent", (("Kd1", 1.6, 2.2, "factor"), ("Kd2", 1.6, 2.2, "factor"),
                     ("Kd4", 1.6, 2.2, "factor")), declared=False),
    Shift("0.9-degree", (("Nr", 100, 100, "value"),), declared=True),
    Shift("low-bus", (("Vdc", 0.5, 0.5, "factor"),), declared=True),
    Shift("load-torque", (("load_torque", 0.1, 0.25, "holding"),), declared=False),
)


@dataclass(frozen=True)
class DrawnProtocol(Protocol):
    """The settings and the motors every version from v1 shares (v1's values
    by default): motors drawn around the presets into the interpolation and
    extrapolation splits (:mod:`.v1`'s docstring specifies them), a user's
    ``custom_motors`` (with ``splits=("custom",)``: the systems of
    ``--motors FILE``), each motor's per-suite grids and settling, and v1's
    scoring (``entries``: ratios to ``none``, v1's and v2's). A version
    subclasses it and gives its values."""

    name: str = PROTOCOL_NAME
    version: str = "v1"
    variant: str = "full"
    suites: tuple[str, ...] = SUITES
    splits: tuple[str, ...] = ("interpolation", "extrapolation")
    #: The presets motors are drawn around, and the training distribution's
    #: (field, low, high): factors of the preset's value, phases in rad.
    presets: tuple[str, ...] = _PRESETS
    training_randomization: tuple[tuple[str, float, float], ...] = _TRAINING_RANDOMIZATION
    interpolation_per_preset: int = 4
    shifts: tuple[Shift, ...] = SHIFTS
    #: (preset index, shift name) pairs; empty: every shift on every preset.
    extrapolation_pairs: tuple[tuple[int, str], ...] = ()
    motor_seed: int = 7_733_052
    #: A draw that fails the physics rule (holding torque >= ``holding_margin``
    #: x detent, friction and load) is redrawn, at most this often.
    max_draw_attempts: int = 100
    holding_margin: float = 3.0
    custom_motors: tuple[SystemParams, ...] = ()
    eval_seeds: tuple[int, ...] = (TRAINING_SEED_LIMIT,)
    #: Open loop: the resonant harmonics scored, and off-resonance (harmonic,
    #: factor) speeds; servo: its speeds as factors of f4.
    resonance_harmonics: tuple[int, ...] = (4, 2, 1)
    off_resonance: tuple[tuple[int, float], ...] = _OFF_RESONANCE
    servo_factors: tuple[float, ...] = (0.1, 0.18, 0.3, 0.5)
    accel_rps2: float = 50.0
    window_s: float = 0.3
    #: Settling before the window (:meth:`settle_times`).
    settle_open_loop_decays: float = 4.0
    settle_servo_time_constants: float = 10.0
    settle_min_s: float = 0.1
    #: The drawn motors' sensors: current noise (A per sample), encoder counts/rev.
    current_noise_a: float = 0.01
    encoder_cpr: int = 4000
    identification_method: str = "iterative"
    failure_ratio: float = FAILURE_RATIO
    #: The two-level bootstrap's resamples, seed and interval.
    bootstrap_resamples: int = 2000
    bootstrap_seed: int = 2000
    confidence: float = 0.95

    def __post_init__(self) -> None:
        self.check_suites_and_seeds()
        bad = [s for s in self.splits if s not in self.known_splits]
        if bad or not self.splits:
            raise ParameterError(f"splits={self.splits!r}: each must be one of "
                                 f"{list(self.known_splits)}")
        if ("custom" in self.splits) != bool(self.custom_motors):
            raise ParameterError("custom_motors: give motors exactly when the 'custom' "
                                 "split is run (--motors FILE)")
        if self.motor_seed < TRAINING_SEED_LIMIT:
            raise ParameterError(f"motor_seed={self.motor_seed!r} must be >= "
                                 f"{TRAINING_SEED_LIMIT} (training seeds are below it)")
        if not (math.isfinite(self.window_s) and self.window_s > 0):
            raise ParameterError(f"window_s={self.window_s!r} is outside (0, inf) s")
        for name, value, low in (("interpolation_per_preset", self.interpolation_per_preset, 0),
                                 ("max_draw_attempts", self.max_draw_attempts, 1),
                                 ("bootstrap_resamples", self.bootstrap_resamples, 1)):
            if not (isinstance(value, int) and value >= low):
                raise ParameterError(f"{name}={value!r} is outside its allowed range "
                                     f"[{low}, inf) (integer)")
        if not (math.isfinite(self.holding_margin) and self.holding_margin > 0):
            raise ParameterError(f"holding_margin={self.holding_margin!r} is outside (0, inf)")
        if not 0.0 < self.confidence < 1.0:
            raise ParameterError(f"confidence={self.confidence!r} is outside (0, 1)")
        if not self.servo_factors or not all(math.isfinite(f) and f > 0
                                             for f in self.servo_factors):
            raise ParameterError(f"servo_factors={self.servo_factors!r}: each must be in "
                                 "(0, inf)")
        shifts = {s.name for s in self.shifts}
        for i, name in self.extrapolation_pairs:
            if not 0 <= i < len(self.presets) or name not in shifts:
                raise ParameterError(f"extrapolation_pairs: ({i!r}, {name!r}) needs a preset "
                                     f"index in [0, {len(self.presets) - 1}] and a shift in "
                                     f"{sorted(shifts)}")

    def to_dict(self) -> dict[str, Any]:
        out = {f.name: getattr(self, f.name) for f in dataclasses.fields(self)
               if f.name not in ("custom_motors", "shifts", "training_randomization",
                                 "off_resonance", "extrapolation_pairs")}
        out["training_distribution"] = {
            "presets": list(self.presets),
            "factors": {n: [lo, hi] for n, lo, hi in self.training_randomization
                        if n not in PHASE_FIELDS},
            "phases_rad": {n: [lo, hi] for n, lo, hi in self.training_randomization
                           if n in PHASE_FIELDS},
            "fixed": "Nr = 50, load_torque = 0, the preset's Vdc and drive; protocol sensors"}
        out["shifts"] = [{"name": s.name, "declared": s.declared,
                          "changes": [{"field": f, "low": lo, "high": hi, "how": how}
                                      for f, lo, hi, how in s.changes]} for s in self.shifts]
        out["extrapolation_pairs"] = [[self.presets[i], s] for i, s in
                                      self.extrapolation_pairs]
        out["off_resonance"] = [{"harmonic": h, "factor": f} for h, f in self.off_resonance]
        out["training_seed_limit"] = TRAINING_SEED_LIMIT
        out["policy_options"] = list(POLICY_OPTIONS)
        out["headline"] = ("mean RMS velocity ripple at the suite's headline speeds (open "
                           "loop: the resonances; servo: the grid) / the same for policy "
                           "'none' (same motor, seed); IQM over motor x seed x training-seed "
                           "cells, two-level stratified bootstrap interval")
        return out

    def with_suites(self, suites: Sequence[str]) -> "DrawnProtocol":
        return dataclasses.replace(self, suites=self.checked_suites(suites))

    def with_custom_motors(self, systems: Sequence[SystemParams]) -> "DrawnProtocol":
        """The ``custom`` split alone, on these motors."""
        return dataclasses.replace(self, splits=("custom",), custom_motors=tuple(systems))

    # -- what the runner and the report ask ------------------------------------------
    known_suites: ClassVar[tuple[str, ...]] = SUITES
    #: The splits this version may run.
    known_splits: ClassVar[tuple[str, ...]] = SPLITS
    pools_training_seeds: ClassVar[bool] = True
    nominal_on_failed_identification: ClassVar[bool] = True
    min_training_seeds: ClassVar[int] = 5
    rows_per_split: ClassVar[bool] = True

    def motors(self) -> tuple[ProtocolMotor, ...]:
        """Interpolation, then extrapolation, or the custom motors."""
        return _motors(self)

    def build_motor(self, name: str, system: SystemParams, nominal: SystemParams, split: str,
                    family: str, attempts: int) -> ProtocolMotor:
        """One drawn (or custom) motor with its sensors (:meth:`motor_sensors`), its
        per-suite grids (:meth:`suite_grids`) and settling (:meth:`settle_times`)."""
        system, nominal = self.motor_sensors(name, system, nominal, split)
        grids = self.suite_grids(system)
        settle = self.settle_times(system)
        return ProtocolMotor(name, system, nominal, grids[0][1], grids[0][2], attempts,
                             split=split, family=family, grids=grids,
                             settle=tuple((s, settle[s]) for s in settle))

    def motor_sensors(self, name: str, system: SystemParams, nominal: SystemParams,
                      split: str) -> tuple[SystemParams, SystemParams]:
        """(plant, nominal model) with the motor's sensors: v1 gives every drawn
        motor the protocol's; a later version may draw them per motor."""
        return system, nominal

    def suite_grids(self, system: SystemParams
                    ) -> tuple[tuple[str, tuple[float, ...], tuple[str, ...]], ...]:
        """(suite, speeds in rev/s, labels) of each suite on ``system``."""
        return (("open-loop", *speed_grid(system, self)),      # v0's open-loop grid rule
                ("servo", *servo_grid(system, self)))

    def settle_times(self, system: SystemParams) -> dict[str, float]:
        """Settling per suite (s): open loop ``settle_open_loop_decays`` decay
        times 1/(zeta*wn) = 2J/D of the undamped resonance; servo
        ``settle_servo_time_constants`` time constants of the servo loop's slowest
        pole; at least ``settle_min_s``, no upper clip."""
        m = system.motor
        decay_rate = m.D / (2.0 * m.J)
        ol = self.settle_open_loop_decays / decay_rate if decay_rate > 0 else math.inf
        kv, kp, ki = system.servo_gains()
        slowest = slowest_decay_rate(m.J, kv, kp, ki)      # the servo loop's
        servo = self.settle_servo_time_constants / slowest if slowest > 0 else math.inf
        if not math.isfinite(ol):
            raise ParameterError(f"motor {system.name!r}: D = 0 leaves its resonance undamped; "
                                 "v1 settles four decay times 2J/D, so D must be > 0")
        if not math.isfinite(servo):
            raise ParameterError(f"motor {system.name!r}: its servo gains (Kp_vel, Kp_pos, "
                                 "Ki_pos) leave the servo loop unstable")
        return {"open-loop": max(ol, self.settle_min_s), "servo": max(servo, self.settle_min_s)}

    def entries(self, names: Mapping[str, tuple[str, str]],
                by_entry: Mapping[tuple[str, str], list[dict[str, Any]]],
                motors: Sequence[ProtocolMotor],
                meta: Mapping[str, dict[str, Any]], *, workers: int = 1
                ) -> list[dict[str, Any]]:
        """Entries per (suite, split), ranked, with every pair's probability of
        improvement."""
        split_of = {m.name: m.split for m in motors}
        strata = {m.name: m.family for m in motors}
        out = []
        for suite in self.suites:
            if (REFERENCE_POLICY, suite) not in by_entry:
                continue
            reference = reference_index(by_entry[(REFERENCE_POLICY, suite)])
            for split in self.splits:
                group = [make_entry_v1(name, spec_text, suite, split,
                                       [r for r in by_entry[(spec, suite)]
                                        if split_of[r["motor"]] == split],
                                       reference, self, strata,
                                       {**meta[spec], "learned": bool(meta[spec].get("learned"))})
                         for spec, (name, spec_text) in names.items()
                         if (spec, suite) in by_entry]
                add_probability_of_improvement(rank(group), self, strata)
                out += group
        return out


@dataclass(frozen=True)
class MidBandProtocol(DrawnProtocol):
    """:class:`DrawnProtocol` plus the ``mid-band`` suite (the voltage-mode drive,
    docs/protocol_v2.md), as v2 defined it and v3 and v4 keep it.

    ``midband_factors``: the suite's speeds, log-spaced through each motor's
    predicted unstable band [f_lo, f_hi] (:func:`stepdamp_env.analysis.midband`
    of the motor with ``drive_mode="voltage"``): f_lo*(f_hi/f_lo)**k for k in
    the factors. A motor without an unstable band uses
    [f_min/1.5, 1.5*f_min] around its least damped speed f_min.
    """

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


# The reduced CI variant's settings (v1's; v2 and v3 add theirs).
QUICK_SETTINGS: dict[str, Any] = dict(
    variant="quick", interpolation_per_preset=1,
    extrapolation_pairs=((0, "inertia"), (1, "0.9-degree"), (2, "load-torque"), (3, "low-bus")),
    off_resonance=(), servo_factors=(0.1, 0.3), window_s=0.1, bootstrap_resamples=500)


def servo_grid(system: SystemParams, protocol: DrawnProtocol) -> tuple[tuple[float, ...],
                                                                     tuple[str, ...]]:
    """v1's servo speeds: ``servo_factors`` x f4 (rev/s), labelled ``s<factor>``."""
    f4 = system.predicted_resonances_rps()[4]
    return (tuple(float(f * f4) for f in protocol.servo_factors),
            tuple(f"s{f:g}" for f in protocol.servo_factors))


def in_training_distribution(system: SystemParams, preset: SystemParams,
                             protocol: DrawnProtocol) -> bool:
    """Whether ``system`` could be a training draw around ``preset``: every
    randomised field within its range (as a factor, phases as values) and every
    other field the preset's (sensors aside)."""
    eps = 1e-12
    for name, lo, hi in protocol.training_randomization:
        x = getattr(system.motor, name)
        if name not in PHASE_FIELDS:
            x = x / getattr(preset.motor, name)
        if not lo - eps <= x <= hi + eps:
            return False
    drawn = {n for n, _, _ in protocol.training_randomization} | {"current_noise_a",
                                                                    "encoder_cpr"}
    mine, theirs = system.to_dict(), preset.to_dict()
    return all(mine[k] == theirs[k] for k in mine if k not in drawn and k != "name")


def _apply_shift(nom: SystemParams, changes: dict[str, Any], shift: Shift,
                 rng: np.random.Generator) -> tuple[dict[str, Any], dict[str, Any]]:
    """(the drawn changes with the shift on top, the shift's declared part)."""
    out, declared = dict(changes), {}
    drawn = nom.replace(**changes)
    for field_name, lo, hi, how in shift.changes:
        x = float(rng.uniform(lo, hi)) if hi > lo else float(lo)
        if how == "value":
            value: Any = int(x) if field_name == "Nr" else x
        elif how == "factor":                  # of the preset's value: outside the box
            value = nom.to_dict()[field_name] * x
        else:                                   # "holding"
            value = x * drawn.motor.Km * drawn.drive.holding_current
        out[field_name] = value
        if shift.declared:
            declared[field_name] = value
    return out, declared


def _motors(protocol: DrawnProtocol) -> tuple[ProtocolMotor, ...]:
    motors: list[ProtocolMotor] = []
    nominals = {name: with_sensors(get_preset(name), protocol) for name in protocol.presets}
    rng = np.random.default_rng(protocol.motor_seed)

    def draw(label: str, nom: SystemParams, shift: Shift | None) -> tuple[SystemParams,
                                                                          SystemParams, int]:
        for attempt in range(1, protocol.max_draw_attempts + 1):
            changes = draw_around(nom, rng, protocol.training_randomization)
            declared: dict[str, Any] = {}
            if shift is not None:
                changes, declared = _apply_shift(nom, changes, shift, rng)
            try:
                system = nom.replace(name=label, **changes)
                nominal = nom.replace(**declared) if declared else nom
            except ParameterError:
                continue
            if holds_its_load(system, protocol.holding_margin):
                return system, nominal, attempt
        raise RuntimeError(f"no draw for {label!r} passes the physics rule in "
                           f"{protocol.max_draw_attempts} attempts")

    # Both splits draw from one stream, in this order, whichever splits are run.
    interp = []
    for name, nom in nominals.items():
        for k in range(protocol.interpolation_per_preset):
            interp.append((f"{name}~i{k}", *draw(f"{name}~i{k}", nom, None), name))
    pairs = protocol.extrapolation_pairs or tuple(
        (i, s.name) for s in protocol.shifts for i in range(len(protocol.presets)))
    shifts = {s.name: s for s in protocol.shifts}
    extrap = []
    for i, shift_name in pairs:
        preset = protocol.presets[i]
        label = f"{preset}~x-{shift_name}"
        extrap.append((label, *draw(label, nominals[preset], shifts[shift_name]), shift_name))
    if "interpolation" in protocol.splits:
        motors += [protocol.build_motor(n, s, nom, "interpolation", fam, a)
                   for n, s, nom, a, fam in interp]
    if "extrapolation" in protocol.splits:
        motors += [protocol.build_motor(n, s, nom, "extrapolation", fam, a)
                   for n, s, nom, a, fam in extrap]
    if "custom" in protocol.splits:
        for system in protocol.custom_motors:
            if not holds_its_load(system, protocol.holding_margin):
                m = system.motor
                need = m.Kd1 + m.Kd2 + m.Kd4 + m.Fs + abs(m.load_torque)
                raise ParameterError(
                    f"--motors: motor {system.name!r} fails the physics rule: holding torque "
                    f"{m.Km * system.drive.holding_current:.4g} N*m must be >= "
                    f"{protocol.holding_margin:g} x (Kd1 + Kd2 + Kd4 + Fs + |load_torque|) = "
                    f"{protocol.holding_margin * need:.4g} N*m")
            motors.append(protocol.build_motor(system.name, system, system, "custom", "custom",
                                    0))
    return tuple(motors)


#: The sensors a protocol gives a custom motor whose file does not set them.
SENSOR_FIELDS = ("current_noise_a", "encoder_cpr")


def with_protocol_sensors(system: SystemParams, protocol: Any,
                          given: Mapping[str, Any] | Sequence[str] = ()) -> SystemParams:
    """``system`` with the protocol's sensors (:data:`SENSOR_FIELDS`) where
    ``given`` (the motor's own keys) does not set them, as ``--motors`` reads it."""
    return system.replace(**{f: getattr(protocol, f) for f in SENSOR_FIELDS if f not in given})


def load_motors_file(path: str, protocol: DrawnProtocol) -> tuple[SystemParams, ...]:
    """The motors of ``--motors FILE.json``: a JSON list (or ``{"motors": [...]}``)
    of preset names or motor objects as ``--motor FILE`` reads them (flat field
    names with an optional ``"base"`` preset, or datasheet keys; optional
    ``"name"``), or one motor object. Sensors the file does not
    set are the protocol's. Names must be unique."""
    if not os.path.isfile(path):
        raise ParameterError(f"--motors {path!r} is not a file")
    data = read_json_file(path, "--motors")
    if isinstance(data, dict):
        # {"motors": [...]}, or one motor object (a motor file)
        data = data.get("motors") if "motors" in data else \
            [{"name": os.path.splitext(os.path.basename(path))[0], **data}]
    if not isinstance(data, list) or not data:
        raise ParameterError(f"--motors {path!r} must hold a non-empty JSON list of motors "
                             "(or an object with one under \"motors\")")
    # Names first, in linear time, before any motor is validated (each takes ~0.2 ms).
    names = Counter(item if isinstance(item, str) else
                    str(item["name"]) if "name" in item else f"custom{k}"
                    for k, item in enumerate(data) if isinstance(item, (str, dict)))
    dupes = sorted(n for n, count in names.items() if count > 1)
    if dupes:
        shown = [n if len(n) <= 40 else n[:37] + "..." for n in dupes[:5]]
        more = f" and {len(dupes) - 5} more" if len(dupes) > 5 else ""
        raise ParameterError(f"--motors {path!r}: motor names must be unique, repeated: "
                             f"{shown}{more}")
    if len(data) > LIMITS.custom_motors:     # each runs every suite, speed and seed
        raise ParameterError(f"--motors {path!r} holds {len(data)} motors; allowed 1 to "
                             f"{LIMITS.custom_motors}")
    systems = []
    for k, item in enumerate(data):
        if not isinstance(item, (str, dict)):
            raise ParameterError(f"--motors {path!r}: motor {k} must be a preset name or an "
                                 f"object of parameters {list(ALL_FIELDS)}")
        try:
            system = load_system(item)
        except ParameterError as exc:
            raise ParameterError(f"--motors {path!r}, motor {k}: {exc}") from None
        if isinstance(item, str) or "name" not in item:
            system = system.replace(name=f"custom{k}" if isinstance(item, dict) else item)
        systems.append(with_protocol_sensors(system, protocol,
                                             item if isinstance(item, dict) else {}))
    return tuple(systems)


def midband_grid(system: SystemParams, protocol: MidBandProtocol,
                 scan: tuple[float, float, float] = MIDBAND_SCAN_RPS,
                 first_band_only: bool = False
                 ) -> tuple[tuple[float, ...], tuple[str, ...]]:
    """The mid-band speeds (rev/s), labelled ``m<factor>``: log-spaced through the
    predicted unstable band of ``system`` in voltage mode (see :class:`MidBandProtocol`),
    found on the speed grid ``scan`` (:func:`stepdamp_env.analysis.midband`)."""
    band = midband(system.replace(drive_mode="voltage"), scan, first_band_only)
    if band.unstable_rps is not None:
        lo, hi = band.unstable_rps
    else:
        lo, hi = band.at_rps / 1.5, band.at_rps * 1.5
    return (tuple(float(lo * fm.exp(f * fm.log(hi / lo))) for f in protocol.midband_factors),
            tuple(f"m{f:g}" for f in protocol.midband_factors))
