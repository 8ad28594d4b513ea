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
from stepdamp_env.stability import (RK4_STABLE_RADIUS, current_loop_poles, current_loop_terms,
                                    loop_radius, loop_surely_stable, plant_rate,
                                    plant_rate_bound)


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
    older = copy.copy(system)
    del older.__dict__["_current_gains"]        # as a system pickled by 0.18.0 has it
    assert older.current_gains() == system.current_gains()
    assert current_loop_radius(system) < 1.0


@pytest.mark.parametrize("name", ["patent", "qsh6018-65-28-210"])
def test_the_gains_are_the_derived_ones(name):
    system = get_preset(name)
    rebuilt = SystemParams(system.motor, system.drive, system.servo, system.name)
    assert rebuilt.current_gains() == system.current_gains()
    assert rebuilt.replace(Kp_current=None).current_gains() == system.current_gains()


def _probe_near(a: float, b: float, ki_share: float, target: float) -> float:
    """kp whose loop radius is within 5e-8 of ``target`` (bisection on eigenvalues)."""
    def radius(kp: float) -> float:
        return loop_radius(a, b, kp, kp * (1.0 - a) * ki_share)

    lo, hi = 0.0, 1.0 / b
    while radius(hi) < target:
        hi *= 2.0
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if radius(mid) < target else (lo, mid)
        if abs(radius(hi) - target) < 5e-8:
            return hi
    raise AssertionError("no crossing found")


@pytest.mark.parametrize("a, b, ki_share", [(0.5, 0.01, 1.0), (0.99, 0.001, 1.0),
                                            (0.2, 0.5, 0.3), (0.9, 2e-4, 2.5)])
def test_the_loop_certificate_stops_at_its_radius(a, b, ki_share):
    # Just inside 1 - 1e-6 it accepts; just outside (still a stable loop) it leaves
    # the question to the eigenvalues.
    inside = _probe_near(a, b, ki_share, 1.0 - 1.3e-6)
    outside = _probe_near(a, b, ki_share, 1.0 - 0.7e-6)
    assert loop_surely_stable(a, b, inside, inside * (1.0 - a) * ki_share)
    assert not loop_surely_stable(a, b, outside, outside * (1.0 - a) * ki_share)


def test_the_lossless_integrator_is_left_to_the_eigenvalues():
    # Ki = 0: (z - 1)(z^2 - a z + b kp), a pole on the unit circle that the
    # constructor accepts (radius 1 within 1e-9) and the certificate does not.
    a, b, kp = 0.7, 0.02, 10.0
    assert abs(loop_radius(a, b, kp, 0.0) - 1.0) < 1e-12
    assert not loop_surely_stable(a, b, kp, 0.0)


def _stiff() -> SystemParams:
    base = get_preset("patent")
    return base.replace(J=base.motor.J / 100)      # fastest mode about 11,900 rad/s


@pytest.mark.parametrize("f", [1.0 - 1e-6, 1.0 + 1e-6, 1.3, 2.0])
def test_check_integrable_at_the_limit_of_one_rk4_step(f):
    # pwm_hz puts one RK4 step's limit at f times the fastest mode: below, refused;
    # between the mode and its bound, the eigenvalues accept it.
    system = _stiff()
    rate, _ = fastest_plant_mode(system)
    pwm = rate / RK4_STABLE_RADIUS * f
    system = system.replace(pwm_hz=pwm, current_bandwidth_hz=pwm / 10)
    if f < 1.0:
        with pytest.raises(ParameterError, match="substeps=1"):
            check_integrable(system, 1)
    else:
        check_integrable(system, 1)


def test_a_fraction_of_a_step_counts_for_nothing():
    # 1.99 RK4 steps where 2 are needed (the mode at 1.05 of one step's limit, its
    # bound at 1.6): refused, as the whole step it runs.
    system = _stiff()
    rate, _ = fastest_plant_mode(system)
    pwm = rate / RK4_STABLE_RADIUS / 1.05
    system = system.replace(pwm_hz=pwm, current_bandwidth_hz=pwm / 10)
    assert fastest_plant_mode_bound(system) < RK4_STABLE_RADIUS * pwm * 1.9
    with pytest.raises(ParameterError, match="substeps >= 2"):
        check_integrable(system, 1.99)


@pytest.mark.parametrize("f, refused", [(0.999, False), (1.001, True)])
def test_the_speed_command_counts_in_the_bound(f, refused):
    # The windings' rotation Nr*omega past one RK4 step's limit: refused with it.
    system = get_preset("patent")
    speed = RK4_STABLE_RADIUS * system.drive.pwm_hz / (2.0 * math.pi * system.motor.Nr) * f
    if refused:
        with pytest.raises(ParameterError, match="speed command"):
            check_integrable(system, 1, speed)
    else:
        check_integrable(system, 1, speed)


def test_real_motors_skip_the_eigenvalues(monkeypatch):
    from stepdamp_env import simulation

    def no_eigenvalues(*args, **kwargs):
        raise AssertionError("the eigenvalues were needed")

    monkeypatch.setattr(simulation, "required_substeps", no_eigenvalues)
    for system in _real_systems():
        check_integrable(system, 1, 10.0)
        terms = current_loop_terms(system)
        assert loop_surely_stable(*terms), system.name
