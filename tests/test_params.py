"""Parameter validation, presets, motor files and the resonance prediction."""

from __future__ import annotations

import json
import math

import pytest

from stepdamp_env.params import ALL_FIELDS, DriveParams, FeedforwardModel, MotorParams, ParameterError, SystemParams, delayed_loop_gain, predicted_resonances
from stepdamp_env.motorfile import load_system, parse_set_overrides
from stepdamp_env.presets import get_preset, preset_names
from stepdamp_env.simulation import RunSettings, SpeedProfile, simulate


def test_presets_include_the_patent_and_three_real_motors():
    names = preset_names()
    assert "patent" in names and len(names) >= 4
    p = get_preset("patent")
    assert (p.motor.Km, p.motor.Nr, p.motor.D) == (0.3, 50, 0.001)
    assert (p.drive.holding_current, p.drive.pwm_hz, p.drive.microsteps) == (1.9, 20000.0, 64)
    assert p.servo.encoder_cpr == 4000


def test_datasheet_presets_reproduce_their_holding_torque():
    # Km * holding_current is the datasheet holding torque (both phases at rated current).
    assert get_preset("qsh4218-51-10-049").motor.Km * get_preset(
        "qsh4218-51-10-049").drive.holding_current == pytest.approx(0.49)
    q = get_preset("qsh5718-56-28-126")
    assert q.motor.Km * q.drive.holding_current == pytest.approx(1.26)
    assert (q.motor.R, q.motor.L) == (0.9, 2.5e-3)


@pytest.mark.parametrize("field,value,fragment", [
    ("L", -1e-3, "L=-0.001 is outside its allowed range [1e-12, 10.0]"),
    ("R", 0.0, "R=0.0 is outside"),
    ("Nr", 50.5, "Nr must be an integer"),
    ("J", math.nan, "J must be finite"),
    ("Kd4", -0.1, "Kd4=-0.1 is outside"),
    ("microsteps", 0, "microsteps=0 is outside"),
    ("current_bandwidth_hz", 5000.0, "pwm_hz/8"),
    ("velocity_cutoff_hz", 15000.0, "velocity_cutoff_hz=15000.0 is outside"),
])
def test_bad_values_name_the_field_and_its_range(field, value, fragment):
    with pytest.raises(ParameterError) as info:
        get_preset("patent").replace(**{field: value})
    assert fragment in str(info.value)


def test_unknown_preset_lists_the_choices():
    with pytest.raises(ParameterError, match="unknown motor preset 'nema99'.*patent"):
        load_system("nema99")


def test_unknown_field_is_rejected_everywhere(tmp_path):
    with pytest.raises(ParameterError, match="unknown parameter"):
        load_system({"Lq": 1.0})
    with pytest.raises(ParameterError, match="unknown parameter 'Lq'"):
        parse_set_overrides(["Lq=1"])
    with pytest.raises(ParameterError, match="FIELD=VALUE"):
        parse_set_overrides(["L"])
    path = tmp_path / "m.json"
    path.write_text("[1, 2]")
    with pytest.raises(ParameterError, match="JSON object"):
        load_system(str(path))
    with pytest.raises(ParameterError, match="does not exist"):
        load_system(str(tmp_path / "missing.json"))


def test_json_round_trip_gives_an_equal_system(tmp_path):
    system = get_preset("qsh6018-65-28-210").replace(load_torque=0.05)
    path = tmp_path / "motor.json"
    path.write_text(json.dumps(system.to_dict()))
    again = load_system(str(path))
    assert again == system
    # drive_mode is written only when it is not the default (older files stay the same).
    assert set(system.to_dict()) == set(ALL_FIELDS) - {"drive_mode"} | {"name"}
    voltage = system.replace(drive_mode="voltage")
    assert set(voltage.to_dict()) == set(ALL_FIELDS) | {"name"}
    path.write_text(json.dumps(voltage.to_dict()))
    assert load_system(str(path)) == voltage


def test_set_overrides_apply_after_the_file(tmp_path):
    path = tmp_path / "m.json"
    path.write_text(json.dumps({"base": "patent", "J": 5e-5}))
    system = load_system(str(path), parse_set_overrides(["J=6e-5", "microsteps=256"]))
    assert system.motor.J == 6e-5 and system.drive.microsteps == 256
    assert isinstance(system.drive.microsteps, int)


def test_predicted_resonances_formula():
    system = get_preset("patent")
    wn = math.sqrt(0.3 * 1.9 * 50 / system.motor.J)
    assert system.natural_frequency() == pytest.approx(wn)
    res = predicted_resonances(system)
    for h in (4, 2, 1):
        assert res[h] == pytest.approx(wn / (h * 50) / (2 * math.pi))
    assert res[4] < res[2] < res[1]


def test_delayed_loop_gain_is_critically_damped_near_an_eighth_of_nyquist():
    # g/(z^2 - z + g) has a double pole at g = 1/4; its -3 dB point is then
    # close to f_s/13.
    g = delayed_loop_gain(1500.0 / 20000.0)
    assert 0.2 < g < 0.3
    assert delayed_loop_gain(0.01) < delayed_loop_gain(0.05) < delayed_loop_gain(0.1)


def test_feedforward_model_coefficients():
    ff = FeedforwardModel(Km=0.3, Kd1=0.1, Kd2=0.2, Kd4=0.3, phi1=0.5, phi2=-1.0, Fs=0.0)
    s1, c1, s2, c2, s4, c4 = ff.coefficients()
    x = 0.37
    assert s1 * math.sin(x) + c1 * math.cos(x) == pytest.approx(0.1 * math.sin(x + 0.5))
    assert s2 * math.sin(2 * x) + c2 * math.cos(2 * x) == pytest.approx(
        0.2 * math.sin(2 * x - 1.0))
    assert (s4, c4) == (0.3, 0.0)
    with pytest.raises(ParameterError, match="Km"):
        FeedforwardModel(Km=-1, Kd1=0, Kd2=0, Kd4=0, phi1=0, phi2=0, Fs=0)


def test_run_options_are_validated():
    with pytest.raises(ParameterError, match="mode='closed'"):
        RunSettings(mode="closed")
    with pytest.raises(ParameterError, match="base_controller"):
        RunSettings(base_controller="magic")
    # The old name (the frozen v0 harness passes it) means the same; not both at once.
    assert RunSettings(damping="patent-ff") == RunSettings(base_controller="patent-ff")
    with pytest.raises(ParameterError, match="not both"):
        RunSettings(base_controller="patent-ff", damping="none")
    with pytest.raises(ParameterError, match="substeps=0"):
        RunSettings(substeps=0)
    with pytest.raises(ParameterError, match="accel_rps2"):
        SpeedProfile(speed_rps=1.0, accel_rps2=0.0)
    with pytest.raises(ParameterError, match="speed_rps"):
        SpeedProfile(speed_rps=math.inf)
    with pytest.raises(ParameterError, match="duration_s"):
        simulate("patent", speed_rps=1.0, duration_s=0.01)


def test_construct_directly_with_dataclasses():
    motor = MotorParams(R=1.0, L=2e-3, Km=0.2, Nr=50, J=1e-5, D=1e-4, Kd1=0.0, Kd2=0.0,
                        Kd4=0.01, phi1=0.0, phi2=0.0, Fs=0.0)
    system = SystemParams(motor, DriveParams(holding_current=1.0))
    assert system.drive.Vdc == 48.0
    assert motor.full_step_rad == pytest.approx(math.radians(1.8))


def test_required_fields_refuse_none_and_accept_numpy_scalars():
    """JSON null once passed for required fields and gave NaN metrics with exit 0."""
    import numpy as np

    from stepdamp_env.params import SystemParams

    base = get_preset("patent")
    for name in ("Kd4", "R", "J", "load_torque", "Vdc", "holding_current", "encoder_cpr"):
        with pytest.raises(ParameterError, match=f"{name} must be a number, got None"):
            SystemParams.from_dict({name: None}, base=base)
    # Optional gains may be None: they are derived.
    assert base.replace(Kp_current=None).current_gains() == base.current_gains()
    s = base.replace(J=np.float32(2e-4), Nr=np.int64(50), Kd4=np.float64(0.01))
    assert s.motor.J == pytest.approx(2e-4) and s.motor.Nr == 50 and type(s.motor.Nr) is int
    with pytest.raises(ParameterError, match="must be a number"):
        base.replace(R=np.bool_(True))


@pytest.mark.parametrize("value", [math.nan, math.inf, -math.inf])
def test_integer_fields_refuse_non_finite_values_with_one_line(value):
    for name in ("encoder_cpr", "Nr", "microsteps"):
        with pytest.raises(ParameterError, match=f"{name} must be finite"):
            get_preset("patent").replace(**{name: value})


def test_replace_equals_a_system_built_from_all_its_fields_and_still_validates():
    """replace() keeps the records it does not change (already validated) and
    builds the others; the result equals one built from every field."""
    import dataclasses as dc

    base = get_preset("patent")
    got = base.replace(J=base.motor.J * 1.3, kalman_accel_std=500.0)
    flat = {**dc.asdict(base.motor), **dc.asdict(base.drive), **dc.asdict(base.servo),
            "J": base.motor.J * 1.3, "kalman_accel_std": 500.0, "name": base.name}
    assert got == SystemParams.from_dict(flat)
    assert got.drive is base.drive and got.servo is not base.servo
    with pytest.raises(ParameterError, match="pwm_hz"):
        base.replace(pwm_hz=-1.0)
