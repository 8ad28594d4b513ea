"""Training motors over the ranges real catalogues span: a pool of public
datasheets (none in a scored split) and the draw of training motors from it.

``datasheet_pool.json`` beside this module holds the pool (built by
``scripts/build_datasheet_pool.py``; every motor's ``source`` inside): step
angle, rated current, holding torque, R, L and rotor inertia of 228 real
motors, NEMA 8 to 34, from a public table of datasheet values, none of them a
motor of the scored catalogue (some are its relatives: docs/motors.md). Each
motor is in the ``train`` or the ``dev`` part (by its name's hash): training
draws from ``train``, model selection from ``dev``; neither is ever scored.
``datasheet_pool_unrelated.json`` (the pool ``"datasheets-unrelated"``, built
with ``--exclude-relatives``) leaves out the scored motors' relatives too: 186
motors, 166 train and 20 dev, no dev motor a twin of a training motor.

A drawn training motor is a datasheet mapping (a motor file's object,
:func:`stepdamp_env.motorfile.load_system`) around one pool motor chosen
uniformly, by :class:`PoolDraw` (the distribution as data; SI units):

* R and L within the datasheets' tolerances (log-uniform, +-10 % and +-20 %);
* the detent torque (the table gives none): a log-uniform 2-6 % of the holding
  torque, around the motor files' default of 3 % and the 3.2-5.5 % of the
  non-scored datasheets that print it (docs/motors.md);
* no load with probability 1/2, else a rigidly coupled load of 0.25-5 rotor
  inertias (log-uniform; belt axes and leadscrews);
* a 24-48 V supply (log-uniform).

The draw uses NumPy's PCG64 and fixedmath's ``exp``/``log``, so it is the same
on every CPU. Every
drawn motor holds its detent and friction with a wide margin (they are at most
7 % of its holding torque).
"""

from __future__ import annotations

import dataclasses
import os
from dataclasses import dataclass
from functools import lru_cache
from types import MappingProxyType
from typing import Any, Sequence

import numpy as np

from . import fixedmath as fm
from .errors import ParameterError
from .io import read_json
from .motorfile import load_system
from .params import SystemParams

__all__ = ["POOL_PATH", "MOTOR_POOLS", "POOL_PARTS", "PoolDraw", "pool", "pool_motors",
           "draw_datasheet", "draw_datasheets", "pool_systems", "as_json"]

POOL_PATH = os.path.join(os.path.dirname(os.path.abspath(__file__)), "datasheet_pool.json")
#: The pools by name (``--motor-pool``): each a file beside this module.
MOTOR_POOLS = MappingProxyType({
    "datasheets": POOL_PATH,
    "datasheets-unrelated": os.path.join(os.path.dirname(POOL_PATH),
                                         "datasheet_pool_unrelated.json")})
POOL_PARTS = ("train", "dev")
_KEYS = ("step_angle_deg", "rated_current_A", "holding_torque_Nm", "phase_resistance_ohm",
         "phase_inductance_H")


@dataclass(frozen=True)
class PoolDraw:
    """How a training motor is drawn around a pool motor (the documented defaults)."""

    #: R and L: log-uniform within these relative tolerances of the datasheet's.
    resistance_tolerance: float = 0.10
    inductance_tolerance: float = 0.20
    #: Detent torque: a log-uniform share of the holding torque.
    detent_share: tuple[float, float] = (0.02, 0.06)
    #: Probability of a bare motor; else a load of load_ratio rotor inertias (log-uniform).
    bare_prob: float = 0.5
    load_ratio: tuple[float, float] = (0.25, 5.0)
    #: Supply voltage (V), log-uniform.
    bus_voltage_V: tuple[float, float] = (24.0, 48.0)

    def __post_init__(self) -> None:
        for name in ("resistance_tolerance", "inductance_tolerance"):
            v = getattr(self, name)
            if not 0.0 <= v < 1.0:
                raise ParameterError(f"{name}={v!r} is outside its allowed range [0, 1)")
        if not 0.0 <= self.bare_prob <= 1.0:
            raise ParameterError(f"bare_prob={self.bare_prob!r} is outside its allowed range "
                                 "[0, 1]")
        for name, lo_ok, hi_ok in (("detent_share", 0.0, 0.5), ("load_ratio", 0.0, 100.0),
                                   ("bus_voltage_V", 1.0, 1000.0)):
            lo, hi = getattr(self, name)
            if not lo_ok < lo <= hi <= hi_ok:
                raise ParameterError(f"{name}={(lo, hi)!r} is outside its allowed range "
                                     f"{lo_ok:g} < low <= high <= {hi_ok:g}")


def pool(motor_pool: str = "datasheets") -> dict[str, Any]:
    """The content of the pool file named ``motor_pool`` (read once)."""
    if not isinstance(motor_pool, str) or motor_pool not in MOTOR_POOLS:
        raise ParameterError(f"motor_pool={motor_pool!r} is not one of {list(MOTOR_POOLS)}")
    return _read(MOTOR_POOLS[motor_pool])


@lru_cache(maxsize=None)
def _read(path: str) -> dict[str, Any]:
    return read_json(path, "datasheet pool")


def pool_motors(part: str = "train", motor_pool: str = "datasheets"
                ) -> tuple[dict[str, Any], ...]:
    """The pool's motors of one part ("train" or "dev"), in the file's order."""
    if part not in POOL_PARTS:
        raise ParameterError(f"part={part!r} is not one of {list(POOL_PARTS)}")
    return tuple(m for m in pool(motor_pool)["motors"] if m["split"] == part)


def _log_uniform(rng: np.random.Generator, lo: float, hi: float) -> float:
    return float(fm.exp(rng.uniform(fm.log(lo), fm.log(hi))))


def draw_datasheet(rng: np.random.Generator, part: str = "train", draw: PoolDraw = PoolDraw(),
                   index: int = 0, motor_pool: str = "datasheets") -> dict[str, Any]:
    """One training motor (a datasheet mapping named ``<pool motor>~<index>``)
    around a pool motor of ``part`` chosen uniformly."""
    motors = pool_motors(part, motor_pool)
    m = motors[int(rng.integers(len(motors)))]
    out: dict[str, Any] = {"name": f"{m['name']}~{index}"}
    out.update({k: m[k] for k in _KEYS})
    r_tol, l_tol = draw.resistance_tolerance, draw.inductance_tolerance
    out["phase_resistance_ohm"] = (m["phase_resistance_ohm"]
                                   * _log_uniform(rng, 1 - r_tol, 1 + r_tol))
    out["phase_inductance_H"] = m["phase_inductance_H"] * _log_uniform(rng, 1 - l_tol, 1 + l_tol)
    torque, rotor = float(m["holding_torque_Nm"]), float(m["rotor_inertia_kgm2"])
    out["rotor_inertia_kgm2"] = rotor
    out["detent_torque_Nm"] = torque * _log_uniform(rng, *draw.detent_share)
    bare = rng.random() < draw.bare_prob
    out["load_inertia_kgm2"] = 0.0 if bare else rotor * _log_uniform(rng, *draw.load_ratio)
    out["bus_voltage_V"] = _log_uniform(rng, *draw.bus_voltage_V)
    out["source"] = f"drawn around the pool motor {m['name']} ({m['source']})"
    return out


def draw_datasheets(seed: int, count: int, part: str = "train", draw: PoolDraw = PoolDraw(),
                    motor_pool: str = "datasheets") -> tuple[dict[str, Any], ...]:
    """``count`` training motors drawn with ``seed`` (each one that builds: a
    draw the model refuses is drawn again)."""
    if isinstance(count, bool) or not isinstance(count, (int, np.integer)) \
            or not 1 <= count <= 4096:
        raise ParameterError(f"count={count!r} is outside its allowed range [1, 4096] (integer)")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) \
            or not 0 <= seed < 2 ** 63:
        raise ParameterError(f"seed={seed!r} is outside its allowed range [0, 2**63) (integer)")
    rng = np.random.default_rng(int(seed))
    out: list[dict[str, Any]] = []
    tries = 0
    while len(out) < count:
        tries += 1
        if tries > 100 * count:
            raise ParameterError(f"the pool's {part} part gave {len(out)} usable motors of "
                                 f"{count} in {tries} draws")
        values = draw_datasheet(rng, part, draw, len(out), motor_pool)
        try:
            load_system(values)
        except ParameterError:
            continue
        out.append(values)
    return tuple(out)


def pool_systems(motors: Sequence[dict[str, Any]]) -> tuple[SystemParams, ...]:
    """The systems of drawn datasheet mappings."""
    return tuple(load_system(m) for m in motors)


def as_json(draw: PoolDraw) -> dict[str, Any]:
    """A draw's settings as JSON-able data (for a training run's record)."""
    return {k: (list(v) if isinstance(v, tuple) else v)
            for k, v in dataclasses.asdict(draw).items()}
