"""plant-bound: the law it runs is the best its rehearsal on the true plant found,
the choice does not depend on the order or the cache, and its feedforward
carries the rotor's lag from a load torque (oracle-floor's does not)."""

import math

import pytest

from stepdamp_baselines import make_baseline
from stepdamp_baselines import plant_bound as pb
from stepdamp_baselines.feedback import PrivilegedBound
from stepdamp_env.bench.policy import MotorKnowledge, policy_context, policy_env_options
from stepdamp_env.bench.runner import EpisodeSpec, run_episode, run_episodes
from stepdamp_env.params import FeedforwardModel
from stepdamp_env.presets import get_preset

WINDOW_S = 0.1


def _case(load_torque=0.0):
    system = get_preset("qsh4218-51-10-049")
    if load_torque:
        system = system.replace(load_torque=load_torque)
    know = MotorKnowledge(nominal=system, identified=None,
                          exact=FeedforwardModel.from_motor(system.motor), plant=system)
    return system, know


def _context(policy, know, speed, mode="open-loop"):
    return policy_context(policy_env_options(policy, know), know, mode, speed,
                          window_s=WINDOW_S)


def _rms(r):
    return math.inf if r.failed or r.metrics is None else r.metrics["rms_velocity_error_rad_s"]


def test_a_batch_of_laws_and_tables_gives_each_run_the_bits_it_has_alone():
    """The rehearsals step many laws and tables in one batch (a third of the time on
    v4's quick board): each run must be the run of its law and table alone."""
    system, know = _case()
    spec = EpisodeSpec(know, system, min(system.predicted_resonances_rps().values()),
                       pb.SELECTION_SEED)
    run = dict(mode="open-loop", window_s=WINDOW_S)
    table = (0.002, 0.0, 0.0, 0.001, 0.0, 0.0)
    rows = [(0, ("zeta", 0.5), None), (0, ("kv", 0.5), table), (0, ("zeta", 0.5), table),
            (0, ("kv", 0.5), None)]
    mixed = pb._rehearse([spec], rows, run)
    for row, got in zip(rows, mixed):
        assert got.metrics == pb._rehearse([spec], [row], run)[0].metrics
        if row[2] is None:
            alone = run_episodes(lambda: pb.PortfolioLaw(row[1]), [spec], **run)[0]
            assert got.metrics == alone.metrics
    assert mixed[0].metrics != mixed[2].metrics        # the table is applied


@pytest.mark.slow
def test_the_law_it_runs_is_the_best_of_its_rehearsal_whatever_the_order():
    system, know = _case()
    speeds = sorted(system.predicted_resonances_rps().values())[:2]
    portfolio = (("zeta", 0.0), ("zeta", 0.5), ("kv", 0.5))
    bound = pb.PlantBound(portfolio)
    chosen = [bound.choice(_context(bound, know, v)) for v in speeds]
    # Rehearse every law by hand: the choice is the argmin of the selection runs.
    specs = [EpisodeSpec(know, system, v, pb.SELECTION_SEED) for v in speeds]
    rms = {law: [_rms(r) for r in run_episodes(lambda law=law: pb.PortfolioLaw(law), specs,
                                               mode="open-loop", window_s=WINDOW_S)]
           for law in portfolio}
    for i in range(len(speeds)):
        assert chosen[i] == min(portfolio, key=lambda law: rms[law][i])
    # A cold cache and the other order give the same choices.
    pb._CHOICES.clear()
    again = pb.PlantBound(portfolio)
    contexts = [_context(again, know, v) for v in reversed(speeds)]
    again.reset_batch(contexts)
    assert [again.choice(c) for c in contexts] == chosen[::-1]


@pytest.mark.slow
def test_its_feedforward_carries_the_lag_of_a_load_torque():
    # With a load of a third of the holding torque the rotor trails its command:
    # the detent it feels is shifted, and a feedforward that ignores that
    # (oracle-floor's exact model, privileged-bound) leaves ripple. No feedback
    # (zeta 0): the feedforwards alone differ.
    system, know = _case()
    system, know = _case(load_torque=0.3 * system.motor.Km * system.drive.holding_current)
    speed = system.predicted_resonances_rps()[4]
    law = pb.PortfolioLaw(("zeta", 0.0))
    old = PrivilegedBound({s: (0.0, 5000.0, "delay-comp")
                           for s in ("open-loop", "servo", "mid-band")})
    new_rms, old_rms = (_rms(run_episode(p, know, system, mode="open-loop", speed_rps=speed,
                                         seed=1, window_s=WINDOW_S)) for p in (law, old))
    assert new_rms < 0.5 * old_rms, (new_rms, old_rms)


def test_the_load_angle_holds_the_torque_on_the_spring():
    # Km*I*sin(Nr*delta) = Fs + D*w + load (the load opposes positive rotation).
    system, know = _case()
    system, know = _case(load_torque=0.4 * system.motor.Km * system.drive.holding_current)
    m, i = system.motor, system.drive.holding_current
    law = pb.PortfolioLaw(("zeta", 0.0))
    for speed in (0.5, -0.5):
        angle = law.load_angle(_context(law, know, speed), system)
        held = m.Fs + m.D * 2.0 * math.pi * 0.5 + m.load_torque * math.copysign(1.0, speed)
        assert m.Km * i * math.sin(angle) == pytest.approx(held, rel=1e-12)
    assert law.load_angle(_context(law, know, 0.5, mode="servo"), system) == 0.0


def test_a_bad_portfolio_is_a_one_line_error():
    for bad in ((), (("gain", 1.0),), (("zeta", -1.0),), (("kv", math.nan),)):
        with pytest.raises(ValueError, match="portfolio=.*'zeta' or 'kv'") as info:
            pb.PlantBound(bad)
        assert "\n" not in str(info.value)
    for name in ("table_steps", "table_laws"):
        with pytest.raises(ValueError, match=rf"{name}=-1 is outside \[0, 10\]"):
            pb.PlantBound(**{name: -1})


def test_it_is_registered_as_a_privileged_entry():
    bound = make_baseline("plant-bound")
    assert bound.card.oracle and "true plant" in bound.card.model


@pytest.mark.slow
def test_its_harmonic_table_cancels_the_harmonics_the_law_leaves_in_the_mid_band():
    """On the voltage-mode drive no law of the portfolio removes the detent
    harmonics' ripple; the table learnt on the plant does (patent~i0 at its
    mid-band speed m0.3: rms 0.097 -> 0.028 rad/s, h = 1 and 2 to 0.0 rad/s)."""
    from stepdamp_env.bench.protocols.v4 import quick_protocol_v4

    motor = next(m for m in quick_protocol_v4().motors() if m.name == "patent~i0")
    motor = motor.for_suite("mid-band")
    speed = dict(zip(motor.speeds("mid-band").labels, motor.speeds("mid-band").speeds_rps))["m0.3"]
    know = MotorKnowledge(nominal=motor.nominal, identified=None,
                          exact=FeedforwardModel.from_motor(motor.system.motor), plant=motor.system)
    runs = {steps: run_episode(pb.PlantBound(table_steps=steps), know, motor.system,
                               mode="open-loop", speed_rps=speed, seed=1_000_000,
                               window_s=WINDOW_S, settle_s=motor.settle_s("mid-band"),
                               suite="mid-band") for steps in (0, 2)}
    assert _rms(runs[2]) < 0.5 * _rms(runs[0])
    before, after = (runs[s].metrics["harmonic_amplitude_rad_s"] for s in (0, 2))
    for h in ("1", "2"):
        assert after[h] < 0.05 * before[h], (h, before, after)
    # Its table is cached with the law: the same on a second ask.
    bound = pb.PlantBound()
    ctx = policy_context(policy_env_options(bound, know), know, "open-loop", speed,
                         suite="mid-band", window_s=WINDOW_S, settle_s=motor.settle_s("mid-band"))
    assert bound.table(ctx) is not None and bound.table(ctx) == bound.table(ctx)
