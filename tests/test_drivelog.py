"""Drive logs: the CSV a drive would write, and the detent model identified from it."""

from __future__ import annotations

import math

import numpy as np
import pytest

from stepdamp_env.drivelog import TRACE_COLUMNS, read_trace, trace_table, write_trace
from stepdamp_env.logfit import (MAX_RESIDUAL_FRACTION, MIN_ELECTRICAL_PERIODS,
                                 identify_from_logs, identify_from_tables)
from stepdamp_env.params import ParameterError
from stepdamp_env.presets import get_preset
from stepdamp_env.simulation import RunSettings, SpeedProfile, simulate

SPEEDS_RPS = (0.2, 0.3, 0.45)       # >= 10 electrical periods each in 1.2 s
DURATION_S = 1.2


def _wrap(angle: float) -> float:
    return (angle + math.pi) % (2.0 * math.pi) - math.pi


@pytest.fixture(scope="module")
def held_out():
    """A motor that is no preset: the patent's drive with another rotor (J 1.5x),
    other detent amplitudes and phases, less friction, current-sensor noise on."""
    return get_preset("patent").replace(
        name="held-out", J=6.0e-5, Kd1=0.005, Kd2=0.0042, Kd4=0.015, phi1=0.3, phi2=-0.8,
        Fs=0.003, current_noise_a=0.01)


def _servo_log(system, speed_rps, duration_s=DURATION_S, seed=0):
    result = simulate(system, profile=SpeedProfile(speed_rps=speed_rps),
                      settings=RunSettings(mode="servo", noise_seed=seed),
                      duration_s=duration_s, trace=True)
    return trace_table(result)


@pytest.fixture(scope="module")
def held_out_logs(held_out, tmp_path_factory):
    """CSV logs of the held-out motor in servo mode at three constant speeds."""
    folder = tmp_path_factory.mktemp("logs")
    paths = []
    for k, v in enumerate(SPEEDS_RPS):
        path = folder / f"servo_{v:g}.csv"
        write_trace(path, _servo_log(held_out, v, seed=k), comments=[f"held-out at {v} rev/s"])
        paths.append(str(path))
    return paths


def test_held_out_motor_identified_from_its_logs_with_the_nominal_prior(held_out, held_out_logs):
    nominal = get_preset("patent")          # R, L, Km, J, Nr, encoder: the prior, not the truth
    result = identify_from_logs(nominal, held_out_logs)
    m, truth = result.model, held_out.motor
    errors = {name: getattr(m, name) / getattr(truth, name) - 1.0
              for name in ("Kd1", "Kd2", "Kd4", "Fs")}
    errors.update(phi1=_wrap(m.phi1 - truth.phi1), phi2=_wrap(m.phi2 - truth.phi2),
                  J=result.J / truth.J - 1.0, D=result.D / truth.D - 1.0)
    print("torque-balance, identified - truth:",
          {k: f"{v:+.4f}" for k, v in errors.items()})
    assert abs(errors["Kd4"]) < 0.10, errors
    # What the method reaches here (about 1 %; the bounds leave room).
    assert max(abs(errors[k]) for k in ("Kd1", "Kd2", "Kd4", "J")) < 0.05, errors
    assert max(abs(errors["phi1"]), abs(errors["phi2"])) < 0.05, errors
    assert abs(errors["Fs"]) < 0.2 and abs(errors["D"]) < 0.2, errors
    assert result.fitted == ("J", "D")
    assert result.speeds_rps == pytest.approx(SPEEDS_RPS, rel=0.01)
    # Servo logs are warned of; the prior is another motor (J -33 %): it says so,
    # and nothing else is warned.
    assert result.warnings[0].startswith("servo logs: ")
    assert "J 4e-05 kg*m^2 against the logs' 6.00" in result.warnings[1]
    assert all(w.startswith("the prior disagrees with the logs: ") for w in result.warnings[1:])
    # Each amplitude's error within three stated uncertainties, each under 5 %.
    for name in ("Kd1", "Kd2", "Kd4"):
        assert result.relative_uncertainty(name) < 0.05
        assert abs(errors[name]) < 3.0 * result.relative_uncertainty(name) + 0.003, name
    assert all(log.electrical_periods >= MIN_ELECTRICAL_PERIODS for log in result.logs)
    assert result.residual_fraction < 0.1 and 0 < result.residual_rms_a < 0.01
    identified = result.apply_to(nominal)
    assert identified.motor.Kd4 == m.Kd4 and identified.motor.J == nominal.motor.J
    assert result.apply_to(nominal, mechanics=True).motor.J == result.J


def test_claim_1_effort_method_on_the_same_logs(held_out, held_out_logs):
    """The patent's one-round effort fit: biased on this light axis (the rotor's
    ripple), so only bounded loosely; the torque balance above is not."""
    result = identify_from_logs("patent", held_out_logs, method="effort")
    m, truth = result.model, held_out.motor
    errors = {name: getattr(m, name) / getattr(truth, name) - 1.0
              for name in ("Kd1", "Kd2", "Kd4")}
    print("effort, identified - truth:", {k: f"{v:+.4f}" for k, v in errors.items()})
    assert abs(errors["Kd4"]) < 0.3, errors
    assert result.fitted == ("D",) and result.J == get_preset("patent").motor.J


def test_csv_round_trip_is_exact(tmp_path, held_out):
    table = _servo_log(held_out, 0.3, duration_s=0.6)
    path = tmp_path / "log.csv"
    write_trace(path, {**table, "extra_V": table["phase_voltage_a_V"] * 2.0},
                comments=["a comment", "two lines\nof it"])
    text = path.read_text(encoding="utf-8").splitlines()
    assert text[:3] == ["# a comment", "# two lines", "# of it"]
    assert text[3] == ",".join(list(TRACE_COLUMNS) + ["extra_V"])
    back = read_trace(path)
    assert list(back) == list(TRACE_COLUMNS) + ["extra_V"]
    for name in TRACE_COLUMNS:
        assert np.array_equal(back[name], table[name]), name


def test_the_table_holds_what_the_drive_sees(patent):
    system = patent.replace(current_offset_a=0.05)
    result = simulate(system, profile=SpeedProfile(speed_rps=0.3),
                      settings=RunSettings(mode="servo"), duration_s=0.6, trace=True)
    table, trace = trace_table(result), result.trace
    q = 2.0 * math.pi / system.servo.encoder_cpr
    assert np.array_equal(table["position_rad"], trace["theta_fb"])
    assert np.allclose(table["position_rad"] / q, np.round(table["position_rad"] / q))
    # Sensors: the true currents plus the offset (no noise set).
    assert np.allclose(table["phase_current_a_A"], trace["ia"] + 0.05, atol=1e-9)
    assert np.allclose(table["phase_current_b_A"], trace["ib"], atol=1e-9)
    # The command's q part at the encoder angle is the servo's iq_cmd, its d part 0.
    x = system.motor.Nr * (trace["theta_fb"] + 0.5 * q)
    a, b = table["command_current_a_A"], table["command_current_b_A"]
    assert np.allclose(-a * np.sin(x) + b * np.cos(x), trace["iq_cmd"], atol=1e-9)
    assert np.allclose(a * np.cos(x) + b * np.sin(x), 0.0, atol=1e-9)
    assert np.array_equal(table["phase_voltage_b_V"], trace["vb"])
    # Open loop: the command holds the holding current on d.
    ol = simulate(patent, speed_rps=0.3, settings=RunSettings(settle_s=0.0), duration_s=0.3,
                  trace=True)
    t_ol = trace_table(ol)
    assert np.allclose(np.hypot(t_ol["command_current_a_A"], t_ol["command_current_b_A"]),
                       patent.drive.holding_current, rtol=1e-6)
    with pytest.raises(ParameterError, match="no trace"):
        trace_table(simulate(patent, speed_rps=0.3, duration_s=0.4))
    with pytest.raises(ParameterError, match="system and mode"):
        trace_table(ol.trace)


def _good_csv() -> str:
    """Four rows, time 0, 0.001, 0.002, 0.003 s (lines 2-5)."""
    rows = [f"{i * 0.001:.3f}," + ",".join(str(i + j) for j in range(len(TRACE_COLUMNS) - 1))
            for i in range(4)]
    return "\n".join([",".join(TRACE_COLUMNS)] + rows) + "\n"


@pytest.mark.parametrize("content, message", [
    (None, "does not exist"),
    ("", "is empty"),
    ("# only a comment\n", "is empty"),
    (_good_csv().replace("phase_current_b_A", "ib"), "missing column 'phase_current_b_A'"),
    (_good_csv().replace("time_s,", "position_rad,", 1), "repeated"),
    (_good_csv().splitlines()[0] + "\n", "0 data row"),
    (_good_csv().replace("\n0.001,", "\nabc,", 1), "line 3, column time_s: 'abc' is not a number"),
    (_good_csv().rstrip("\n") + ",9\n", "line 5 has 9 field"),
    (_good_csv().replace("\n0.001,", "\nnan,", 1), "line 3, column time_s: 'nan' is not finite"),
    (_good_csv().replace("\n0.001,", "\n0,", 1), "time_s does not increase at line 3"),
    (b"\xff\xfe\x00bin", "not UTF-8"),
])
def test_bad_files_are_one_line_errors_naming_the_file(tmp_path, content, message):
    path = tmp_path / "bad.csv"
    if isinstance(content, bytes):
        path.write_bytes(content)
    elif content is not None:
        path.write_text(content, encoding="utf-8")
    with pytest.raises(ParameterError) as info:
        read_trace(path)
    text = str(info.value)
    assert message in text and "bad.csv" in text and "\n" not in text, text
    with pytest.raises(ParameterError, match="is a directory"):
        read_trace(tmp_path)


def test_good_minimal_file_reads(tmp_path):
    path = tmp_path / "ok.csv"
    path.write_text(_good_csv(), encoding="utf-8")
    table = read_trace(path)
    assert table["time_s"][1] == 0.001 and table["phase_voltage_b_V"][3] == 9.0
    assert len(table["phase_voltage_b_V"]) == 4


def test_short_and_noisy_logs_warn(held_out):
    clean = [_servo_log(held_out, v, seed=k) for k, v in enumerate((0.2, 0.3))]
    # 0.45 s at 0.2 rev/s: 0.35 s after ramp and settle, 3.5 electrical periods.
    short = {k: v[: int(0.45 * 20_000)] for k, v in clean[0].items()}
    result = identify_from_tables("patent", [short, clean[1]], ["short.csv", "long.csv"])
    assert [w for w in result.warnings if "too short" in w] == [result.logs[0].warnings[0]]
    assert result.warnings[0].startswith("short.csv: too short: 3.")
    assert result.logs[1].warnings == ()
    assert abs(result.model.Kd4 / held_out.motor.Kd4 - 1.0) < 0.10
    # White noise on the phase-current sensors, 0.3 A: the fit cannot explain it.
    rng = np.random.default_rng(1)
    noisy = [{k: (v + 0.3 * rng.standard_normal(len(v)) if k.startswith("phase_current")
                  else v) for k, v in t.items()} for t in clean]
    result = identify_from_tables("patent", noisy, ["n1.csv", "n2.csv"])
    too_noisy = [w for w in result.warnings if "too noisy" in w]
    assert len(too_noisy) == 2 and too_noisy[0].startswith("n1.csv: too noisy")
    assert all(log.residual_fraction > MAX_RESIDUAL_FRACTION for log in result.logs)
    clean_result = identify_from_tables("patent", clean)
    assert not [w for w in clean_result.warnings if "too noisy" in w]
    assert all(log.residual_fraction < MAX_RESIDUAL_FRACTION for log in clean_result.logs)


def test_logs_that_cannot_be_fitted_raise(held_out, patent):
    table = _servo_log(held_out, 0.2, duration_s=0.6)
    with pytest.raises(ParameterError, match=r"0\.\d+ electrical period\(s\) at constant speed"):
        identify_from_tables("patent", [{k: v[: int(0.2 * 20_000)] for k, v in table.items()}])
    still = {**table, "position_rad": np.zeros_like(table["position_rad"])}
    with pytest.raises(ParameterError, match="allowed .speed. >= 0.01 rev/s"):
        identify_from_tables("patent", [still])
    with pytest.raises(ParameterError, match="missing column 'phase_current_a_A'"):
        identify_from_tables("patent", [{k: v for k, v in table.items()
                                         if k != "phase_current_a_A"}])
    uneven = {**table, "time_s": table["time_s"] * (1.0 + table["time_s"])}
    with pytest.raises(ParameterError, match="not evenly sampled"):
        identify_from_tables("patent", [uneven])
    with pytest.raises(ParameterError, match="method='lsq' is not one of"):
        identify_from_logs("patent", [], method="lsq")
    with pytest.raises(ParameterError, match="no drive log"):
        identify_from_tables("patent", [])
    open_loop = trace_table(simulate(patent, speed_rps=0.3, duration_s=0.8, trace=True))
    with pytest.raises(ParameterError, match="not a servo log"):
        identify_from_tables("patent", [open_loop], method="effort")
