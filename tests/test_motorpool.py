"""The datasheet pool (``stepdamp_env/datasheet_pool.json``) and the draw of training
motors over it (:mod:`stepdamp_env.motorpool`): real motors, none of the scored
catalogue's, drawn the same on every CPU, within the stated distribution."""

from __future__ import annotations

import json
import math
import re

import numpy as np
import pytest

from stepdamp_env.bench.protocols.v4 import CATALOGUE_PATH
from stepdamp_env.motorfile import load_system
from stepdamp_env.motorpool import (PoolDraw, draw_datasheet, draw_datasheets, pool,
                                    pool_motors)
from stepdamp_env.params import ParameterError

KEYS = ("step_angle_deg", "rated_current_A", "holding_torque_Nm", "phase_resistance_ohm",
        "phase_inductance_H")


def _plain(name):
    return re.sub(r"[^a-z0-9]", "", name.lower())


def test_no_pool_motor_is_a_scored_catalogue_motor():
    with open(CATALOGUE_PATH, encoding="utf-8") as fh:
        scored = json.load(fh)
    names = [_plain(m["name"]) for m in scored]
    values = {tuple(round(m[k], 9) for k in KEYS) for m in scored}
    for m in pool()["motors"]:
        plain = _plain(m["name"])
        assert not any(s in plain or plain in s for s in names), m["name"]
        assert "qsh" not in plain
        assert tuple(round(m[k], 9) for k in KEYS) not in values, m["name"]


def test_every_pool_motor_is_sourced_loads_and_has_a_datasheet_inertia():
    motors = pool()["motors"]
    assert len(motors) >= 200
    assert {m["split"] for m in motors} == {"train", "dev"}
    assert 0.1 < len(pool_motors("dev")) / len(motors) < 0.3
    for m in motors:
        assert "stepper-db.ts" in m["source"] and "line" in m["source"]
        system = load_system({k: m[k] for k in KEYS + ("rotor_inertia_kgm2",)})
        assert system.motor.Nr in (50, 100)
        assert 3e-4 <= system.motor.L / system.motor.R <= 1e-2
    # The ranges real catalogues span: NEMA 8 to 34.
    torques = [m["holding_torque_Nm"] for m in motors]
    assert min(torques) < 0.1 and max(torques) > 5.0


def test_the_train_and_dev_parts_share_no_motor():
    train = {m["name"] for m in pool_motors("train")}
    dev = {m["name"] for m in pool_motors("dev")}
    assert train and dev and not train & dev


def test_a_draw_is_reproducible_and_within_the_stated_distribution():
    a = draw_datasheets(123, 40)
    assert a == draw_datasheets(123, 40)
    assert a != draw_datasheets(124, 40)
    by_name = {m["name"]: m for m in pool_motors("train")}
    d = PoolDraw()
    bare = 0
    for values in a:
        base = by_name[values["name"].rsplit("~", 1)[0]]
        r = values["phase_resistance_ohm"] / base["phase_resistance_ohm"]
        l_ratio = values["phase_inductance_H"] / base["phase_inductance_H"]
        assert 1 - d.resistance_tolerance <= r <= 1 + d.resistance_tolerance
        assert 1 - d.inductance_tolerance <= l_ratio <= 1 + d.inductance_tolerance
        assert values["rotor_inertia_kgm2"] == base["rotor_inertia_kgm2"]
        share = values["detent_torque_Nm"] / base["holding_torque_Nm"]
        assert d.detent_share[0] <= share <= d.detent_share[1]
        load = values["load_inertia_kgm2"] / values["rotor_inertia_kgm2"]
        bare += load == 0.0
        assert load == 0.0 or d.load_ratio[0] <= load <= d.load_ratio[1]
        assert d.bus_voltage_V[0] <= values["bus_voltage_V"] <= d.bus_voltage_V[1]
        system = load_system(values)
        assert math.isclose(system.drive.Vdc, values["bus_voltage_V"])
    assert 10 <= bare <= 30                       # probability 1/2 of 40


def test_the_draw_pins_its_values_bit_for_bit():
    # fixedmath's exp/log and PCG64: the same bits on every CPU (test_architecture
    # runs the suite under emulated CPUs).
    values = draw_datasheet(np.random.default_rng(7))
    assert values["name"] == "Sanyo Denki SM2863-5166~0"
    assert values["phase_resistance_ohm"].hex() == "0x1.08d12e6159216p+0"
    assert values["bus_voltage_V"].hex() == "0x1.5fc6d30e40e22p+5"


def test_the_dev_part_draws_only_dev_motors():
    dev = {m["name"] for m in pool_motors("dev")}
    assert all(v["name"].rsplit("~", 1)[0] in dev for v in draw_datasheets(5, 20, "dev"))


@pytest.mark.parametrize("kwargs, message", [
    ({"resistance_tolerance": 1.0}, "resistance_tolerance=1.0 is outside its allowed range"),
    ({"bare_prob": -0.1}, "bare_prob=-0.1 is outside"),
    ({"load_ratio": (2.0, 1.0)}, "load_ratio=(2.0, 1.0) is outside"),
    ({"bus_voltage_V": (0.0, 48.0)}, "bus_voltage_V=(0.0, 48.0) is outside"),
])
def test_bad_draw_settings_are_refused_in_one_line(kwargs, message):
    with pytest.raises(ParameterError, match=re.escape(message)) as info:
        PoolDraw(**kwargs)
    assert "\n" not in str(info.value)


def test_bad_counts_seeds_and_parts_are_refused_in_one_line():
    with pytest.raises(ParameterError, match=r"count=0 is outside its allowed range \[1, 4096\]"):
        draw_datasheets(1, 0)
    with pytest.raises(ParameterError, match=r"seed=-1 is outside its allowed range"):
        draw_datasheets(-1, 2)
    with pytest.raises(ParameterError, match=r"part='test' is not one of \['train', 'dev'\]"):
        pool_motors("test")
    with pytest.raises(ParameterError, match=r"motor_pool='presets' is not one of "
                                             r"\['datasheets', 'datasheets-unrelated'\]"):
        draw_datasheets(1, 2, motor_pool="presets")


def _series(name):
    # The model without its brand, up to its first -, _ or (: another winding of a frame.
    head = _plain(re.split(r"[-_(]", name.split(" ", 1)[-1])[0])
    return head if len(head) >= 5 else None


def _near(a, b, factor):
    return a["step_angle_deg"] == b["step_angle_deg"] and all(
        1 / factor <= a[k] / b[k] <= factor for k in KEYS[1:])


def test_the_unrelated_pool_leaves_out_every_relative_of_a_scored_motor():
    with open(CATALOGUE_PATH, encoding="utf-8") as fh:
        scored = json.load(fh)
    full = {m["name"]: m for m in pool()["motors"]}
    unrelated = pool("datasheets-unrelated")["motors"]
    assert (len(pool_motors("train", "datasheets-unrelated")),
            len(pool_motors("dev", "datasheets-unrelated"))) == (166, 20)
    scored_series = {_series(m["name"]) for m in scored} - {None}
    for m in unrelated:
        # A motor of the full pool, values unchanged; a hash-dev motor may move to train.
        assert {k: v for k, v in m.items() if k != "split"} == \
            {k: v for k, v in full[m["name"]].items() if k != "split"}
        assert _series(m["name"]) not in scored_series, m["name"]
        assert not any(_near(m, s, 1.25) for s in scored), m["name"]
    train = pool_motors("train", "datasheets-unrelated")
    for d in pool_motors("dev", "datasheets-unrelated"):
        assert full[d["name"]]["split"] == "dev"
        assert not any(_near(d, t, 1.10) or (_series(d["name"]) is not None and
                                             _series(d["name"]) == _series(t["name"]))
                       for t in train), d["name"]
    dev = {m["name"] for m in pool_motors("dev", "datasheets-unrelated")}
    drawn = draw_datasheets(950_000, 12, "dev", motor_pool="datasheets-unrelated")
    assert all(v["name"].rsplit("~", 1)[0] in dev for v in drawn)
