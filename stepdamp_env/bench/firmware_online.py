"""A harmonic table that adapts while it runs, for a drive's firmware:
:class:`KalmanTable` (``adaptive-ff``) and :class:`RepetitiveTable`
(``repetitive-control``), their JSON and their C99.

The drive applies a harmonic table every PWM period, as a fixed law's
(:mod:`.firmware`), but the table changes: every agent step (``decision_hz``)
an update reads the speed error and the electrical angle's sines and cosines
the benchmark's policy reads (its float32 observation entries
``velocity_error``, ``sin_x`` ... ``cos_4x``) and moves the table. The C
keeps the update's state in a struct, the caller's, one per drive; the
benchmark's action is float32, so the exported update is the simulated one bit
for bit (``tests/test_firmware_online.py``). The C: :mod:`.firmware_online_c`.

The table is a phasor per detent harmonic h = 1, 2, 4: ``P_h = s_h + j*c_h``
(N*m), the torque ``s_h*sin(h*x) + c_h*cos(h*x)``; the q current the drive adds
is ``sum_h (s_h*sin(h*x) + c_h*cos(h*x)) / Km`` plus, in servo, the friction
feedforward ``friction_a*sign(w_cmd)``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Mapping

import numpy as np

from ..params import DETENT_HARMONICS, ParameterError
from ..version import __version__

__all__ = ["OnlineTableLaw", "KalmanTable", "RepetitiveTable", "ONLINE_FORMAT_ID",
           "online_to_json", "online_from_json"]

#: The JSON file's ``format`` tag.
ONLINE_FORMAT_ID = "stepdamp-firmware-online-table/1"


def _check_number(law: Any, name: str) -> None:
    value = getattr(law, name)
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)) \
            or not math.isfinite(float(value)):
        raise ParameterError(f"{name}={value!r} must be a finite number")
    object.__setattr__(law, name, float(value))


def _check_six(law: Any, name: str) -> None:
    try:
        values = tuple(float(v) for v in getattr(law, name))
    except (TypeError, ValueError):
        values = ()
    if len(values) != 6 or not all(math.isfinite(v) for v in values):
        raise ParameterError(f"{name} must hold 6 finite numbers")
    object.__setattr__(law, name, values)


def _check_step(law: Any, name: str) -> None:
    value = getattr(law, name)
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 0:
        raise ParameterError(f"{name}={value!r} must be an integer >= 0")
    object.__setattr__(law, name, int(value))


@dataclass(frozen=True)
class OnlineTableLaw:
    """What both online tables share: the operating point, the table they start
    from and how the table is written as the benchmark's action.

    Attributes:
        entry, motor, mode, speed_rps: the entry and operating point.
        decision_hz: updates per second (the agent rate, Hz).
        km_nm_per_a: the torque constant the table is divided by (N*m/A).
        friction_a: the servo's friction feedforward (A; 0 in open loop).
        base_nm: the patent feedforward's table (s1, c1, s2, c2, s4, c4), N*m.
        action_scale_nm: the action's scale (N*m per 1.0).
        initial_action: the first table's action (float32; ``ff-delay-comp``'s).
        speed_ref_rad_s: the observation's velocity unit (rad/s).
        accel_rps2: the ramp from rest to the held speed the step counts
            (``start_step``, ``wait_step``) assume (rev/s^2).
        velocity_estimator: the drive's speed estimate the update reads.
    """

    entry: str
    motor: str
    mode: str
    speed_rps: float
    decision_hz: float
    km_nm_per_a: float
    friction_a: float
    base_nm: tuple[float, ...]
    action_scale_nm: float
    initial_action: tuple[float, ...]
    speed_ref_rad_s: float
    accel_rps2: float
    velocity_estimator: str

    #: The JSON's ``update``: which update moves the table.
    UPDATE = ""

    def __post_init__(self) -> None:
        for name in ("speed_rps", "decision_hz", "km_nm_per_a", "friction_a",
                     "action_scale_nm", "speed_ref_rad_s", "accel_rps2"):
            _check_number(self, name)
        for name in ("base_nm", "initial_action"):
            _check_six(self, name)
        if any(float(np.float32(v)) != v or abs(v) > 1.0 for v in self.initial_action):
            raise ParameterError("initial_action must hold float32 values in [-1, 1]")
        for name in ("decision_hz", "km_nm_per_a", "action_scale_nm", "accel_rps2"):
            if not getattr(self, name) > 0.0:
                raise ParameterError(f"{name}={getattr(self, name)!r} must be > 0")


@dataclass(frozen=True)
class KalmanTable(OnlineTableLaw):
    """``adaptive-ff``'s law: a harmonic table moved by a Kalman filter's
    estimate of the speed ripple (see :class:`stepdamp_baselines.AdaptiveFF`).

    Every agent step k = 1, 2, ... (the first at the start of the run) with the
    speed error ``z = velocity_error * speed_ref_rad_s`` (rad/s) and ``H`` =
    (sin x, cos x, sin 2x, cos 2x, sin 4x, cos 4x):

    * from k > ``start_step``: one random-walk Kalman step of the ripple's six
      coefficients ``X`` (``P += drift_variance*I``; measurement ``H.X`` with
      variance ``noise_variance``; Joseph form), from ``X = 0``,
      ``P = initial_variance*I``;
    * up to k = ``adapt_step``: each harmonic's ripple power |R_h|^2 is kept
      as its reference;
    * after: a harmonic whose power passes ``guard_ratio`` times its reference
      plus 4 times its variance goes back to its first table and stops
      adapting; the others move by ``step_gain * w_h * R_h * inverse_path_h``
      (complex), ``w_h = clip(1 - 4*var_h/|R_h|^2, 0, 1)``;
    * the table is then written as the benchmark's action (relative to
      ``base_nm``, over ``action_scale_nm``, rounded to float32 and clipped to
      [-1, 1]) and read back: the table applied.

    Attributes (besides :class:`OnlineTableLaw`'s):
        inverse_path: 1/(G*H) per harmonic as (re, im) pairs (rad/s -> N*m).
        start_step, adapt_step: the agent steps where the filter starts and
            where adapting starts (after the probe).
        drift_variance, noise_variance, initial_variance: the filter's Q, R
            and P0 (rad^2/s^2).
        step_gain, guard_ratio: as above.
    """

    inverse_path: tuple[float, ...]
    start_step: int
    adapt_step: int
    drift_variance: float
    noise_variance: float
    initial_variance: float
    step_gain: float
    guard_ratio: float
    notes: str = ""

    UPDATE = "kalman"

    def __post_init__(self) -> None:
        super().__post_init__()
        for name in ("drift_variance", "noise_variance", "initial_variance", "step_gain",
                     "guard_ratio"):
            _check_number(self, name)
        _check_six(self, "inverse_path")
        for name in ("start_step", "adapt_step"):
            _check_step(self, name)
        if self.adapt_step < self.start_step:
            raise ParameterError("adapt_step must not be below start_step")
        if not self.noise_variance > 0.0:
            raise ParameterError(f"noise_variance={self.noise_variance!r} must be > 0")


@dataclass(frozen=True)
class RepetitiveTable(OnlineTableLaw):
    """``repetitive-control``'s law: a table learned once per electrical period
    from the speed error's harmonics (see
    :class:`stepdamp_baselines.learning.RepetitiveControl`).

    Every agent step k = 1, 2, ... from k > ``wait_step``: the electrical angle
    ``a = atan2(sin x, cos x)`` (fdlibm's) is followed over steps (its turn
    ``(a - a_prev + pi) mod 2*pi - pi`` summed from the second such step on),
    and ``z * (sin hx + j*cos hx)`` summed per harmonic, ``z = velocity_error *
    speed_ref_rad_s``. When the turn reaches a full period (|turn| >= 2*pi):
    the ripple ``R_h = 2*sum_h / count`` and its size |R_h|; a harmonic whose
    size passes ``guard_ratio`` times the least size seen goes back to its start
    and stops learning; the table becomes ``T_h = S_h + leak*(T_h - S_h) +
    learn_h*R_h`` (``S`` the start table, complex products), is written as the
    benchmark's action and read back; the turn loses 2*pi and the sums restart.

    Attributes (besides :class:`OnlineTableLaw`'s):
        start_nm: the start table S (``ff-delay-comp``'s, before the action's
            rounding), (s, c) pairs, N*m.
        learn: each harmonic's learning gain as (re, im) pairs (rad/s -> N*m;
            0 where a period holds too few agent steps).
        wait_step: the agent steps before learning starts (the ramp).
        leak, guard_ratio: as above.
    """

    start_nm: tuple[float, ...]
    learn: tuple[float, ...]
    wait_step: int
    leak: float
    guard_ratio: float
    notes: str = ""

    UPDATE = "repetitive"

    def __post_init__(self) -> None:
        super().__post_init__()
        for name in ("leak", "guard_ratio"):
            _check_number(self, name)
        for name in ("start_nm", "learn"):
            _check_six(self, name)
        _check_step(self, "wait_step")


_UPDATES = {cls.UPDATE: cls for cls in (KalmanTable, RepetitiveTable)}


def online_to_json(law: OnlineTableLaw) -> dict[str, Any]:
    """The law as a JSON object (``format`` :data:`ONLINE_FORMAT_ID`, ``update``
    "kalman" or "repetitive")."""
    out: dict[str, Any] = {"format": ONLINE_FORMAT_ID, "update": law.UPDATE,
                           "exported_by": f"stepdamp {__version__}",
                           "harmonics": list(DETENT_HARMONICS)}
    for name in type(law).__dataclass_fields__:
        value = getattr(law, name)
        out[name] = list(value) if isinstance(value, tuple) else value
    return out


def online_from_json(data: Mapping[str, Any]) -> OnlineTableLaw:
    """The law of :func:`online_to_json`'s object (a one-line error otherwise)."""
    if not isinstance(data, Mapping) or data.get("format") != ONLINE_FORMAT_ID:
        raise ParameterError(f"not a {ONLINE_FORMAT_ID} object")
    cls = _UPDATES.get(data.get("update"))
    if cls is None:
        raise ParameterError(f"update={data.get('update')!r} is not one of {list(_UPDATES)}")
    missing = [f for f in cls.__dataclass_fields__ if f not in data]
    if missing:
        raise ParameterError(f"online table JSON lacks {missing}")
    return cls(**{f: data[f] for f in cls.__dataclass_fields__})
