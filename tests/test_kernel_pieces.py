"""The small njit pieces, each against an identity or an analytic result."""

from __future__ import annotations

import math

import numpy as np
import pytest

from stepdamp_env import fixedmath as fm
from stepdamp_env import kernel as K
from stepdamp_env.presets import get_preset
from stepdamp_env.simulation import RunSettings, SpeedProfile, build_config

RNG = np.random.default_rng(1234)


def test_sincos_matches_libm_to_an_ulp_or_two():
    xs = np.concatenate([RNG.uniform(-1e5, 1e5, 20000), RNG.uniform(-7, 7, 20000),
                         np.arange(-8, 9) * math.pi / 4])
    for x in xs:
        s, c = fm.sincos(float(x))
        assert abs(s - math.sin(x)) <= 4e-16 * max(1.0, 1.0)
        assert abs(c - math.cos(x)) <= 4e-16


def test_sincos_shifted_equals_direct_evaluation():
    # Small x0 so that rounding x0 + d itself (an ulp of x0) stays below the bound.
    for x0, d in zip(RNG.uniform(-3, 3, 5000), RNG.uniform(-0.3, 0.3, 5000)):
        s0, c0 = math.sin(x0), math.cos(x0)
        s, c = fm.sincos_shifted(x0, s0, c0, d)
        assert abs(s - math.sin(x0 + d)) < 2e-15
        assert abs(c - math.cos(x0 + d)) < 2e-15


def test_park_round_trip_and_magnitude():
    for ia, ib, a in RNG.uniform(-5, 5, (2000, 3)) * np.array([1, 1, 40]):
        d, q = K.park(ia, ib, a)
        assert math.hypot(d, q) == pytest.approx(math.hypot(ia, ib), rel=1e-14, abs=1e-15)
        a2, b2 = K.inverse_park(d, q, a)
        assert a2 == pytest.approx(ia, abs=1e-13)
        assert b2 == pytest.approx(ib, abs=1e-13)


def test_park_matches_physics_notes_definition():
    # id = ia cos a + ib sin a, iq = -ia sin a + ib cos a; a current along the
    # angle is pure d, a quarter turn ahead is pure q.
    a = 0.7
    d, q = K.park(math.cos(a), math.sin(a), a)
    assert (d, q) == pytest.approx((1.0, 0.0), abs=1e-15)
    d, q = K.park(-math.sin(a), math.cos(a), a)
    assert (d, q) == pytest.approx((0.0, 1.0), abs=1e-15)


@pytest.mark.parametrize("vdc", [12.0, 48.0])
def test_svpwm_legs_inside_bus_and_exact_when_feasible(vdc):
    feasible = 0
    for va, vb in RNG.uniform(-1.2 * vdc, 1.2 * vdc, (5000, 2)):
        legs = K.svpwm_legs(va, vb, vdc)
        assert all(0.0 <= v <= vdc for v in legs)
        app_a, app_b = legs[0] - legs[2], legs[1] - legs[2]
        span = max(va, vb, 0.0) - min(va, vb, 0.0)
        if span <= vdc:
            feasible += 1
            assert app_a == pytest.approx(va, abs=1e-12)
            assert app_b == pytest.approx(vb, abs=1e-12)
        else:
            # Saturated: the applied span is the whole bus, never more.
            app_span = max(app_a, app_b, 0.0) - min(app_a, app_b, 0.0)
            assert app_span == pytest.approx(vdc, abs=1e-12)
    assert 1000 < feasible < 5000


def test_svpwm_centres_the_common_leg():
    # eq. 13: v0 = Vdc/2 - (vmax + vmin)/2.
    legs = K.svpwm_legs(10.0, -4.0, 48.0)
    assert legs[2] == pytest.approx(24.0 - 3.0)
    assert legs[0] == pytest.approx(31.0)
    assert legs[1] == pytest.approx(17.0)


def test_pi_update_plain_when_unsaturated_and_tracks_when_saturated():
    kp, ki, dt = 2.0, 500.0, 5e-5
    integ = 0.3
    assert K.pi_update(1.5, integ, 3.3, 3.3, kp, ki, dt) == pytest.approx(integ + dt * ki * 1.5)
    # Saturated at 1 V with a persistent error: the integrator settles where
    # kp*e + integ equals what is achievable plus e*kp... i.e. it stays bounded.
    integ = 0.0
    e = 1.0
    for _ in range(200000):
        out = K.pi_output(e, integ, kp)
        integ = K.pi_update(e, integ, out, min(out, 1.0), kp, ki, dt)
    assert abs(integ) < 2.0     # without anti-windup it would be ki*e*t = 5000 V


def test_harmonic_series_identities():
    for x in RNG.uniform(-50, 50, 500):
        s1, c1 = math.sin(x), math.cos(x)
        s2, c2, s4, c4 = K.harmonics(s1, c1)
        assert s2 == pytest.approx(math.sin(2 * x), abs=1e-14)
        assert c2 == pytest.approx(math.cos(2 * x), abs=1e-14)
        assert s4 == pytest.approx(math.sin(4 * x), abs=1e-13)
        assert c4 == pytest.approx(math.cos(4 * x), abs=1e-13)


def _config(system=None):
    system = system or get_preset("patent")
    return build_config(system, SpeedProfile(1.0), RunSettings())


def test_parameter_tuples_are_read_by_their_named_positions():
    # Distinct values everywhere, so a wrong position cannot pass by accident.
    c = 1.5 + np.arange(len(K.CONFIG), dtype=np.float64)
    p, q = K.plant_params(c), K.controller_params(c)
    assert len(p) == len(K.PLANT) and len(q) == len(K.CTRL)
    inverted = {"INV_L": "L", "INV_J": "J"}
    for name in K.PLANT._fields:
        if name in inverted:
            assert p[getattr(K.PLANT, name)] == 1.0 / c[getattr(K.CONFIG, inverted[name])]
        else:
            assert p[getattr(K.PLANT, name)] == c[getattr(K.CONFIG, name)], name
    for name in K.CTRL._fields:
        assert q[getattr(K.CTRL, name)] == c[getattr(K.CONFIG, name)], name


def test_layouts_are_dense_and_described():
    from stepdamp_env.fields import describe, layout

    for lay in (K.CONFIG, K.PLANT, K.CTRL, K.STATE, K.ACC, K.INPUT, K.LAW, K.TRACE):
        assert list(lay) == list(range(len(lay)))
        assert set(describe(lay)) == set(type(lay)._fields)
    assert K.TRACE_UNITS["omega"] == "rad/s" and K.TRACE_NAMES[0] == "t"
    with pytest.raises(ValueError, match="repeats"):
        layout("Bad", "A\nA")
    rows = layout("Rows", "X  first\nG[3]  gain j (A)\nY")
    assert type(rows).__name__ == "Rows" and rows.G + 2 == rows.G_2
    assert type(rows)._fields == ("X", "G", "G_1", "G_2", "Y")
    assert describe(rows)["G"] == "gain j (A)"
    for bad in ("G[0]", "G[x]", "G[2"):
        with pytest.raises(ValueError, match="NAME\\[n\\]"):
            layout("Bad", bad)


def test_detent_torque_is_the_patent_expression_and_minus_gradient_of_potential():
    system = get_preset("patent")
    m = system.motor
    p = K.plant_params(_config(system))
    for th in RNG.uniform(-3, 3, 300):
        x = m.Nr * th
        expected = -(m.Kd4 * math.sin(4 * x) + m.Kd2 * math.sin(2 * x + m.phi2)
                     + m.Kd1 * math.sin(x + m.phi1))
        assert K.detent_torque(th, p) == pytest.approx(expected, abs=1e-15)
        h = 1e-6
        grad = (K.detent_potential(th + h, p) - K.detent_potential(th - h, p)) / (2 * h)
        assert -grad == pytest.approx(expected, abs=1e-9)


def test_back_emf_power_equals_torque_times_speed():
    p = K.plant_params(_config())
    R, inv_l = p[K.PLANT.R], p[K.PLANT.INV_L]
    for th, w, ia, ib in RNG.uniform(-1, 1, (1000, 4)) * np.array([10, 50, 3, 3]):
        d = K.motor_derivative(th, w, ia, ib, 0.0, 0.0, p)
        # With va = vb = 0: L di/dt = -R i - e, so -e = L di/dt + R i.
        ea = -(d[2] / inv_l + R * ia)
        eb = -(d[3] / inv_l + R * ib)
        x = p[K.PLANT.NR] * th
        tau_em = p[K.PLANT.KM] * (-ia * math.sin(x) + ib * math.cos(x))
        assert ea * ia + eb * ib == pytest.approx(tau_em * w, rel=1e-12, abs=1e-12)


def test_winding_power_splits_into_copper_magnetic_and_mechanical():
    p = K.plant_params(_config())
    R, L = p[K.PLANT.R], 1.0 / p[K.PLANT.INV_L]
    for th, w, ia, ib, va, vb in RNG.uniform(-1, 1, (500, 6)) * np.array([5, 30, 2, 2, 40, 40]):
        d = K.motor_derivative(th, w, ia, ib, va, vb, p)
        x = p[K.PLANT.NR] * th
        tau_em = p[K.PLANT.KM] * (-ia * math.sin(x) + ib * math.cos(x))
        p_in = va * ia + vb * ib
        assert d[4] == pytest.approx(p_in, rel=1e-14, abs=1e-14)
        rhs = R * (ia**2 + ib**2) + L * (ia * d[2] + ib * d[3]) + tau_em * w
        assert p_in == pytest.approx(rhs, rel=1e-10, abs=1e-10)


def test_friction_sign_and_breakaway():
    assert K.friction_torque(2.0, 5.0, 0.01) == 0.01
    assert K.friction_torque(-2.0, 5.0, 0.01) == -0.01
    assert K.friction_torque(0.0, 0.004, 0.01) == 0.004      # holds below breakaway
    assert K.friction_torque(0.0, -0.5, 0.01) == -0.01       # capped at breakaway


def test_quantise_floors_to_the_grid():
    q = 2 * math.pi / 4000
    for x in RNG.uniform(-10, 10, 1000):
        y = K.quantise(x, q)
        assert y <= x + 1e-15 and x - y < q + 1e-15
        assert abs(y / q - round(y / q)) < 1e-6


@pytest.mark.parametrize("distance", [3.0, -2.0, 0.05])
def test_move_profile_integrates_to_its_distance(distance):
    two_pi = 2 * math.pi
    speed, accel = two_pi * 2.0, two_pi * 20.0
    prof = SpeedProfile(speed_rps=2.0, accel_rps2=20.0, kind="move", distance_rev=distance)
    t_end = prof.duration_s()
    ts = np.linspace(0, t_end * 1.1, 40001)
    th, w = zip(*(K.command(t, 1, speed, accel, two_pi * distance) for t in ts))
    th, w = np.array(th), np.array(w)
    assert th[-1] == pytest.approx(two_pi * distance, abs=1e-12)
    assert w[-1] == 0.0
    assert np.max(np.abs(w)) <= speed + 1e-12
    # The speed command is the derivative of the position command.
    integral = np.concatenate([[0], np.cumsum(0.5 * (w[1:] + w[:-1]) * np.diff(ts))])
    assert np.max(np.abs(integral - th)) < 1e-5


def test_constant_profile_ramps_then_holds():
    two_pi = 2 * math.pi
    th, w = K.command(0.01, 0, two_pi, two_pi * 50, 0.0)
    assert w == pytest.approx(two_pi * 50 * 0.01)
    assert th == pytest.approx(0.5 * two_pi * 50 * 0.01**2)
    th, w = K.command(1.0, 0, two_pi, two_pi * 50, 0.0)
    assert w == two_pi
    assert th == pytest.approx(two_pi * (0.5 * 0.02 + (1.0 - 0.02)))
