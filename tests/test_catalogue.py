"""The catalogue motors (``stepdamp_env/bench/catalogue.json``): real motors from public
datasheets, for the coming catalogue split (stepdamp-bench v4). Every one loads
as ``--motors`` reads it, says where its values come from, and runs."""

from __future__ import annotations

import json
import math
import os

import pytest

from stepdamp_env.bench import load_motors_file
from stepdamp_env.bench.protocols.v3 import quick_protocol_v3
from stepdamp_env.motorfile import load_system
from stepdamp_env.simulation import RunSettings, simulate

PATH = os.path.join(os.path.dirname(__file__), "..", "stepdamp_env", "bench", "catalogue.json")


def _items():
    with open(PATH, encoding="utf-8") as fh:
        return json.load(fh)


def test_at_least_twenty_sourced_motors_load_as_the_board_reads_them():
    items = _items()
    systems = load_motors_file(PATH, quick_protocol_v3())
    assert len(systems) == len(items) >= 20
    assert all(item["source"] and item["notes"] for item in items)
    assert {s.motor.Nr for s in systems} == {50, 100}            # 1.8 and 0.9 degree
    for item, system in zip(items, systems):
        # The datasheet's holding torque: both phases at the rated current.
        assert math.isclose(system.motor.Km * math.sqrt(2) * item["rated_current_A"],
                            item["holding_torque_Nm"], rel_tol=1e-12)
        assert system.motor.L == item["phase_inductance_H"] < 0.1    # henries, not mH


def test_an_estimated_inertia_follows_the_stated_fit_and_a_given_one_is_kept():
    for item in _items():
        given = "rotor inertia not in the source" not in item["notes"]
        fit = 2.2e-05 * item["holding_torque_Nm"] ** 1.2098
        if not given:
            assert math.isclose(item["rotor_inertia_kgm2"], fit, rel_tol=5e-3)
        else:           # the fit's own motors lie within its stated scatter (x1.17, 1 sd)
            assert 1 / 1.4 < item["rotor_inertia_kgm2"] / fit < 1.4


@pytest.mark.slow
def test_every_catalogue_motor_runs_at_its_first_resonance():
    for item in _items():
        system = load_system(item)
        m = system.motor
        f4 = math.sqrt(m.Nr * m.Km * system.drive.holding_current / m.J) / (2 * math.pi * 4 * m.Nr)
        run = simulate(system, speed_rps=f4, settings=RunSettings(settle_s=0.05, window_s=0.05))
        assert math.isfinite(run.metrics.rms_velocity_error_rad_s), item["name"]
