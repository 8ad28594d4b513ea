"""The stability checks' certificates (stepdamp_env/stability.py) decide as the
eigenvalues do: they accept only what the eigenvalues accept, and they accept
the systems people build (presets, datasheet motors), so those skip the eigenvalues."""

from __future__ import annotations

import copy
import math
import os
import pickle

import numpy as np
import pytest

from stepdamp_env import fixedmath as fm
from stepdamp_env import bench
from stepdamp_env.io import read_json
from stepdamp_env.motorfile import load_system
from stepdamp_env.motorpool import draw_datasheets, pool_systems
from stepdamp_env.params import (ParameterError, SystemParams, current_loop_radius,
                                 fastest_plant_mode, fastest_plant_mode_bound, required_substeps)
from stepdamp_env.presets import get_preset, preset_names
from stepdamp_env.simulation import check_integrable
from stepdamp_env.stability import (RK4_STABLE_RADIUS, current_loop_poles, loop_radius,
                                    loop_surely_stable, plant_rate, plant_rate_bound)


def _loop_draws(n: int, seed: int = 3) -> list[tuple[float, float, float, float]]:
    """(a, b, kp, ki*dt) of current loops from well damped to unstable."""
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n):
        a = float(np.exp(-rng.uniform(1e-6, 3.0)))
        R = float(10 ** rng.uniform(-2, 2))
        b = (1.0 - a) / R
        g = float(rng.uniform(0.0, 1.6))                 # the loop gain: stable up to 1
        kp = g * R / (1.0 - a) * float(rng.uniform(0.5, 2.0))
        ki_dt = kp * (1.0 - a) * float(rng.uniform(0.0, 3.0))
        out.append((a, b, kp, ki_dt))
    return out


def test_the_characteristic_polynomial_is_the_loops():
    for a, b, kp, ki_dt in _loop_draws(200):
        coeffs = np.poly(current_loop_poles(a, b, kp, ki_dt))
        mine = [1.0, -(1.0 + a), a + b * kp, b * (ki_dt - kp)]
        assert np.allclose(coeffs, mine, rtol=1e-9, atol=1e-12)


def test_the_loop_certificate_accepts_only_what_the_eigenvalues_accept_and_nearly_all_of_it():
    draws = _loop_draws(4000)
    radii = np.array([loop_radius(*d) for d in draws])
    sure = np.array([loop_surely_stable(*d) for d in draws])
    assert (radii < 1.0).sum() > 1000 and (radii > 1.0).sum() > 500     # both sides drawn
    assert np.all(radii[sure] < 1.0 - 1e-6 + 1e-9)
    # Everything clearly inside is certified (Jury's test is exact, not a bound).
    assert np.all(sure[radii < 1.0 - 1e-5])


def test_the_loop_certificate_says_nothing_of_nan_or_inf():
    assert not loop_surely_stable(0.5, 0.1, math.nan, 0.0)
    assert not loop_surely_stable(0.5, 0.1, math.inf, 0.0)
    assert loop_radius(0.5, 0.1, math.inf, 0.0) == math.inf


def _plant_draws(n: int, seed: int = 5) -> list[tuple[float, ...]]:
    """(k_max, J, D, Km, L, R) log-uniform over and beyond real motors' ranges."""
    rng = np.random.default_rng(seed)
    lo = np.log10([1e-3, 1e-8, 1e-7, 1e-3, 1e-5, 1e-2])
    hi = np.log10([1e4, 1e-2, 1e-1, 10.0, 1e-1, 1e2])
    return [tuple(float(v) for v in 10 ** rng.uniform(lo, hi)) for _ in range(n)]


def test_the_plant_bound_bounds_the_fastest_mode():
    for terms in _plant_draws(3000):
        assert plant_rate_bound(*terms) >= plant_rate(*terms) * (1.0 - 1e-12), terms


def _real_systems() -> list[SystemParams]:
    drawn = draw_datasheets(1, 200) + draw_datasheets(2, 50, part="dev")
    catalogue = read_json(os.path.join(os.path.dirname(bench.__file__), "catalogue.json"),
                          "catalogue")
    return ([get_preset(n) for n in preset_names()] + list(pool_systems(drawn))
            + [load_system(m) for m in catalogue])


def test_the_plant_bound_is_near_the_mode_on_real_motors():
    # Tight enough that their runs at one RK4 step per period skip the eigenvalues.
    for system in _real_systems():
        rate, _ = fastest_plant_mode(system)
        bound = fastest_plant_mode_bound(system)
        assert rate <= bound <= 3.0 * rate, system.name
        assert bound <= RK4_STABLE_RADIUS * system.drive.pwm_hz * (1.0 - 1e-6), system.name


def test_check_integrable_decides_as_the_eigenvalues_do():
    rng = np.random.default_rng(7)
    base = get_preset("patent")
    checked = refused = 0
    for _ in range(400):
        changes = {"J": base.motor.J * float(10 ** rng.uniform(-4, 1)),
                   "L": base.motor.L * float(10 ** rng.uniform(-3, 1)),
                   "Km": base.motor.Km * float(10 ** rng.uniform(-1, 1))}
        try:
            system = base.replace(**changes)
        except ParameterError:
            continue
        substeps = int(rng.integers(1, 6))
        speed = float(rng.uniform(0.0, 60.0))
        expect = substeps >= required_substeps(system, speed)
        try:
            check_integrable(system, substeps, speed)
            got = True
        except ParameterError:
            got = False
        assert got == expect
        checked += 1
        refused += not got
    assert checked > 300 and 20 < refused < checked - 20


def test_a_system_is_accepted_exactly_where_its_current_loop_is_stable():
    rng = np.random.default_rng(11)
    base = get_preset("patent")
    seen = set()
    for _ in range(300):
        kp = float(10 ** rng.uniform(-1, 2))
        ki = float(10 ** rng.uniform(2, 6))
        try:
            base.replace(Kp_current=kp, Ki_current=ki)
            accepted = True
        except ParameterError as e:
            accepted = False
            assert "unstable" in str(e)
        # The check the constructor made before the certificate, with its arithmetic.
        m, dt = base.motor, 1.0 / base.drive.pwm_hz
        x = m.R * dt / m.L
        radius = loop_radius(fm.exp(-x), -fm.expm1(-x) / m.R, kp, ki * dt)
        anti_windup_ok = ki / (kp * base.drive.pwm_hz) < 2.0
        assert accepted == (radius <= 1.0 + 1e-9 and anti_windup_ok)
        seen.add(accepted)
    assert seen == {True, False}


def test_a_systems_gains_survive_copies_and_pickles():
    system = get_preset("qsh4218-51-10-049").replace(R=2.0)
    for other in (copy.copy(system), copy.deepcopy(system),
                  pickle.loads(pickle.dumps(system))):
        assert other == system and other.current_gains() == system.current_gains()
    assert current_loop_radius(system) < 1.0


@pytest.mark.parametrize("name", ["patent", "qsh6018-65-28-210"])
def test_the_gains_are_the_derived_ones(name):
    system = get_preset(name)
    rebuilt = SystemParams(system.motor, system.drive, system.servo, system.name)
    assert rebuilt.current_gains() == system.current_gains()
    assert rebuilt.replace(Kp_current=None).current_gains() == system.current_gains()
