"""Datasheet motor files (docs/motors.md), `stepdamp motors`, and boards that
stay readable on any motor (a suite without scores, a privileged entry worse
than no damping)."""

from __future__ import annotations

import copy
import json
import math
import os

import numpy as np
import pytest

from stepdamp_env.analysis import bridge_limit_rps, rotor_damping
from stepdamp_env.cli import main
from stepdamp_env.motorfile import (DAMPING_RATIO, DETENT_FRACTION, DETENT_SPLIT,
                                    FRICTION_FRACTION, describe, describe_spec)
from stepdamp_env.params import ParameterError
from stepdamp_env.motorfile import load_system, system_from_mapping

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
EXAMPLE = os.path.join(ROOT, "docs", "motors", "17hs4401.json")

SHEET = {"step_angle_deg": 1.8, "rated_current_A": 1.7, "holding_torque_Nm": 0.40,
         "phase_resistance_ohm": 1.5, "phase_inductance_H": 2.8e-3,
         "rotor_inertia_kgm2": 5.4e-6, "detent_torque_Nm": 0.022,
         "load_inertia_kgm2": 2.7e-5, "bus_voltage_V": 24.0}


def test_datasheet_conversion_formulas():
    s = system_from_mapping(SHEET)
    m, d = s.motor, s.drive
    assert m.Nr == 50
    assert d.holding_current == pytest.approx(math.sqrt(2) * 1.7, rel=1e-15)
    # Both phases on at the rated current give the holding torque.
    assert m.Km * d.holding_current == pytest.approx(0.40, rel=1e-15)
    assert (m.R, m.L, d.Vdc) == (1.5, 2.8e-3, 24.0)
    assert m.J == pytest.approx(5.4e-6 + 2.7e-5, rel=1e-15)
    for h, k in ((1, m.Kd1), (2, m.Kd2), (4, m.Kd4)):
        assert k == pytest.approx(DETENT_SPLIT[h] * 0.022, rel=1e-15)
    assert sum(DETENT_SPLIT.values()) == pytest.approx(1.0)
    stiffness = 0.40 * 50                           # N*m/rad: Km * I * Nr
    assert m.D / (2 * math.sqrt(stiffness * m.J)) == pytest.approx(DAMPING_RATIO)
    assert m.Fs == pytest.approx(FRICTION_FRACTION * 0.40)
    assert system_from_mapping({**SHEET, "step_angle_deg": 0.9}).motor.Nr == 100


def test_holding_current_given_keeps_km_from_the_rated_current():
    s = system_from_mapping({**SHEET, "holding_current": 2.0})
    assert s.drive.holding_current == 2.0
    assert s.motor.Km == pytest.approx(0.40 / (math.sqrt(2) * 1.7))


@pytest.mark.parametrize("load", [0.0, 2.7e-5, 2e-4])
def test_resonances_follow_the_holding_torque_stiffness(load):
    s = system_from_mapping({**SHEET, "load_inertia_kgm2": load})
    j = 5.4e-6 + load
    for h, v in s.predicted_resonances_rps().items():
        assert v == pytest.approx(math.sqrt(50 * 0.40 / j) / (2 * math.pi * h * 50), rel=1e-12)
    # The linearised drive (current loops included) puts the rotor mode within
    # a few per cent of the rigid-spring formula: the current loop's small shift.
    mode = rotor_damping(s, 0.05)
    assert abs(mode.eigenvalue) == pytest.approx(s.natural_frequency(), rel=0.05)
    assert mode.damping_ratio > 0


def test_servo_gains_follow_the_motor():
    light = system_from_mapping({**SHEET, "load_inertia_kgm2": 0.0})
    heavy = system_from_mapping({**SHEET, "load_inertia_kgm2": 2e-4})
    ws = 2 * math.pi * 100.0 / 5
    for s in (light, heavy):
        kv, kp, ki = s.servo_gains()
        assert (kv, kp, ki) == pytest.approx((3 * s.motor.J * ws, 3 * s.motor.J * ws ** 2,
                                              s.motor.J * ws ** 3))
    assert heavy.servo_gains()[0] / light.servo_gains()[0] == pytest.approx(
        heavy.motor.J / light.motor.J)


@pytest.mark.parametrize("extra, words", [
    ({"Km": 0.2}, "holding_torque_Nm and Km"),
    ({"J": 1e-4}, "rotor_inertia_kgm2 and J"),
    ({"Kd4": 0.01}, "detent_torque_Nm and Kd4"),
    ({"Vdc": 30.0}, "bus_voltage_V and Vdc"),
    ({"Nr": 50}, "step_angle_deg and Nr"),
    ({"base": "patent"}, "base"),
    ({"step_angle_deg": 1.7}, "step_angle_deg=1.7"),
    ({"rated_current_A": -1.0}, "rated_current_A=-1.0 is outside its allowed range"),
    ({"holding_torque_Nm": "0.4"}, "holding_torque_Nm must be a number"),
    ({"rotor_inertia_kgm": 1e-5}, "unknown parameter(s) ['rotor_inertia_kgm']"),
    ({"phase_inductance_H": 2.5}, "Was it in mH? 2.5 mH is 0.0025 H"),
])
def test_bad_datasheet_files_are_one_line_errors(extra, words):
    with pytest.raises(ParameterError) as err:
        system_from_mapping({**SHEET, **extra})
    assert words in str(err.value) and "\n" not in str(err.value)


def test_every_catalogue_motor_passes_the_inductance_check():
    """The refusal of L/R > 0.1 s leaves every real motor the project knows."""
    from stepdamp_env.bench.protocols.v4 import ProtocolV4, catalogue_systems

    taus = [s.motor.L / s.motor.R for s in catalogue_systems(ProtocolV4())]
    assert len(taus) >= 20 and max(taus) < 0.01


def test_missing_quantities_are_named():
    sheet = {k: v for k, v in SHEET.items() if k != "phase_inductance_H"}
    with pytest.raises(ParameterError, match="phase_inductance_H .or the model field L. is "
                                             "missing"):
        system_from_mapping(sheet)
    with pytest.raises(ParameterError, match="rated_current_A"):
        system_from_mapping({k: v for k, v in SHEET.items() if k != "rated_current_A"})


def test_assumed_lists_every_default_with_its_value():
    d = describe(SHEET)
    assert d.source == "datasheet defaults"
    assert not set(d.assumed) & set(SHEET)
    assert d.assumed["D"] == d.system.motor.D and d.assumed["Fs"] == d.system.motor.Fs
    assert d.assumed["encoder_cpr"] == 4000 and d.assumed["drive_mode"] == "current"
    assert d.assumed["Kp_vel"] == pytest.approx(d.system.servo_gains()[0])
    assert "Vdc" not in d.assumed and "holding_current" not in d.assumed
    bare = describe({k: v for k, v in SHEET.items() if k != "detent_torque_Nm"})
    assert bare.assumed["detent_torque_Nm"] == pytest.approx(DETENT_FRACTION * 0.40)
    # A model file inherits from its preset: that is listed too, with the preset named.
    legacy = describe({"base": "patent", "J": 8e-5})
    assert legacy.source == "preset patent"
    assert legacy.assumed["D"] == 0.001 and "J" not in legacy.assumed


@pytest.mark.slow
def test_example_file_and_motors_command(capsys):
    (d,) = describe_spec(EXAMPLE)
    assert d.system.name == "17hs4401-belt"
    assert main(["motors", EXAMPLE, "--json"]) == 0
    (rec,) = json.loads(capsys.readouterr().out)
    assert set(rec) >= {"parameters", "resonances_rps", "midband_rps", "max_speed_rps",
                        "assumed"}
    assert set(rec["resonances_rps"]) == {"1", "2", "4"}
    assert rec["resonances_rps"]["4"] == pytest.approx(
        d.system.predicted_resonances_rps()[4])
    assert rec["max_speed_rps"] == pytest.approx(bridge_limit_rps(d.system))
    assert set(rec["midband_rps"]) == {"current", "voltage"}
    lo, hi = rec["midband_rps"]["voltage"]
    assert 0 < lo < hi
    assert main(["motors", "patent"]) == 0 and "resonances h=4: 0.672" in capsys.readouterr().out
    assert main(["presets"]) == 0 and "qsh6018-65-28-210" in capsys.readouterr().out
    assert main(["motors", "no-such-motor"]) == 2
    assert "unknown motor preset" in capsys.readouterr().err


def test_a_motor_file_is_a_motors_file(tmp_path):
    from stepdamp_env.bench.protocols.v3 import quick_protocol_v3
    from stepdamp_env.bench.protocols.v1 import load_motors_file

    (system,) = load_motors_file(EXAMPLE, quick_protocol_v3())
    assert system.name == "17hs4401-belt"
    assert system == load_system(EXAMPLE).replace(current_noise_a=system.drive.current_noise_a)


# -- boards on any motor ------------------------------------------------------

def _row(name, suite, att, *, privileged=False, rank=1, lost=0, runs=4, spec=None):
    return {"name": name, "spec": spec or name, "suite": suite, "split": "custom",
            "reference": name == "reference", "privileged": privileged,
            "oracle": privileged, "zero_shot": False, "rank": None if privileged else rank,
            "attenuation_db": {"iqm": att, "ci": [att, att]},
            "gap_closed": {"iqm": att / 30, "ci": [att / 30, att / 30]},
            "ratio": {"iqm": 10 ** (-att / 20), "ci": [0, 0]},
            "success_rate": 1 - lost / runs, "full_sweep": {"mean": 1.0, "worst": 1.0},
            "step_losses": {"runs_lost": lost, "runs": runs}, "per_motor_db": {},
            "headline": {"iqm": 1.0, "ci95": [1, 1], "n": 0}, "scores": [], "runs": [],
            "knowledge": "test", "effect_db": {}, "probability_of_improvement": {}}


def test_notes_on_lost_unscored_and_privileged_rows():
    from stepdamp_env.bench.report import row_notes

    assert row_notes(_row("a", "servo", 3.0)) == []
    assert "loses every run" in row_notes(_row("none", "servo", 0.0, lost=4))[0]
    assert "no score" in row_notes(_row("a", "servo", math.nan))[0]
    assert "worse than no damping" in row_notes(_row("o", "servo", -2.0, privileged=True))[0]
    assert row_notes(_row("o", "servo", 2.0, privileged=True)) == []


def test_a_suite_without_scores_still_renders(tmp_path):
    """A suite where `none` lost every run has no scores: the tables say so and
    the performance profile draws an empty panel (it raised before)."""
    from stepdamp_env.bench.report import (plot_performance_profile, render_markdown,
                                           render_suite_page)

    rows = [_row("reference", "servo", 30.0, rank=None),
            _row("none", "servo", math.nan, rank=None, lost=4),
            _row("tuned-constant-gain", "servo", math.nan, rank=None),
            _row("oracle-floor", "servo", math.nan, privileged=True)]
    board = {"protocol": {"name": "stepdamp-bench", "version": "v3", "variant": "test",
                          "suites": ["servo"], "splits": ["custom"], "eval_seeds": [1],
                          "motors": [{"name": "m", "split": "custom"}]},
             "entries": rows, "versions": {"package": "test"}}
    summary = render_markdown(board)
    page = render_suite_page(board, "servo")
    assert "loses every run" in page and "no score" in page
    assert len(summary.encode()) < 5000
    plot_performance_profile(copy.deepcopy(board), str(tmp_path / "profile.png"))
    assert (tmp_path / "profile.png").stat().st_size > 0


def test_ripple_figure_highlights_at_most_six():
    from stepdamp_env.bench.report import HIGHLIGHTED, highlighted_rows

    rows = [_row("none", "open-loop", 0.0, rank=20)]
    rows += [_row(f"e{k}", "open-loop", 30.0 - k, rank=k + 1) for k in range(19)]
    rows.append(_row("patent-ff-identified", "open-loop", 20.0, rank=15))
    rows.append(_row("o", "open-loop", 40.0, privileged=True))
    shown = highlighted_rows(rows, reference=True)
    names = [e["name"] for e in shown]
    assert len(shown) == HIGHLIGHTED - 1 == 5
    assert names[:2] == ["none", "patent-ff-identified"] and names[2:] == ["e0", "e1", "e2"]


# -- sweeps: peaks by prominence, any entry -----------------------------------

def _humps(v, centres, widths, heights, floor):
    y = floor(v)
    for c, w, h in zip(centres, widths, heights):
        y = y + h / np.sqrt(1 + ((v - c) / w) ** 2)
    return y


def test_prominent_peaks_find_humps():
    from stepdamp_env.sweep import prominent_peaks

    v = np.arange(0.2, 3.5, 0.02)
    rng = np.random.default_rng(0)
    # Three humps on a falling floor, with 3 % noise: every hump found, nothing else.
    y = _humps(v, (0.67, 1.34, 2.69), (0.03, 0.05, 0.1), (2.0, 3.0, 1.0),
               lambda x: 0.5 / x) * (1 + 0.03 * rng.standard_normal(v.size))
    peaks = prominent_peaks(v, y)
    assert sorted(round(p["speed_rps"], 1) for p in peaks) == [0.7, 1.3, 2.7]
    assert all(p["prominence"] >= 1.5 for p in peaks)
    # A monotone curve, a plateau and a lone tiny spike on a damped curve: no hump.
    assert prominent_peaks(v, 1 / v) == []
    assert prominent_peaks(v, np.ones_like(v)) == []
    flat = 0.01 * np.ones_like(v)
    flat[40] = 0.012
    assert prominent_peaks(v, flat) == []
    # A lost run (nan) splits the curve; the hump beside it is still found.
    y2 = _humps(v, (1.0,), (0.05,), (2.0,), lambda x: 0.2 + 0 * x)
    y2[10] = np.nan
    assert [round(p["speed_rps"], 2) for p in prominent_peaks(v, y2)] == [1.0]


def test_sweep_any_entry(tmp_path, capsys):
    out = tmp_path / "sw"
    assert main(["sweep", "--motor", EXAMPLE, "--entries", "none", "tuned-constant-gain",
                 "--speeds", "0.55:0.7:0.05", "--out", str(out), "--no-progress",
                 "--workers", "1"]) == 0
    text = capsys.readouterr().out
    assert "none: lost steps in 0 of 4 runs" in text and "tuned-constant-gain" in text
    none = json.loads((out / "sweep_none.json").read_text())
    tcg = json.loads((out / "sweep_tuned-constant-gain.json").read_text())
    assert none["entry"] == "none" and len(none["rms_velocity_error_rad_s"]) == 4
    # Damping the h=4 resonance (0.625 rev/s) by a lot: the entry is really run.
    assert max(tcg["rms_velocity_error_rad_s"]) < 0.2 * max(none["rms_velocity_error_rad_s"])
    # Its dB against none, per speed and summarised, in the file and in one line.
    db = [20 * math.log10(n / e) for n, e in zip(none["rms_velocity_error_rad_s"],
                                                  tcg["rms_velocity_error_rad_s"])]
    summary = tcg["against_none"]
    np.testing.assert_allclose(summary["attenuation_db"], db, rtol=0, atol=1e-12)
    assert summary["worst_db"] == min(summary["attenuation_db"]) > 10.0
    assert summary["humps_rps"] == [] and "against none: mean +" in text and "no humps" in text
    # Asked without none, none is swept as the reference all the same.
    assert main(["sweep", "--motor", EXAMPLE, "--entries", "tuned-constant-gain",
                 "--speeds", "0.55:0.6:0.05", "--out", str(tmp_path / "sw2"), "--no-progress",
                 "--workers", "1"]) == 0
    assert "swept too: the reference" in capsys.readouterr().out
    assert (tmp_path / "sw2" / "sweep_none.json").is_file()
    assert main(["sweep", "--entries", "no-such-entry", "--out", str(tmp_path / "x")]) == 2
    assert "--entries: unknown ['no-such-entry']" in capsys.readouterr().err


def test_the_decibel_summary_flags_humps_and_counts_lost_runs():
    from stepdamp_env.bench.entry_sweep import EntrySweep, decibel_summary
    from stepdamp_env.presets import get_preset

    system = get_preset("patent")
    v = np.array([0.5, 0.6, 0.7, 0.8])
    none = EntrySweep("none", "open-loop", system, v, np.array([1.0, 1.0, math.nan, 1.0]),
                      np.array([False, False, True, False]))
    # 20 dB better, 2 dB worse (a hump), none lost (not scored), a lost run (-20 dB).
    entry = EntrySweep("x", "open-loop", system, v, np.array([0.1, 10 ** 0.1, 0.5, math.nan]),
                       np.array([False, False, False, True]))
    s = decibel_summary(entry, none)
    assert s["attenuation_db"][0] == pytest.approx(20.0) and s["attenuation_db"][2] is None
    assert s["attenuation_db"][1] == pytest.approx(-2.0) and s["attenuation_db"][3] == -20.0
    assert s["humps_rps"] == [0.6] and s["speeds_scored"] == 3
    assert s["worst_db"] == -20.0 and s["worst_speed_rps"] == 0.8
    assert s["mean_db"] == pytest.approx((20.0 - 2.0 - 20.0) / 3)
    assert decibel_summary(entry, none, hump_db=3.0)["humps_rps"] == []


@pytest.mark.parametrize("speeds, words", [
    ("-1:1:0.1", "START=-1 is outside its allowed range [0.001, 1000] rev/s (a sweep runs "
                 "forward"),
    ("1:0.5:0.1", "STOP=0.5 must be >= START=1"),
    ("0.1:1:0", "STEP=0 must be > 0"),
])
def test_sweep_speed_errors_name_the_part(speeds, words, capsys, tmp_path):
    assert main(["sweep", f"--speeds={speeds}", "--out", str(tmp_path / "x")]) == 2
    err = capsys.readouterr().err
    assert words in err and err.count("\n") == 1


def test_lone_spikes_are_marked():
    from stepdamp_env.sweep import prominent_peaks

    v = np.arange(0.2, 3.5, 0.05)
    y = 0.02 * np.ones_like(v)
    y[20] = 0.3
    (p,) = prominent_peaks(v, y)
    assert p["lone"] and p["speed_rps"] == pytest.approx(v[20])
    y = _humps(v, (1.0,), (0.1,), (1.0,), lambda x: 0.1 + 0 * x)
    (p,) = prominent_peaks(v, y)
    assert not p["lone"]


def test_drive_logs_of_the_example_motor_identify_back(tmp_path, capsys):
    """docs/motors.md, step 5: logs `simulate --trace` writes of the datasheet
    motor with a detent unlike the file's assumption, identified with the file
    as the prior."""
    truth = ["--set", "Kd1=0.002", "--set", "Kd2=0.004", "--set", "Kd4=0.016",
             "--set", "phi1=0.4", "--set", "phi2=-0.7", "--set", "current_noise_a=0.01"]
    def identify(mode: str, speeds_durations: tuple[tuple[str, str], ...], out: str
                 ) -> list[str]:
        logs = []
        for v, duration in speeds_durations:
            logs += ["--log", str(tmp_path / f"{mode}_{v}.csv")]
            assert main(["simulate", "--motor", EXAMPLE, *truth, "--mode", mode, "--speed", v,
                         "--duration", duration, "--trace", logs[-1]]) == 0
        assert main(["identify", "--motor", EXAMPLE, *logs, "--out", str(tmp_path / out)]) == 0
        return [line for line in capsys.readouterr().out.splitlines()
                if line.startswith("warning")]

    # Open loop at two of the plan's speeds: the file's assumed detent is not the
    # truth's: said, and nothing else.
    warnings = identify("open-loop", (("0.2501", "3.6"), ("0.3751", "2.5")), "id")
    assert len(warnings) == 1 and warnings[0].startswith(
        "warning: the prior disagrees with the logs: Kd1 0.0033 N*m against the logs' 0.00")
    # Servo logs get a warning of their own besides.
    servo = identify("servo", (("0.2", "1.2"), ("0.45", "1.2")), "id_servo")
    assert len(servo) == 2 and servo[0].startswith(
        "warning: servo logs: on 3 of 81 ")
    got = json.loads((tmp_path / "id" / "identified_motor.json").read_text())
    assert got["Kd4"] == pytest.approx(0.016, rel=0.10)
    assert got["Kd2"] == pytest.approx(0.004, rel=0.10)
    assert got["phi2"] == pytest.approx(-0.7, abs=0.05)
    # The fitted inertia and drag are written, and said to be fitted.
    fit = json.loads((tmp_path / "id" / "identification.json").read_text())
    assert set(fit["fitted"]) <= {"J", "D"}
    for name in ("J", "D"):
        assert got[name] == fit[name]
        assert (name in got["notes"].split(";")[0]) == (name in fit["fitted"])
    assert main(["motors", str(tmp_path / "id" / "identified_motor.json")]) == 0


@pytest.mark.slow
def test_an_entry_that_cannot_run_is_lost_with_its_reason(tmp_path, capsys):
    from stepdamp_env.bench.report import load_leaderboard, row_notes

    policy = os.path.join(ROOT, "tests", "fragile_policy.py") + ":Fragile"
    out = tmp_path / "b"
    assert main(["leaderboard", "--quick", "--motors", EXAMPLE, "--suite", "open-loop",
                 "--entries", "ff-delay-comp", "--policy", policy, "--eval-seeds", "1",
                 "--no-progress", "--out", str(out)]) == 0
    assert "could not run in 2 of 3 runs" in capsys.readouterr().out
    board = load_leaderboard(out)
    row = next(e for e in board["entries"] if e["name"] == "test-fragile")
    errors = [r for r in row["runs"] if r.get("error")]
    assert len(errors) == 2 and all(r["failed"] and r["speed_rps"] > 1.0 for r in errors)
    assert "outside this law's design range" in errors[0]["error"]
    assert "could not run" in " ".join(row_notes(row))
    assert "could not run" in (out / "LEADERBOARD_open-loop.md").read_text()
    # The runs that could run are the batch's own numbers: as ff-delay-comp's base alone.
    fine = [r for r in row["runs"] if not r.get("error")]
    assert fine and all(not r["failed"] for r in fine)


def test_the_worked_example_prints_what_docs_motors_md_shows(capsys):
    assert main(["motors", EXAMPLE]) == 0
    doc = open(os.path.join(ROOT, "docs", "motors.md"), encoding="utf-8").read()
    for line in capsys.readouterr().out.splitlines():
        assert line in doc, line


@pytest.mark.slow
def test_motors_warns_where_the_bus_cannot_push_the_current(tmp_path, capsys):
    path = tmp_path / "low.json"
    path.write_text(json.dumps({**SHEET, "bus_voltage_V": 2.0}))
    assert main(["presets", str(path)]) == 0           # the older name takes files too
    text = capsys.readouterr().out
    assert "warning: R * holding current = 3.61 V already exceeds the bridge circle" in text
    assert "top speed the bus allows 0.00 rev/s" in text


@pytest.mark.parametrize("extra, words", [
    ({"holding_current": "2"}, "holding_current must be a number"),
    ({"holding_current": -1.0}, "holding_current=-1.0 is outside its allowed range"),
    ({"D": "x"}, "D must be a number"),
    ({"drive_mode": "pwm"}, "drive_mode='pwm' is not one of"),
])
def test_model_fields_in_a_datasheet_file_are_checked_first(extra, words):
    with pytest.raises(ParameterError) as err:
        system_from_mapping({**SHEET, **extra})
    assert words in str(err.value)
