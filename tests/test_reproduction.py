"""The patent's results on every preset: three resonances where predicted, and
the harmonic feedforward cutting them; servo ripple lowered; JSON motors alike."""

from __future__ import annotations

import json

import numpy as np
import pytest

from stepdamp_env.motorfile import load_system
from stepdamp_env.presets import preset_names
from stepdamp_env.simulation import RunSettings, simulate
from stepdamp_env.sweep import find_resonance_peaks, run_sweep


def _resonance_grid(system, span=0.15, points=16):
    pred = system.predicted_resonances_rps()
    return np.unique(np.concatenate([np.round(v * np.linspace(1 - span, 1 + span, points), 5)
                                     for v in pred.values()]))


def _check_three_peaks_and_feedforward(system):
    speeds = _resonance_grid(system)
    undamped = run_sweep(system, speeds, RunSettings(base_controller="none"), progress=False)
    damped = run_sweep(system, speeds, RunSettings(base_controller="patent-ff"), progress=False)
    ripple = undamped.column("rms_velocity_error_rad_s")
    ripple_ff = damped.column("rms_velocity_error_rad_s")
    assert not undamped.column("step_loss").any()
    peaks = find_resonance_peaks(speeds, ripple, system.predicted_resonances_rps())
    assert sorted(peaks) == [1, 2, 4]
    for h, peak in peaks.items():
        assert peak["is_local_max"], (h, peak)
        assert abs(peak["relative_offset"]) <= 0.05, (h, peak)
        i = int(np.argmin(np.abs(speeds - peak["speed_rps"])))
        assert ripple[i] / ripple_ff[i] >= 4.0, (h, ripple[i], ripple_ff[i])
    return peaks


@pytest.mark.parametrize("name", preset_names())
def test_open_loop_resonances_and_feedforward_on_every_preset(name):
    _check_three_peaks_and_feedforward(load_system(name))


@pytest.mark.parametrize("name", preset_names())
def test_servo_feedforward_lowers_low_speed_ripple(name):
    # Below the encoder's resolution the quantisation noise sets a floor that
    # no feedforward removes, so the gain is smaller at the lowest speed.
    system = load_system(name)
    speeds = (0.2, 0.5, 1.0)
    none = [simulate(system, speed_rps=v, mode="servo", base_controller="none").metrics
            for v in speeds]
    ff = [simulate(system, speed_rps=v, mode="servo", base_controller="patent-ff").metrics
          for v in speeds]
    for a, b in zip(none, ff):
        assert b.rms_velocity_error_rad_s < 0.9 * a.rms_velocity_error_rad_s, a.speed_rps
        assert not a.step_loss and not b.step_loss
    mean_none = np.mean([a.rms_velocity_error_rad_s for a in none])
    mean_ff = np.mean([b.rms_velocity_error_rad_s for b in ff])
    assert mean_none / mean_ff > 1.5


def test_custom_json_motor_behaves_the_same(tmp_path):
    # A made-up motor: heavier load, other detent mix, its own bus; from a file.
    spec = {"base": "qsh5718-56-28-126", "name": "custom-rig", "J": 2.0e-4, "D": 0.004,
            "Kd4": 0.02, "Kd2": 0.012, "phi2": -0.7, "Kd1": 0.008, "phi1": 2.2,
            "Vdc": 36.0}
    path = tmp_path / "rig.json"
    path.write_text(json.dumps(spec))
    system = load_system(str(path))
    assert system.name == "custom-rig" and system.motor.J == 2.0e-4
    _check_three_peaks_and_feedforward(system)


def test_feedforward_with_a_wrong_model_does_worse_than_exact():
    from stepdamp_env.params import FeedforwardModel

    system = load_system("patent")
    speed = system.predicted_resonances_rps()[2]
    exact = simulate(system, speed_rps=speed, base_controller="patent-ff").metrics
    m = system.motor
    shifted = FeedforwardModel(Km=m.Km, Kd1=m.Kd1, Kd2=m.Kd2, Kd4=m.Kd4, phi1=m.phi1,
                               phi2=m.phi2 + 0.8, Fs=m.Fs)
    wrong = simulate(system, speed_rps=speed, base_controller="patent-ff", estimate=shifted).metrics
    assert wrong.rms_velocity_error_rad_s > 2 * exact.rms_velocity_error_rad_s


def test_the_spike_rule_applies_only_on_grids_that_resolve_the_resonance():
    """A resonance of damping ratio zeta sampled on a grid coarser than
    zeta*sqrt(SPIKE_RATIO^2 - 1) may stand SPIKE_RATIO above both neighbours and is
    still a resonance; on a finer grid such a lone point is an aliasing spike."""
    from stepdamp_env.sweep import SPIKE_RATIO

    zeta = 0.02
    res = zeta * np.sqrt(SPIKE_RATIO ** 2 - 1)

    def lorentz(v):
        return 1.0 / np.sqrt((1 - v ** 2) ** 2 + (2 * zeta * v) ** 2)

    # At the resolving spacing a resonance falls by SPIKE_RATIO (to first order).
    assert lorentz(1.0) / lorentz(1.0 + res) == pytest.approx(SPIKE_RATIO, rel=0.03)
    coarse = np.round(np.arange(0.70, 1.3001, 0.05), 10)
    peak = find_resonance_peaks(coarse, lorentz(coarse), {4: 1.0}, resolving_spacing=res)[4]
    assert lorentz(1.0) > SPIKE_RATIO * lorentz(1.05)          # a lone point on this grid
    assert peak["is_resonance"] and not peak["resolved"] and peak["speed_rps"] == 1.0
    fine = np.arange(0.70, 1.3001, 0.002)
    peak = find_resonance_peaks(fine, lorentz(fine), {4: 1.0}, resolving_spacing=res)[4]
    assert peak["is_resonance"] and peak["resolved"] and abs(peak["speed_rps"] - 1.0) < 0.01
    spiky = np.ones_like(fine)
    spiky[np.argmin(abs(fine - 0.97))] = 5.0                   # aliasing at one speed
    peak = find_resonance_peaks(fine, spiky, {4: 1.0}, resolving_spacing=res)[4]
    assert peak["resolved"] and not peak["is_resonance"]
