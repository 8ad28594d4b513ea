"""What identification from drive logs says about its own accuracy: the stated
uncertainty per coefficient, the warnings above 5 %, the prior's J where the
logs do not give it, and the logs ``identify --plan`` asks for
(docs/drivelogs.md, "Uncertainty" and "Accuracy")."""

from __future__ import annotations

import os

import pytest

from stepdamp_env.cli import main
from stepdamp_env.drivelog import trace_table
from stepdamp_env.logfit import MAX_UNCERTAINTY, PRIOR_J_UNCERTAINTY, identify_from_tables
from stepdamp_env.logplan import PLAN_SPEEDS_PER_F4, log_plan
from stepdamp_env.motorfile import load_system
from stepdamp_env.presets import get_preset
from stepdamp_env.simulation import RunSettings, SpeedProfile, simulate

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
CATALOGUE = os.path.join(ROOT, "docs", "motors", "17hs4401.json")
AMPLITUDES = ("Kd1", "Kd2", "Kd4")


def _log(system, speed_rps, mode, seed, duration_s):
    run = simulate(system, profile=SpeedProfile(speed_rps=speed_rps),
                   settings=RunSettings(mode=mode, noise_seed=seed), duration_s=duration_s,
                   trace=True)
    return trace_table(run)


def _errors(result, truth):
    return {n: getattr(result.model, n) / getattr(truth.motor, n) - 1.0 for n in AMPLITUDES}


def _held_out():
    """No preset: the patent's drive with a 1.5x rotor and other detent, noisy sensors."""
    return get_preset("patent").replace(
        name="held-out", J=6.0e-5, Kd1=0.005, Kd2=0.0042, Kd4=0.015, phi1=0.3, phi2=-0.8,
        Fs=0.003, current_noise_a=0.01)


@pytest.mark.parametrize("mode", ["servo", "open-loop"])
@pytest.mark.parametrize("which", ["catalogue", "held-out"])
def test_the_planned_logs_identify_within_5_percent_with_a_prior_j_15_percent_off(which, mode):
    truth = load_system(CATALOGUE).replace(current_noise_a=0.01) if which == "catalogue" \
        else _held_out()
    prior = truth.replace(J=1.15 * truth.motor.J)
    plan = log_plan(prior)
    tables = [_log(truth, v, mode, k, d)
              for k, (v, d) in enumerate(zip(plan.speeds_rps, plan.durations_s))]
    result = identify_from_tables(prior, tables)
    errors = _errors(result, truth)
    assert max(abs(e) for e in errors.values()) < 0.05, errors
    assert all(result.relative_uncertainty(n) < MAX_UNCERTAINTY for n in AMPLITUDES)
    assert not [w for w in result.warnings if w.startswith("uncertain")]
    assert result.fitted == ("J", "D") and abs(result.J / truth.motor.J - 1.0) < 0.05
    # The prior's J is 15 % off: within PRIOR_J_UNCERTAINTY, so no note.
    assert not [w for w in result.warnings if "prior disagrees" in w and " J " in w]


def test_one_log_above_the_resonance_warns_and_its_uncertainty_covers_the_error():
    """One speed: J is the prior's (here 20 % high) and its uncertainty is carried
    into the harmonics, which above the h=4 resonance depend on J: warned."""
    truth = load_system(CATALOGUE).replace(current_noise_a=0.01)
    prior = truth.replace(J=1.2 * truth.motor.J)
    f4 = prior.predicted_resonances_rps()[4]
    result = identify_from_tables(prior, [_log(truth, 1.3 * f4, "servo", 0, 1.2)])
    assert result.fitted == ()
    assert result.uncertainty["J"] == pytest.approx(PRIOR_J_UNCERTAINTY * prior.motor.J)
    assert "D" not in result.uncertainty
    errors = _errors(result, truth)
    assert max(abs(e) for e in errors.values()) > 0.1              # it is off ...
    assert any(w.startswith("uncertain: ") and "identify --plan" in w for w in result.warnings)
    for name in AMPLITUDES:                                          # ... and says by how much
        assert abs(errors[name]) < 3.0 * result.relative_uncertainty(name), name
    assert any("J and D are the prior's, and the harmonics only as right as its J" in w
               for w in result.warnings)


def test_j_fitted_above_the_resonance_is_warned_of():
    truth = get_preset("patent").replace(current_noise_a=0.01)
    f4 = truth.predicted_resonances_rps()[4]
    tables = [_log(truth, k * f4, "servo", seed, 1.2) for seed, k in enumerate((1.2, 2.4))]
    result = identify_from_tables(truth, tables)
    assert result.fitted == ("J", "D")
    assert any(w.startswith("J fitted from logs above the h=4 resonance") for w in
               result.warnings)


def test_the_stated_uncertainty_grows_with_the_sensor_noise():
    """The fit's covariance part follows the noise in the logs (the same logs,
    10x the current-sensor noise)."""
    stated = []
    for noise in (0.005, 0.05):
        truth = get_preset("qsh4218-51-10-049").replace(current_noise_a=noise)
        plan = log_plan(truth)
        tables = [_log(truth, v, "servo", k, d)
                  for k, (v, d) in enumerate(zip(plan.speeds_rps, plan.durations_s))]
        stated.append(identify_from_tables(truth, tables).relative_uncertainty("Kd1"))
    assert stated[1] > 2.0 * stated[0], stated


def test_a_prior_far_from_the_logs_gets_a_note():
    truth = _held_out()
    prior = truth.replace(J=2.0 * truth.motor.J, Kd4=0.5 * truth.motor.Kd4)
    plan = log_plan(prior)
    tables = [_log(truth, v, "servo", k, d)
              for k, (v, d) in enumerate(zip(plan.speeds_rps, plan.durations_s))]
    notes = [w for w in identify_from_tables(prior, tables).warnings if "prior disagrees" in w]
    assert len(notes) == 2 and "J 0.00012 kg*m^2 against the logs' 5.9" in notes[0]
    assert "load" not in notes[0]                     # the prior is the heavier
    assert "Kd4 0.0075 N*m against the logs' 0.015" in notes[1]


def test_the_plan_and_its_command(capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    system = load_system(CATALOGUE)
    plan = log_plan(system)
    f4 = system.predicted_resonances_rps()[4]
    assert plan.f4_rps == f4
    assert plan.speeds_rps == pytest.approx([k * f4 for k in PLAN_SPEEDS_PER_F4])
    for v, d in zip(plan.speeds_rps, plan.durations_s):
        assert d >= 1.0 and (d - plan.settle_s) * system.motor.Nr * v >= 40.0 - 1e-9
    assert main(["identify", "--plan", CATALOGUE]) == 0
    out = capsys.readouterr().out
    assert f"h=4 resonance is at {f4:.4g} rev/s" in out
    assert all(f"{v:.4g} rev/s" in out for v in plan.speeds_rps)
    assert "in open loop" in out and "stick-slip" not in out
    assert "--log log1.csv --log log2.csv --log log3.csv" in out
    assert main(["identify", "--motor", CATALOGUE, "--plan"]) == 0
    assert capsys.readouterr().out == out
    assert not os.listdir(tmp_path)
    assert main(["identify", "--motor", "patent"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--out" in err[0]
    assert main(["identify", "--plan", "patent", "--out", "x"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "without --log and --out" in err[0]
    assert main(["identify", "--plan", "patent", "--set", "J=8e-5", "--settle", "0.2"]) == 0
    assert "then: stepdamp identify --motor patent --set J=8e-5 --settle 0.2 --log" in \
        capsys.readouterr().out


def test_the_effort_methods_bias_on_a_light_axis_is_warned():
    """Claim 1's effort fit is 15-18 % off on Kd2 and Kd4 here (docs/drivelogs.md):
    its logs disagree, and it says so."""
    truth = _held_out()
    tables = [_log(truth, v, "servo", k, 1.2) for k, v in enumerate((0.2, 0.3, 0.45))]
    result = identify_from_tables(get_preset("patent"), tables, method="effort")
    errors = _errors(result, truth)
    assert max(abs(errors["Kd2"]), abs(errors["Kd4"])) > 0.1
    assert any(w.startswith("uncertain: Kd2") and "Kd4" in w for w in result.warnings)
    for name in AMPLITUDES:
        assert abs(errors[name]) < 3.0 * result.relative_uncertainty(name), name


def test_the_plan_asks_for_open_loop_and_says_where_a_servo_stick_slips(capsys):
    """On a catalogue motor whose servo stalls and reverses at the plan's speeds
    (qsh4218-35-10-027 with the v4 sensors), the plan says so, its open-loop logs
    identify within 5 % and the servo's come out over 10 % off, warned
    (benchmarks/identify_plan_catalogue.py measures all 27 motors)."""
    from stepdamp_env.bench.protocols.v4 import catalogue_systems, full_protocol_v4
    from stepdamp_env.logplan import servo_reversals

    truth = catalogue_systems(full_protocol_v4(), ["qsh4218-35-10-027"])[0]
    plan = log_plan(truth)
    assert plan.servo_stick_slip == (True, True, True)
    assert not any(log_plan(get_preset("patent")).servo_stick_slip)
    assert servo_reversals(get_preset("patent"), plan.speeds_rps[0], 1.0) == 0
    found = {}
    for mode in ("open-loop", "servo"):
        tables = [_log(truth, v, mode, k, d)
                  for k, (v, d) in enumerate(zip(plan.speeds_rps, plan.durations_s))]
        result = identify_from_tables(truth, tables)
        found[mode] = (max(abs(e) for e in _errors(result, truth).values()), result.warnings)
    assert found["open-loop"][0] < 0.05
    assert found["servo"][0] > 0.10 and any("backwards" in w for w in found["servo"][1])
    assert plan.to_dict()["servo_stick_slip"] == [True, True, True]


def test_servo_logs_off_beyond_their_stated_uncertainty_are_warned_of():
    """On `qsh5718-41-28-055` (a catalogue motor, the v4 sensors) the plan's
    servo logs come out 6-8 % off with every stated uncertainty under 5 %: the
    servo-log warning says so. Its open-loop logs identify within 5 % without
    it (benchmarks/identify_plan_catalogue.py measures all 27 motors)."""
    from stepdamp_env.bench.protocols.v4 import catalogue_systems, full_protocol_v4

    truth = catalogue_systems(full_protocol_v4(), ["qsh5718-41-28-055"])[0]
    plan = log_plan(truth)
    found = {}
    for mode in ("open-loop", "servo"):
        tables = [_log(truth, v, mode, k, d)
                  for k, (v, d) in enumerate(zip(plan.speeds_rps, plan.durations_s))]
        result = identify_from_tables(truth, tables)
        found[mode] = (max(abs(e) for e in _errors(result, truth).values()), result)
    error, servo = found["servo"]
    assert 0.05 < error < 0.10                                   # off ...
    assert all(servo.relative_uncertainty(n) < MAX_UNCERTAINTY for n in AMPLITUDES)
    assert [w for w in servo.warnings if "servo logs: " in w] == [
        "servo logs: on 3 of 81 simulated catalogue identifications servo logs came out "
        "6-8 % off with every stated uncertainty under 5 %; open-loop logs, as `stepdamp "
        "identify --plan` asks, within 2.7 %"]                   # ... and warned
    error, open_loop = found["open-loop"]
    assert error < 0.05 and not [w for w in open_loop.warnings if "servo" in w]
