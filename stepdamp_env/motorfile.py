"""Motor files from datasheet values, and what a file leaves to defaults.

A motor file (``--motor FILE.json``, an item of ``--motors FILE.json``) gives
either the model's own fields (``R``, ``Km``, ``J``, ... with an optional
``"base"`` preset for the rest) or the values a datasheet prints, in SI units:

=====================  =========================================================
key                    model fields it sets (docs/motors.md has the formulas)
=====================  =========================================================
step_angle_deg         Nr = 360 / (4 * step_angle_deg)  (1.8 -> 50, 0.9 -> 100)
rated_current_A        holding_current = sqrt(2) * rated_current_A (the
                       microstep amplitude of equal copper loss) unless
                       ``holding_current`` is given
holding_torque_Nm      Km = holding_torque_Nm / (sqrt(2) * rated_current_A):
                       both phases on at the rated current
phase_resistance_ohm   R
phase_inductance_H     L
rotor_inertia_kgm2     J = rotor_inertia_kgm2 + load_inertia_kgm2
load_inertia_kgm2      (rigidly coupled load; default 0)
detent_torque_Nm       Kd1, Kd2, Kd4 = 15 %, 25 %, 60 % of it
load_torque_Nm         load_torque
bus_voltage_V          Vdc
=====================  =========================================================

A datasheet file starts from no preset: what it does not give comes from the
defaults below (:data:`DATASHEET_DEFAULTS` and the drive's and servo's field
defaults), each listed by :func:`describe` as assumed, with its value. D follows
the motor (mechanical damping ratio 0.02), Fs is 1 % of the holding torque, and
the servo gains are derived from J (a triple pole at 2*pi*velocity_cutoff_hz/5,
:meth:`stepdamp_env.params.SystemParams.servo_gains`), never a preset's.
Giving a datasheet key and a model field for one quantity is an error.

This module is where systems are loaded: :func:`load_system` (a preset name, a
motor file or a mapping), :func:`system_from_mapping` and ``--set``'s
:func:`parse_set_overrides`; :mod:`stepdamp_env.params` holds the validated
data alone.
"""

from __future__ import annotations

import dataclasses
import math
import os
from dataclasses import dataclass
from typing import Any, Iterable, Mapping

from .errors import ParameterError, show_value
from .io import read_json
from .limits import LIMITS
from .params import (ALL_FIELDS, DRIVE_FIELDS, INTEGER_FIELDS, META_KEYS, MOTOR_FIELDS,
                     SERVO_FIELDS, TEXT_FIELDS, DriveParams, MotorParams, ServoParams,
                     SystemParams, allowed)
from .presets import PRESETS, get_preset

__all__ = ["load_system", "system_from_mapping", "read_json_file", "parse_set_overrides",
           "DATASHEET_KEYS", "DATASHEET_DEFAULTS", "is_datasheet", "datasheet_fields",
           "MotorDescription", "describe", "describe_spec", "DETENT_SPLIT", "DAMPING_RATIO", "FRICTION_FRACTION",
           "DETENT_FRACTION"]

SQRT2 = math.sqrt(2.0)

#: Datasheet key -> (model fields it determines, allowed range).
DATASHEET_KEYS: dict[str, tuple[tuple[str, ...], Any]] = {
    "step_angle_deg": (("Nr",), allowed(0.01, 90.0, low_open=False)),
    "rated_current_A": ((), allowed(0.0, 100.0, low_open=True)),
    "holding_torque_Nm": (("Km",), allowed(0.0, 1e3, low_open=True)),
    "phase_resistance_ohm": (("R",), allowed(0.0, 1e3, low_open=True)),
    "phase_inductance_H": (("L",), allowed(1e-12, 10.0)),
    "rotor_inertia_kgm2": (("J",), allowed(1e-12, 10.0)),
    "load_inertia_kgm2": (("J",), allowed(0.0, 10.0)),
    "detent_torque_Nm": (("Kd1", "Kd2", "Kd4"), allowed(0.0, 100.0)),
    "load_torque_Nm": (("load_torque",), allowed(-100.0, 100.0)),
    "bus_voltage_V": (("Vdc",), allowed(0.0, 1e4, low_open=True)),
}
#: The quantities a datasheet file must give, each as a datasheet key or the model field.
REQUIRED = (("phase_resistance_ohm", "R"), ("phase_inductance_H", "L"),
            ("holding_torque_Nm", "Km"), ("rotor_inertia_kgm2", "J"))

#: Share of the datasheet's detent torque (the peak of its detent curve) per
#: harmonic h = 1, 2, 4; the presets' split (stepdamp_env/presets.py).
DETENT_SPLIT = {1: 0.15, 2: 0.25, 4: 0.60}
#: A datasheet's L/R past this (s) is refused: catalogue steppers span about
#: 0.3-10 ms (docs/motors.md), so an inductance typed in mH lands far above it.
MAX_ELECTRICAL_TIME_CONSTANT_S = 0.1
#: Mechanical damping ratio D / (2 * sqrt(Km * holding_current * Nr * J)).
DAMPING_RATIO = 0.02
#: Coulomb friction as a share of the holding torque.
FRICTION_FRACTION = 0.01
#: Defaults of datasheet quantities a file leaves out.
DATASHEET_DEFAULTS: dict[str, float] = {
    "step_angle_deg": 1.8,
    "load_inertia_kgm2": 0.0,
    "load_torque_Nm": 0.0,
    "phi1": -1.1,                      # rad, the patent preset's detent phases
    "phi2": 0.6,
}
#: Detent torque of a file that does not give it, as a share of the holding torque.
DETENT_FRACTION = 0.03


_FIELD_RANGES = {f.name: f.metadata["allowed"] for cls in (MotorParams, DriveParams, ServoParams)
                 for f in dataclasses.fields(cls)}
_OPTIONAL = {f.name for cls in (DriveParams, ServoParams) for f in dataclasses.fields(cls)
             if f.default is None}


def is_datasheet(values: Mapping[str, Any]) -> bool:
    """Whether a motor mapping gives any datasheet key."""
    return any(k in values for k in DATASHEET_KEYS)


def _check(key: str, value: Any) -> float:
    rng = DATASHEET_KEYS[key][1]["allowed"]
    rng.check(key, value)
    return float(value)


@dataclass(frozen=True)
class _Resolved:
    fields: dict[str, Any]        # flat model fields
    assumed: dict[str, Any]       # what came from a default, with its value


def _resolve(values: Mapping[str, Any]) -> _Resolved:
    """The flat fields of a datasheet mapping, and what was assumed."""
    if "base" in values:
        raise ParameterError("base: a datasheet motor (a file with "
                             f"{sorted(k for k in DATASHEET_KEYS if k in values)}) starts from "
                             "documented defaults, not from a preset; leave base out")
    for key, (targets, _) in DATASHEET_KEYS.items():
        clash = [f for f in targets if f in values]
        if key in values and clash:
            raise ParameterError(f"{key} and {clash[0]} give the same quantity; give one of them")
    for key, field_name in REQUIRED:
        if key not in values and field_name not in values:
            raise ParameterError(f"{key} (or the model field {field_name}) is missing: a "
                                 "datasheet motor needs rated_current_A, holding_torque_Nm, "
                                 "phase_resistance_ohm, phase_inductance_H and "
                                 "rotor_inertia_kgm2")
    if "rated_current_A" not in values and "holding_current" not in values:
        raise ParameterError("rated_current_A (or the model field holding_current) is missing")
    if "holding_torque_Nm" in values and "rated_current_A" not in values:
        raise ParameterError("holding_torque_Nm needs rated_current_A: the datasheet's holding "
                             "torque is at the rated current with both phases on")
    given = {k: _check(k, values[k]) for k in DATASHEET_KEYS if k in values}
    out: dict[str, Any] = {k: values[k] for k in values
                           if k in MOTOR_FIELDS or k in DRIVE_FIELDS or k in SERVO_FIELDS}
    for name, value in out.items():     # checked now: the conversion below uses some
        if value is not None or name not in _OPTIONAL:
            _FIELD_RANGES[name].check(name, value)
    assumed: dict[str, Any] = {}

    def ds(key: str) -> float:
        if key in given:
            return given[key]
        assumed[key] = DATASHEET_DEFAULTS[key]
        return DATASHEET_DEFAULTS[key]

    if "Nr" not in out:
        step = ds("step_angle_deg")
        nr = 360.0 / (4.0 * step)
        if abs(nr - round(nr)) > 1e-9:
            raise ParameterError(f"step_angle_deg={step:g} gives Nr = 90/step_angle_deg = {nr:.4g}, "
                                 "allowed: a whole number of rotor teeth (1.8 -> 50, 0.9 -> 100)")
        out["Nr"] = int(round(nr))
    if "rated_current_A" in given:
        out.setdefault("holding_current", SQRT2 * given["rated_current_A"])
        if "holding_torque_Nm" in given:
            out["Km"] = given["holding_torque_Nm"] / (SQRT2 * given["rated_current_A"])
    if "phase_resistance_ohm" in given:
        out["R"] = given["phase_resistance_ohm"]
    if "phase_inductance_H" in given:
        out["L"] = given["phase_inductance_H"]
        tau = out["L"] / float(out["R"])    # R is required (checked above)
        if tau > MAX_ELECTRICAL_TIME_CONSTANT_S:
            raise ParameterError(
                f"phase_inductance_H={given['phase_inductance_H']:g} gives L/R = {tau:.3g} s; "
                f"allowed <= {MAX_ELECTRICAL_TIME_CONSTANT_S:g} s (datasheets: 0.3-10 ms). "
                f"Was it in mH? {given['phase_inductance_H']:g} mH is "
                f"{given['phase_inductance_H'] * 1e-3:g} H")
    if "J" not in out:
        out["J"] = given["rotor_inertia_kgm2"] + ds("load_inertia_kgm2")
    # The defaults below are shares of the datasheet's holding torque where it is given.
    t_hold = given.get("holding_torque_Nm", float(out["Km"]) * float(out["holding_current"]))
    if not any(k in out for k in ("Kd1", "Kd2", "Kd4")):
        if "detent_torque_Nm" in given:
            detent = given["detent_torque_Nm"]
        else:
            detent = DETENT_FRACTION * t_hold
            assumed["detent_torque_Nm"] = detent
        for h in (1, 2, 4):
            out[f"Kd{h}"] = DETENT_SPLIT[h] * detent
    else:
        for h in (1, 2, 4):
            if f"Kd{h}" not in out:
                out[f"Kd{h}"] = 0.0
                assumed[f"Kd{h}"] = 0.0
    for name in ("phi1", "phi2"):
        if name not in out:
            out[name] = ds(name)
    if "load_torque" not in out:
        out["load_torque"] = ds("load_torque_Nm")
    if "D" not in out:
        out["D"] = 2.0 * DAMPING_RATIO * math.sqrt(t_hold * out["Nr"] * out["J"])
        assumed["D"] = out["D"]
    if "Fs" not in out:
        out["Fs"] = FRICTION_FRACTION * t_hold
        assumed["Fs"] = out["Fs"]
    if "bus_voltage_V" in given:
        out["Vdc"] = given["bus_voltage_V"]
    return _Resolved(out, assumed)


def datasheet_fields(values: Mapping[str, Any]) -> dict[str, Any]:
    """The flat model fields of a datasheet mapping (every motor field; drive
    and servo fields only where given), plus its ``name``."""
    resolved = _resolve(values)
    out = dict(resolved.fields)
    if "name" in values:
        out["name"] = values["name"]
    return out


@dataclass(frozen=True)
class MotorDescription:
    """A motor as a file describes it: the system and what was not from the file.

    ``assumed`` maps each field (or datasheet key) the file did not give to the
    value used, ``source`` says where defaults came from ("datasheet defaults"
    or "preset NAME")."""

    system: SystemParams
    assumed: dict[str, Any]
    source: str


def system_from_mapping(values: Mapping[str, Any]) -> SystemParams:
    """The system of a motor mapping (a motor file's object): model fields over the
    preset named by ``"base"`` (``"patent"`` if absent), or datasheet keys over
    the documented defaults (:data:`DATASHEET_DEFAULTS`)."""
    unknown = sorted(set(values) - set(ALL_FIELDS) - set(META_KEYS) - set(DATASHEET_KEYS))
    if unknown:
        raise ParameterError(
            f"unknown parameter(s) {unknown}; allowed: {list(ALL_FIELDS)}, datasheet keys "
            f"{list(DATASHEET_KEYS)} and metadata keys {list(META_KEYS)}")
    if is_datasheet(values):
        flat = datasheet_fields(values)
        drive = {**dataclasses.asdict(DriveParams()),
                 **{k: flat[k] for k in DRIVE_FIELDS if k in flat}}
        servo = {**dataclasses.asdict(ServoParams()),
                 **{k: flat[k] for k in SERVO_FIELDS if k in flat}}
        return SystemParams(MotorParams(**{k: flat[k] for k in MOTOR_FIELDS}),
                            DriveParams(**drive), ServoParams(**servo),
                            name=str(values.get("name", "custom")))
    base = get_preset(str(values.get("base", "patent")))
    return SystemParams.from_dict({k: v for k, v in values.items() if k != "base"}, base=base)


def describe(values: Mapping[str, Any]) -> MotorDescription:
    """The system of a motor mapping and the values it did not give."""
    system = system_from_mapping(values)
    if is_datasheet(values):
        assumed = dict(_resolve(values).assumed)
        drive_defaults = dataclasses.asdict(DriveParams())
        servo_defaults = dataclasses.asdict(ServoParams())
        for name in DRIVE_FIELDS + SERVO_FIELDS:
            if name in values or (name == "Vdc" and "bus_voltage_V" in values) \
                    or (name == "holding_current" and "rated_current_A" in values):
                continue
            value = {**drive_defaults, **servo_defaults}[name]
            assumed[name] = _derived(system, name) if value is None else value
        return MotorDescription(system, assumed, "datasheet defaults")
    base = str(values.get("base", "patent"))
    assumed = {}
    flat = system.to_dict()
    flat.setdefault("drive_mode", "current")
    for name in MOTOR_FIELDS + DRIVE_FIELDS + SERVO_FIELDS:
        if name not in values:
            assumed[name] = _derived(system, name) if flat[name] is None else flat[name]
    return MotorDescription(system, assumed, f"preset {base}")


def _derived(system: SystemParams, name: str) -> float:
    """A gain left to be derived: its value in use."""
    return float(system.derived_dict()[name])


def _check_file(text: str) -> bool:
    """Whether ``text`` names a motor file (it exists, ends in .json or holds a
    path separator); one that does not exist or is a directory is an error."""
    if not (text.endswith(".json") or os.path.sep in text or os.path.isfile(text)):
        return False
    if os.path.isdir(text):
        raise ParameterError(f"motor file {text!r} is a directory")
    if not os.path.isfile(text):
        raise ParameterError(f"motor file {text!r} does not exist")
    return True


def describe_spec(spec: str, _within: tuple[str, ...] = ()) -> list[MotorDescription]:
    """The motors a preset name or a motor file names: one for a preset or a
    motor object, one per item for a list file (``--motors``'s format; an item
    may name another file, but no file may name itself, even through others)."""
    if spec in PRESETS:
        return [MotorDescription(get_preset(spec), {}, f"preset {spec}")]
    if not os.path.isfile(spec):
        _check_file(spec)
        get_preset(spec)        # the one-line error listing the presets
    real = os.path.realpath(spec)
    if len(_within) >= LIMITS.list_file_depth:
        raise ParameterError(f"motor file {spec!r} is list file {len(_within) + 1} deep; allowed "
                             f"at most {LIMITS.list_file_depth} list files naming list files")
    if real in _within:
        raise ParameterError(f"motor file {spec!r} names itself (through "
                             f"{' -> '.join(map(repr, _within))}); a list file may name presets "
                             "and other motor files only")
    data = read_json_file(spec, "motor file")
    stem = os.path.splitext(os.path.basename(spec))[0]
    if isinstance(data, dict) and isinstance(data.get("motors"), list):
        data = data["motors"]
    items = data if isinstance(data, list) else [data]
    if len(items) > LIMITS.custom_motors:
        raise ParameterError(f"motor file {spec!r} lists {len(items)} motors; allowed 1 to "
                             f"{LIMITS.custom_motors}")
    out = []
    for k, item in enumerate(items):
        if isinstance(item, str):
            out.extend(describe_spec(item, _within + (real,)))
            continue
        if not isinstance(item, dict):
            raise ParameterError(f"motor file {spec!r}: item {k} must be a preset name or a "
                                 "JSON object of motor values")
        item = dict(item)
        # As --motors names them: a lone object by its file, list items custom<k>.
        item.setdefault("name", stem if isinstance(data, dict) else f"custom{k}")
        try:
            out.append(describe(item))
        except ParameterError as exc:
            raise ParameterError(f"motor file {spec!r}" + (f", motor {k}" if len(items) > 1
                                                          else "") + f": {exc}") from None
    return out


def read_json_file(path: str, label: str) -> Any:
    """The JSON in ``path``; invalid JSON or an unreadable file is a one-line
    ``ParameterError`` naming it as ``label`` (e.g. "motor file", "--motors")."""
    return read_json(path, label)


def load_system(spec: str | os.PathLike[str] | Mapping[str, Any] | SystemParams,
                overrides: Mapping[str, Any] | None = None) -> SystemParams:
    """Resolve a preset name, a motor JSON file or a mapping to a SystemParams.

    A JSON file (or mapping) holds any of the flat field names; the others come
    from the preset named by its optional ``"base"`` key (``"patent"`` if absent).
    ``overrides`` (flat field names, e.g. from ``--set``) are applied last.
    """
    if isinstance(spec, SystemParams):
        system = spec
    elif isinstance(spec, Mapping):
        system = system_from_mapping(spec)
    else:
        if not isinstance(spec, (str, os.PathLike)):
            raise ParameterError(f"motor must be a preset name, a motor .json file, a mapping "
                                 f"or SystemParams, got {type(spec).__name__} {show_value(spec)}")
        text = os.fspath(spec)
        if _check_file(text):
            values = read_json_file(text, "motor file")
            if not isinstance(values, dict):
                raise ParameterError(f"motor file {text!r} must hold a JSON object")
            values.setdefault("name", os.path.splitext(os.path.basename(text))[0])
            system = system_from_mapping(values)
        else:
            system = get_preset(text)
    if overrides:
        system = system.replace(**overrides)
    return system


def parse_set_overrides(items: Iterable[str]) -> dict[str, float | str]:
    """Parse ``FIELD=VALUE`` strings (``--set``) into a dict of numbers (text for
    ``drive_mode``)."""
    out: dict[str, float | str] = {}
    for item in items:
        name, sep, raw = item.partition("=")
        name = name.strip()
        if not sep or not name:
            raise ParameterError(f"--set expects FIELD=VALUE, got {item!r}")
        if name not in ALL_FIELDS:
            raise ParameterError(f"--set: unknown parameter {name!r}; allowed: "
                                 f"{list(ALL_FIELDS)}")
        if name in TEXT_FIELDS:
            text = raw.strip()
            DriveParams.__dataclass_fields__[name].metadata["allowed"].check(f"--set {name}",
                                                                             text)
            out[name] = text
            continue
        try:
            value = float(raw)
        except ValueError:
            raise ParameterError(f"--set {name}: {raw!r} is not a number") from None
        out[name] = int(value) if value.is_integer() and name in INTEGER_FIELDS else value
    return out
