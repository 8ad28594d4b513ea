"""The baseline ladder: each method's own physics, and the orderings physics predicts."""

from __future__ import annotations

import cmath
import math

import numpy as np
import pytest

from stepdamp_baselines import BASELINE_NAMES, make_baseline
from stepdamp_baselines.feedback import design_gains, hold_response
from stepdamp_baselines.learning import CalibratedTable, RepetitiveControl, golden_section
from stepdamp_env.bench import (MotorKnowledge, PolicyContext, policy_env_options,
                                quick_protocol, run_leaderboard)
from stepdamp_env.bench.policy import policy_card
from stepdamp_env.bench.rig import CalibrationRig
from stepdamp_env.env.layout import HARMONIC_COS, HARMONIC_SIN, OBS
from stepdamp_env.params import DETENT_HARMONICS, FeedforwardModel, ParameterError
from stepdamp_env.presets import get_preset
from stepdamp_env.response import phasors
from stepdamp_env.simulation import RunSettings, SpeedProfile, simulate

LADDER = ("velocity-feedback", "sensorless-damping", "calibrated-table",
          "repetitive-control", "tuned-constant-gain", "oracle-floor")


def test_every_ladder_entry_is_registered_with_a_card():
    for name in LADDER:
        assert name in BASELINE_NAMES
        card = policy_card(make_baseline(name))
        assert card is not None and card.sensors and card.model
    assert policy_card(make_baseline("oracle-floor")).oracle
    assert not any(policy_card(make_baseline(n)).oracle for n in LADDER[:-1])


def test_only_an_oracle_may_ask_for_the_true_state():
    system = get_preset("patent")
    knowledge = MotorKnowledge(system, None, FeedforwardModel.from_motor(system.motor))
    assert policy_env_options(make_baseline("oracle-floor"), knowledge)["privileged"]

    class Cheat:
        name = "cheat"

        def env_options(self, knowledge):
            return {"privileged": True}

    with pytest.raises(ParameterError, match="privileged"):
        policy_env_options(Cheat(), knowledge)


@pytest.mark.parametrize("speed_rps", [0.67, 1.34, 2.69])
def test_back_emf_observer_tracks_the_true_speed_on_a_clean_run(speed_rps):
    # Stated error: within 10 % of the (low-passed) speed ripple RMS, mean within
    # 0.5 % of the command speed (measured 3-7 % and 0.1-0.2 %: the projection on
    # the command's angle reads w*cos(load angle)).
    system = get_preset("patent").replace(current_noise_a=0.0)
    r = simulate(system, profile=SpeedProfile(speed_rps=speed_rps, accel_rps2=50.0),
                 settings=RunSettings(velocity_estimator="back-emf", window_s=0.2), trace=True)
    dt = 1.0 / system.drive.pwm_hz
    alpha = 1.0 - math.exp(-2.0 * math.pi * system.servo.velocity_cutoff_hz * dt)
    w = r.trace["omega"]
    filtered = np.empty_like(w)
    acc = w[0]
    for i, x in enumerate(w):
        acc += alpha * (x - acc)
        filtered[i] = acc
    m = r.trace["t"] > r.window_start_s
    err = r.trace["omega_fb"][m] - filtered[m]
    assert np.std(err) < 0.10 * np.std(filtered[m])
    assert abs(err.mean()) < 0.005 * 2.0 * math.pi * speed_rps


def test_back_emf_estimate_ignores_the_encoder():
    base = get_preset("patent").replace(current_noise_a=0.0)
    runs = [simulate(base.replace(encoder_cpr=cpr), speed_rps=1.0,
                     settings=RunSettings(velocity_estimator="back-emf", window_s=0.05),
                     trace=True).trace["omega_fb"] for cpr in (400, 40000)]
    assert np.array_equal(runs[0], runs[1])


def test_design_gains_solve_the_two_real_equations():
    a, b = design_gains(complex(0.3, -0.7), complex(0.9, -0.2), complex(0.1, -1.1))
    assert abs(a * complex(0.9, -0.2) + b * complex(0.1, -1.1) - complex(0.3, -0.7)) < 1e-12
    # A hold of one PWM period is the period's delay.
    assert abs(hold_response(100.0, 20000.0, 20000.0) - cmath.exp(-1j * 100.0 / 20000.0)) < 1e-12


def test_tuned_constant_gain_is_v1_law_at_kv_and_checks_it():
    from stepdamp_baselines import TunedConstantGain
    from stepdamp_env.env import StepperDampV1Env

    policy = make_baseline("tuned-constant-gain")
    assert policy.env_id == "StepperDamp-v1"
    env = StepperDampV1Env(**{k: v for k, v in policy.env_options(
        MotorKnowledge(get_preset("patent"), None, None)).items() if k != "estimate"})
    assert env.action_space.contains(policy.act(None))
    assert policy.act(None)[0] == 0.5 and not policy.act(None)[1:].any()
    for bad in (1.5, float("nan")):
        with pytest.raises(ValueError, match="^kv="):
            TunedConstantGain(bad)


def test_golden_section_finds_a_minimum_and_never_ends_worse_than_its_start():
    x = golden_section(lambda v: (v - 0.3) ** 2, -1.0, 1.0, 30)
    assert abs(x - 0.3) < 1e-4
    bumpy = golden_section(lambda v: 0.0 if v == 0.9 else 1.0 + v, 0.0, 1.0, 8, start=0.9)
    assert bumpy == 0.9


def _context(system, mode="open-loop", speed_rps=1.0, model=None, rig=None, agent_hz=1000.0):
    exact = FeedforwardModel.from_motor(system.motor)
    knowledge = MotorKnowledge(system, model or exact, exact, plant=system, rig=rig)
    return PolicyContext(knowledge=knowledge, estimate=model or exact, mode=mode,
                         speed_rps=speed_rps, action_mode="harmonic",
                         action_scale=0.05, agent_hz=agent_hz, current_scale_a=1.0,
                         accel_rps2=50.0)


def test_repetitive_control_converges_on_a_pure_periodic_disturbance():
    # The ripple phasors are R_h = P_h*(D_h - A_h) for a detent D the start
    # table misses; learning must drive A to D within 40 electrical periods.
    system = get_preset("patent")
    ctx = _context(system, speed_rps=0.3)
    rc = RepetitiveControl(learning_gain=0.5, leak=1.0, guard_ratio=1e9)
    rc.reset(ctx)
    # The plant's response, scaled so that each learned harmonic's loop gain
    # (L*P) is 0.5 per period: this checks the per-period DFT and the update.
    p = np.where(rc._learn != 0, 0.5 / np.where(rc._learn != 0, rc._learn, 1.0), 0.0)
    detent = rc._start + np.array([0.004 + 0.003j, -0.002j, 0.0015])
    nr = system.motor.Nr
    obs = np.zeros(len(OBS) + 6, dtype=np.float32)
    steps = int(40 * ctx.agent_hz / (nr * ctx.speed_rps))
    first = None
    action = rc._action.copy()
    for k in range(rc._wait + steps):
        applied = rc._base + ctx.action_scale * (action[0::2] + 1j * action[1::2])
        x = 2.0 * math.pi * nr * ctx.speed_rps * k / ctx.agent_hz
        hx = np.array([h * x for h in DETENT_HARMONICS])
        ripple = p * (detent - applied)
        e = float(np.sum((ripple * np.exp(1j * hx)).imag))
        obs[OBS.velocity_error] = e / rc._w_ref
        obs[HARMONIC_SIN] = np.sin(hx)
        obs[HARMONIC_COS] = np.cos(hx)
        action = rc.act(obs)
        if first is None and k > rc._wait:
            first = np.abs(detent - applied)
    learned = rc._learn != 0
    final = np.abs(detent - (rc._base + ctx.action_scale * (action[0::2]
                                                            + 1j * action[1::2])))
    assert learned.any()
    assert np.all(final[learned] < 0.05 * first[learned])


def test_calibration_finds_a_planted_phase_error():
    # The drive's model has the first harmonic's phase 30 degrees off; the rig
    # (clean sensors) must put the table's h1 torque within 5 degrees of the
    # plant's detent phasor.
    system = get_preset("patent").replace(current_noise_a=0.0)
    exact = FeedforwardModel.from_motor(system.motor)
    wrong = FeedforwardModel(**{**exact.__dict__, "phi1": exact.phi1 + math.radians(30.0)})
    rig = CalibrationRig(system, noise_seed=0, accel_rps2=50.0)
    ctx = _context(system, model=wrong, rig=rig)
    table = CalibratedTable()
    torque, seconds = table._calibrate(ctx.knowledge, "open-loop", wrong)
    error = math.degrees(abs(cmath.phase(torque[0] / phasors(exact)[0])))
    assert error < 5.0, error
    assert seconds > 0.0


def _headlines(board, suite):
    return {e["name"]: e["headline"]["iqm"] for e in board["entries"] if e["suite"] == suite}


@pytest.fixture(scope="module")
def quick_board():
    names = ("patent-ff-identified", "ff-delay-comp") + LADDER
    return run_leaderboard(quick_protocol(), names, workers=2, progress=False)


@pytest.mark.slow
def test_ladder_orderings_on_the_quick_protocol(quick_board):
    h = _headlines(quick_board, "open-loop")
    best = min(v for k, v in h.items() if k not in ("oracle-floor", "none"))
    assert h["oracle-floor"] <= 0.8 * best
    assert h["velocity-feedback"] < h["ff-delay-comp"]
    assert h["tuned-constant-gain"] < h["ff-delay-comp"]
    assert h["sensorless-damping"] < h["ff-delay-comp"]
    assert h["calibrated-table"] < h["patent-ff-identified"]
    assert h["repetitive-control"] < h["patent-ff-identified"]


def test_entries_outside_their_suites_are_reported_not_run(quick_board):
    servo = _headlines(quick_board, "servo")
    assert "sensorless-damping" not in servo and "velocity-feedback" not in servo
    reasons = {(x["name"], x["suite"]): x["reason"] for x in quick_board["not_run"]}
    assert "encoder" in reasons[("sensorless-damping", "servo")]
    knowledge = {e["name"]: e.get("knowledge", "") for e in quick_board["entries"]}
    assert "oracle" in knowledge["oracle-floor"]
    assert "no encoder" in knowledge["sensorless-damping"]
    calib = [r["calibration_s"] for e in quick_board["entries"] if e["name"] ==
             "calibrated-table" for r in e["runs"]]
    assert min(calib) > 0.0
