"""``adaptive-ff`` for a drive's firmware: its adapting harmonic table as JSON and
C99 (:mod:`stepdamp_env.bench.firmware_online`), checked against the simulated
policy step by step."""

from __future__ import annotations

import dataclasses
import json
import subprocess

import numpy as np
import pytest

from conftest import c_compiler, compiled_driver, recorded_episode
from stepdamp_env import kernel as K
from stepdamp_env.bench import MotorKnowledge
from stepdamp_env.bench.firmware import KalmanTable, RepetitiveTable, entry_export, export_any
from stepdamp_env.bench.firmware_online import online_from_json, online_to_json
from stepdamp_env.bench.rig import CalibrationRig
from stepdamp_env.env.layout import HARMONIC_COS, HARMONIC_SIN, OBS
from stepdamp_env.params import FeedforwardModel, ParameterError
from stepdamp_env.presets import get_preset



def _knowledge(mode: str, nominal_j: float = 1.0) -> MotorKnowledge:
    """The patent motor and an identified model the table has something to learn
    from: off in every field (open loop), or with 30 % of the detent (servo, whose
    loop leaves a smaller ripple than the filter's noise otherwise). The drive's
    nominal inertia ``nominal_j`` times the plant's."""
    plant = get_preset("patent")
    nominal = dataclasses.replace(plant, motor=dataclasses.replace(
        plant.motor, J=nominal_j * plant.motor.J))
    exact = FeedforwardModel.from_motor(plant.motor)
    identified = (FeedforwardModel(Km=0.29, Kd1=0.0045, Kd2=0.0055, Kd4=0.013, phi1=-1.0,
                                   phi2=0.7, Fs=0.005) if mode == "open-loop" else
                  dataclasses.replace(exact, Kd1=0.3 * exact.Kd1, Kd2=0.3 * exact.Kd2,
                                      Kd4=0.3 * exact.Kd4))
    return MotorKnowledge(nominal=nominal, identified=identified, exact=exact, plant=plant,
                          rig=CalibrationRig(plant, noise_seed=0, accel_rps2=50.0))


def _run(entry, knowledge, mode, until_s=0.4):
    """A run of the entry at the h=4 resonance: each step's observation and
    action (float32), and every PWM period (kernel.TRACE columns), per step."""
    obs, actions, speed, result = recorded_episode(
        entry, knowledge, mode, until_s, on_step=lambda env, obs, start: env.step_trace,
        pwm_trace=True)
    return obs, actions, speed, result.trace



_DRIVER = """#include <stdio.h>
#include "{p}.h"

int main(void)
{{
    struct {p}_state state;
    float in[7];
    double x, w;
    int n;

    {p}_start(&state);
    while (fread(in, sizeof(float), 7, stdin) == 7) {{
        {p}_update(in[0], in + 1, &state);
        fwrite(state.action, sizeof(float), 6, stdout);
        if (fread(&n, sizeof(int), 1, stdin) != 1) {{
            return 1;
        }}
        while (n-- > 0) {{
            if (fread(&x, sizeof(double), 1, stdin) != 1
                    || fread(&w, sizeof(double), 1, stdin) != 1) {{
                return 1;
            }}
            x = {p}_iq_correction_a(x, w, &state);
            fwrite(&x, sizeof(double), 1, stdout);
        }}
    }}
    return 0;
}}
"""


@pytest.mark.parametrize("entry", ["adaptive-ff", "repetitive-control"])
@pytest.mark.parametrize("mode, nominal_j", [("open-loop", 1.0), ("servo", 1.0),
                                             ("open-loop", 0.5)])
def test_the_c_table_adapts_as_the_simulated_policy(tmp_path, entry, mode, nominal_j):
    """The C update, compiled with the strict flags and fed the observations the
    policy read, step by step, gives its actions bit for bit while the table
    moves; the C's correction at each PWM period's angle is the kernel's
    injected q current to 1e-12 A. With the drive's inertia half the motor's,
    a harmonic's guard trips (its table goes back to the start)."""
    c_compiler()                     # skips before the run without a compiler
    knowledge = _knowledge(mode, nominal_j)
    obs, actions, speed, trace = _run(entry, knowledge, mode)
    law = entry_export(entry, knowledge, mode=mode, speed_rps=speed)
    kalman = entry == "adaptive-ff"
    assert isinstance(law, KalmanTable if kalman else RepetitiveTable)
    first = law.adapt_step if kalman else law.wait_step    # no move up to this step
    assert len(obs) > first + 100
    assert online_from_json(json.loads(json.dumps(online_to_json(law)))) == law
    moved = np.any(actions != actions[0], axis=1)
    # Step k (from 1) is row k - 1: it adapts from step adapt_step + 1 on, after the probe.
    assert moved.any() and not moved[:first].any()
    pairs = actions.reshape(len(actions), 3, 2)
    back = np.all(pairs == pairs[0], axis=2)               # a harmonic at its first table
    tripped = [h for h in range(3) if (~back[:, h]).any()
               and back[np.argmax(~back[:, h]):, h].any()]
    if kalman:
        assert bool(tripped) == (nominal_j != 1.0)
    paths = export_any(law, "c", tmp_path, "table_under_test")
    exe = compiled_driver(paths[1], _DRIVER.format(p="table_under_test"), tmp_path)
    plant = knowledge.plant
    m = plant.motor
    step = m.full_step_rad / plant.drive.microsteps
    count = 2.0 * np.pi / plant.servo.encoder_cpr
    assert len(trace) == len(obs)
    chunks, angles = [], []
    for k in range(len(obs)):
        row = obs[k]
        inputs = np.concatenate([[row[OBS.velocity_error]],
                                 np.ravel(np.column_stack([row[HARMONIC_SIN],
                                                           row[HARMONIC_COS]]))])
        chunks.append(inputs.astype("<f4").tobytes())
        # The PWM periods of this step, which its action drives.
        rows = trace[k]
        if mode == "open-loop":
            angle = m.Nr * (np.floor(rows[:, K.TRACE.THETA_CMD] * (1.0 / step)) * step)
        else:
            angle = m.Nr * (rows[:, K.TRACE.THETA_FB] + 0.5 * count)
        w_cmd = rows[:, K.TRACE.OMEGA_CMD]
        angles.append(angle)
        chunks.append(np.array([len(angle)], dtype="<i4").tobytes())
        chunks.append(np.column_stack([angle, w_cmd]).astype("<f8").tobytes())
    run = subprocess.run([exe], input=b"".join(chunks), capture_output=True, timeout=120)
    assert run.returncode == 0, run.stderr
    data, at = run.stdout, 0
    for k in range(len(obs)):
        got = np.frombuffer(data, dtype="<f4", count=6, offset=at)
        at += 24
        np.testing.assert_array_equal(got.view(np.uint32), actions[k].view(np.uint32),
                                      err_msg=f"step {k}")
        n = len(angles[k])
        iq = np.frombuffer(data, dtype="<f8", count=n, offset=at)
        at += 8 * n
        if n:
            np.testing.assert_allclose(iq, trace[k][:, K.TRACE.IQ_FF], rtol=0.0,
                                       atol=1e-12, err_msg=f"step {k}")
    assert at == len(data)


def test_bad_online_tables_are_one_line_errors():
    law = entry_export("adaptive-ff", _knowledge("open-loop"))
    for change, text in [({"base_nm": (0.0,) * 5}, "base_nm must hold 6"),
                         ({"adapt_step": law.start_step - 1}, "adapt_step must not be below"),
                         ({"initial_action": (0.1,) * 6}, "initial_action must hold float32"),
                         ({"noise_variance": 0.0}, "noise_variance=0.0 must be > 0"),
                         ({"step_gain": float("nan")}, "step_gain=nan must be a finite")]:
        with pytest.raises(ParameterError, match=text) as info:
            KalmanTable(**{**law.__dict__, **change})
        assert "\n" not in str(info.value)
    with pytest.raises(ParameterError, match="not a stepdamp-firmware-online-table/1"):
        online_from_json({"format": "stepdamp-firmware-law/3"})


def test_the_cli_exports_the_adapting_table_and_refuses_a_schedule(tmp_path):
    from stepdamp_env.cli import main

    assert main(["export", "adaptive-ff", "--motor", "patent", "--format", "json",
                 "--out", str(tmp_path)]) == 0
    with open(tmp_path / "adaptive_ff.json") as fh:
        law = online_from_json(json.load(fh))
    assert law.entry == "adaptive-ff" and law.adapt_step > law.start_step
    assert main(["export", "adaptive-ff", "--motor", "patent", "--speeds", "0.5:1:0.25",
                 "--out", str(tmp_path)]) == 2
