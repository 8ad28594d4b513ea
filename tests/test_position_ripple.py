"""The position error's window metrics: at a resonance, where one detent
harmonic h carries the velocity ripple, the position ripple is that ripple
integrated, RMS(velocity error about its mean) / (h*Nr*w); v0-v3 records keep
their published fields, v4's carry the position metrics."""

import math

import pytest

from stepdamp_env import get_preset, simulate
from stepdamp_env.metrics import METRICS_V0_V3
from stepdamp_env.simulation import RunSettings, SpeedProfile


@pytest.mark.parametrize("h", [4, 2, 1])
def test_position_ripple_is_the_velocity_ripple_integrated_at_a_resonance(h):
    system = get_preset("patent")
    speed = system.predicted_resonances_rps()[h]
    m = simulate(system, profile=SpeedProfile(speed_rps=speed), settings=RunSettings()).metrics
    amps = m.harmonic_amplitude_rad_s
    assert amps[h] > 4.0 * max(a for k, a in amps.items() if k != h)   # one harmonic
    ac = math.sqrt(m.rms_velocity_error_rad_s ** 2 - m.mean_velocity_error_rad_s ** 2)
    expected = ac / (h * system.motor.Nr * 2.0 * math.pi * speed) / system.motor.full_step_rad
    assert m.position_ripple_steps == pytest.approx(expected, rel=0.05)
    # The RMS about the command holds the ripple and the mean lag.
    assert m.rms_position_error_steps >= m.position_ripple_steps > 0.0


def test_frozen_protocols_record_only_their_published_metrics():
    from stepdamp_env.bench.protocols import protocol_for

    for version in ("v0", "v1", "v2", "v3"):
        assert protocol_for(version, quick=True).run_metrics == METRICS_V0_V3
    assert protocol_for("v4", quick=True).run_metrics is None
    m = simulate(get_preset("patent"), profile=SpeedProfile(speed_rps=0.5)).metrics
    assert list(m.to_dict(METRICS_V0_V3)) == list(METRICS_V0_V3)
    assert {"rms_position_error_steps", "position_ripple_steps"} <= set(m.to_dict())
