"""One law over a speed range (issue #52): the schedule is the single-speed law at
its grid speeds, its C computes it, its interpolation converges."""

from __future__ import annotations

import json
import math
import os
import subprocess

import numpy as np
import pytest

from conftest import compiled_driver
from stepdamp_env.bench.firmware import correction, entry_law, firmware_knowledge, position_lowpass
from stepdamp_env.bench.firmware_schedule import (build_schedule, export_schedule,
                                                  interpolation_error, schedule_correction,
                                                  schedule_from_json)
from stepdamp_env.cli import main
from stepdamp_env.motorfile import load_system
from stepdamp_env.params import ParameterError

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
MOTOR = os.path.join(ROOT, "docs", "motors", "17hs4401.json")


@pytest.fixture(scope="module")
def knowledge():
    return firmware_knowledge(load_system(MOTOR))


def _law_at(entry, knowledge):
    return lambda v: entry_law(entry, knowledge, speed_rps=v)


@pytest.mark.parametrize("entry", ["ff-delay-comp", "tuned-gain-pair"])
def test_at_its_grid_speeds_the_schedule_is_the_single_speed_law(knowledge, entry):
    law_at = _law_at(entry, knowledge)
    schedule = build_schedule(law_at, 0.3, 2.7, 9)
    rng = np.random.default_rng(5)
    x = rng.uniform(-50.0, 50.0, 200)
    e_w = rng.uniform(-5.0, 5.0, 200)
    e_theta = np.cumsum(rng.uniform(-1e-3, 1e-3, 200))
    lp = position_lowpass(schedule.laws[0], e_theta)
    for law in schedule.laws:
        w = 2.0 * math.pi * law.speed_rps
        np.testing.assert_allclose(schedule_correction(schedule, x, e_w, w, e_theta, lp),
                                   correction(law, x, e_w, w, e_theta, lp), rtol=0, atol=1e-12)
    # The tables differ over the range: the schedule is not one law repeated.
    tables = schedule.coefficients_a()
    assert np.max(np.abs(tables[-1] - tables[0])) > 1e-4


def test_interpolation_converges_as_the_step_halves(knowledge):
    law_at = _law_at("ff-delay-comp", knowledge)
    errors = [interpolation_error(build_schedule(law_at, 0.3, 2.7, n), law_at)[0]
              for n in (4, 7, 13)]
    # Linear interpolation of a smooth table: about 4x less per halving.
    assert errors[0] > 3.0 * errors[1] > 9.0 * errors[2] > 0.0


def test_json_round_trip_and_speeds_outside_hold_the_ends(tmp_path, knowledge):
    schedule = build_schedule(_law_at("tuned-gain-pair", knowledge), 0.5, 1.5, 5)
    [path] = export_schedule(schedule, "json", tmp_path)
    with open(path, encoding="utf-8") as fh:
        data = json.load(fh)
    assert schedule_from_json(data) == schedule
    assert data["cost_per_pwm_period"]["table_doubles"] == 30 and len(data["speeds_rps"]) == 5
    x = np.linspace(0.0, 6.0, 7)
    for inside, outside in ((0.5, 0.1), (1.5, 40.0)):
        np.testing.assert_array_equal(
            schedule_correction(schedule, x, 0.0, 2 * math.pi * inside),
            schedule_correction(schedule, x, 0.0, 2 * math.pi * outside))


_DRIVER = """#include <stdio.h>
#include "{prefix}.h"

int main(void)
{{
    double x, e, w, p;
    double lowpass = 0.0;

    while (scanf("%lf %lf %lf %lf", &x, &e, &w, &p) == 4) {{
        printf("%.17g\\n", {prefix}_iq_correction_a(x, e, w, p, &lowpass));
    }}
    return 0;
}}
"""


def test_the_c_computes_the_python_schedule(tmp_path, knowledge):
    schedule = build_schedule(_law_at("tuned-gain-pair", knowledge), 0.3, 2.7, 13)
    paths = export_schedule(schedule, "c", tmp_path, "sched")
    exe = compiled_driver(paths[1], _DRIVER.format(prefix="sched"), tmp_path)
    rng = np.random.default_rng(52)
    n = 1000
    x = rng.uniform(-2000.0, 2000.0, n)
    e_w = rng.uniform(-30.0, 30.0, n)
    w = rng.choice([-1.0, 1.0], n) * 2 * math.pi * rng.uniform(0.0, 3.5, n)   # ends too
    w[:13] = 2 * math.pi * schedule.speeds_rps                               # grid speeds
    e_theta = np.cumsum(rng.uniform(-0.01, 0.01, n))
    text = "".join(" ".join(repr(float(v)) for v in row) + "\n"
                   for row in zip(x, e_w, w, e_theta))
    run = subprocess.run([exe], input=text, capture_output=True, text=True, timeout=60)
    assert run.returncode == 0, run.stderr
    out = np.array([float(v) for v in run.stdout.split()])
    expected = schedule_correction(schedule, x, e_w, w, e_theta,
                                   position_lowpass(schedule.laws[0], e_theta))
    np.testing.assert_allclose(out, expected, rtol=0.0, atol=1e-9)


def test_export_speeds_writes_one_law_and_bad_input_is_one_line(tmp_path, capsys):
    assert main(["export", "ff-delay-comp", "--motor", MOTOR, "--speeds", "0.3:1.5:0.3",
                 "--out", str(tmp_path), "--format", "json"]) == 0
    text = capsys.readouterr().out
    assert "5 speeds 0.3..1.5 rev/s" in text and "multiplications" in text
    assert "off by at most" in text
    for argv, words in (
            (["--speeds", "0.5:0.5:0.1"], "a schedule needs at least 2"),
            (["--speeds", "0.5:1:0.1", "--speed", "0.7"], "--speed and --speeds"),
            (["--speeds", "1:40:1"], "above the top speed")):
        assert main(["export", "ff-delay-comp", "--motor", MOTOR, "--out", str(tmp_path),
                     *argv]) == 2
        err = capsys.readouterr().err
        assert words in err and len(err.strip().splitlines()) == 1, err
    with pytest.raises(ParameterError, match="points"):
        build_schedule(lambda v: None, 0.1, 1.0, 1)
