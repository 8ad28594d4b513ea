"""Identification of the detent model (claim 1) from what a drive sees."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from stepdamp_env.cli import main
from stepdamp_env.identify import effort_response, identify
from stepdamp_env.params import FeedforwardModel
from stepdamp_env.motorfile import load_system
from stepdamp_env.presets import get_preset, preset_names
from stepdamp_env.simulation import RunSettings, simulate


@pytest.mark.parametrize("name", preset_names())
def test_iterative_identification_meets_the_accuracy_targets(name):
    # Encoder quantisation (4000 counts/rev) and current-sensor noise on.
    system = get_preset(name).replace(current_noise_a=0.01)
    result = identify(system, method="iterative", noise_seed=5)
    e = result.errors
    for key in ("Kd1", "Kd2", "Kd4"):
        assert abs(e[key]) < 0.05, (key, e)
    for key in ("phi1", "phi2"):
        assert abs(e[key]) < 0.05, (key, e)
    assert abs(e["Fs"]) < 0.10, e
    assert result.iterations >= 2
    assert result.D == pytest.approx(system.motor.D, rel=0.2)


@pytest.mark.parametrize("name", ["qsh5718-56-28-126", "qsh6018-65-28-210"])
def test_direct_least_squares_on_the_heavier_axes(name):
    # One run per speed; the servo's rejection ratio is divided out. On the
    # lighter axes its residual ripple biases Kd2 by 10-20 % (docs/protocols.md).
    system = get_preset(name).replace(current_noise_a=0.01)
    e = identify(system, method="least-squares", noise_seed=5).errors
    assert max(abs(e["Kd1"]), abs(e["Kd2"]), abs(e["Kd4"])) < 0.05, e
    assert max(abs(e["phi1"]), abs(e["phi2"])) < 0.05, e
    assert abs(e["Fs"]) < 0.10, e


def test_identified_feedforward_damps_like_the_oracle():
    system = get_preset("patent").replace(current_noise_a=0.01)
    model = identify(system, noise_seed=1).model
    speed = system.predicted_resonances_rps()[4]
    none = simulate(system, speed_rps=speed).metrics.rms_velocity_error_rad_s
    oracle = simulate(system, speed_rps=speed, base_controller="patent-ff").metrics
    ident = simulate(system, speed_rps=speed, base_controller="patent-ff", estimate=model).metrics
    assert ident.rms_velocity_error_rad_s < 0.25 * none
    assert ident.rms_velocity_error_rad_s == pytest.approx(oracle.rms_velocity_error_rad_s,
                                                           rel=0.3)


def test_effort_response_limits():
    system = get_preset("patent")
    # Far below the servo bandwidth the loop rejects a disturbance fully: the
    # effort equals it; far above, the inertia takes it and the effort vanishes.
    assert abs(effort_response(system, 2 * math.pi * 0.5) - 1.0) < 1e-3
    assert abs(effort_response(system, 2 * math.pi * 2000.0)) < 0.05


def test_identification_is_deterministic_and_seeded():
    system = get_preset("qsh5718-56-28-126").replace(current_noise_a=0.02)
    a = identify(system, noise_seed=3)
    b = identify(system, noise_seed=3)
    c = identify(system, noise_seed=4)
    assert a.model == b.model
    assert a.model != c.model


def test_identify_cli_writes_a_motor_file_that_loads(tmp_path, capsys):
    out = tmp_path / "id"
    assert main(["identify", "--motor", "qsh6018-65-28-210", "--set", "current_noise_a=0.01",
                 "--out", str(out)]) == 0
    motor = load_system(str(out / "identified_motor.json"))
    truth = get_preset("qsh6018-65-28-210")
    assert motor.motor.Kd4 == pytest.approx(truth.motor.Kd4, rel=0.05)
    assert motor.motor.J == truth.motor.J           # untouched fields carried over
    report = json.loads((out / "identification.json").read_text())
    assert set(report["errors"]) == {"Kd1", "Kd2", "Kd4", "Fs", "phi1", "phi2"}
    assert "Kd4" in capsys.readouterr().out


def test_bad_identification_options():
    with pytest.raises(ValueError, match="method='magic'"):
        identify("patent", method="magic")
    with pytest.raises(ValueError, match="speeds_rps"):
        identify("patent", speeds_rps=(0.0,))
