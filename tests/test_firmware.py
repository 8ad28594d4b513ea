"""Firmware out (issue #34, point 6): the exported law is what the simulation applies,
its C is the Python law to 1e-9, its tables and files hold together."""

from __future__ import annotations

import json
import math
import os
import subprocess

import numpy as np
import pytest

from conftest import c_compiler, compiled_driver
from stepdamp_baselines import make_baseline
from stepdamp_env import kernel as K
from stepdamp_env.env.layout import OBS
from stepdamp_env.bench import MotorKnowledge, run_episode
from stepdamp_env.bench.firmware import (FilteredFeedback, FirmwareLaw, c_source, correction,
                                         entry_law, export_law, filtered_feedback_currents,
                                         firmware_knowledge, from_json, microstep_table,
                                         policy_law, position_lowpass, to_json)
from stepdamp_env.bench.firmware_schedule import (build_schedule, export_schedule,
                                                  schedule_from_json, schedule_to_json)
from stepdamp_env.bench.policy import PolicyCard
from stepdamp_env.bench.registry import resolve_policy
from stepdamp_env.bench.rig import CalibrationRig
from stepdamp_env.params import FeedforwardModel, ParameterError
from stepdamp_env.presets import get_preset

HERE = os.path.dirname(os.path.abspath(__file__))


@pytest.fixture(scope="module")
def knowledge():
    """The patent motor, and an identified model that differs from the plant's in
    every field (so a law built from the wrong model shows)."""
    plant = get_preset("patent")
    identified = FeedforwardModel(Km=0.29, Kd1=0.0045, Kd2=0.0055, Kd4=0.013, phi1=-1.0,
                                  phi2=0.7, Fs=0.005)
    return MotorKnowledge(nominal=plant, identified=identified,
                          exact=FeedforwardModel.from_motor(plant.motor), plant=plant,
                          rig=CalibrationRig(plant, noise_seed=0, accel_rps2=50.0))


def _pwm_trace(entry, knowledge, mode, speed_rps, until_s=0.03):
    """Every PWM period of a short run of the entry (kernel.TRACE columns)."""
    result = run_episode(resolve_policy(entry).make(), knowledge, knowledge.plant, mode=mode,
                         speed_rps=speed_rps, seed=3, measure_from_s=0.0, window_s=until_s,
                         until_s=until_s, on_step=lambda env, obs, start: env.step_trace,
                         pwm_trace=True)
    assert not result.terminated
    return np.concatenate(result.trace)


@pytest.mark.parametrize("entry, mode", [("patent-ff-identified", "open-loop"),
                                         ("ff-delay-comp", "open-loop"),
                                         ("ff-delay-comp", "servo"),
                                         ("calibrated-table", "open-loop"),
                                         ("tuned-constant-gain", "open-loop"),
                                         ("tuned-constant-gain", "servo"),
                                         ("tuned-gain-pair", "open-loop"),
                                         ("tuned-gain-pair", "servo")])
def test_the_python_law_is_what_the_simulation_applies(knowledge, entry, mode):
    # The kernel's injected q current (feedforward, plus the v1 damping law's
    # current) at each PWM period, against correction() at the Park angle the
    # kernel took, the law's velocity error (the samples of the period before)
    # and the command speed.
    plant = knowledge.plant
    speed = plant.predicted_resonances_rps()[2]       # where the delay compensation shows
    law = entry_law(entry, knowledge, mode=mode, speed_rps=speed)
    tr = _pwm_trace(entry, knowledge, mode, speed)
    m = plant.motor
    if mode == "open-loop":
        step = m.full_step_rad / plant.drive.microsteps
        angle = m.Nr * (np.floor(tr[:, K.TRACE.THETA_CMD] * (1.0 / step)) * step)
    else:
        count = 2.0 * math.pi / plant.servo.encoder_cpr
        angle = m.Nr * (tr[:, K.TRACE.THETA_FB] + 0.5 * count)
    e_w = tr[:-1, K.TRACE.OMEGA_CMD] - tr[:-1, K.TRACE.OMEGA_FB]
    e_theta = tr[:-1, K.TRACE.THETA_CMD] - tr[:-1, K.TRACE.THETA_FB]
    expected = tr[1:, K.TRACE.IQ_FF]
    got = correction(law, angle[1:], e_w, tr[1:, K.TRACE.OMEGA_CMD], e_theta,
                     position_lowpass(law, e_theta))
    assert len(expected) > 500
    np.testing.assert_allclose(got, expected, rtol=0.0, atol=1e-12)
    # The law is not a trivial one: the table differs from the plain identified
    # model where it should, and the feedback and friction terms act.
    plain = knowledge.identified.coefficients()
    table = law.coefficients_nm()
    delay_comp = entry != "patent-ff-identified"
    assert (max(abs(a - b) for a, b in zip(table, plain)) > 1e-4) == delay_comp
    if entry.startswith("tuned-"):
        assert law.velocity_gain_a_s_per_rad > 0.0
        assert np.max(np.abs(law.velocity_gain_a_s_per_rad * e_w)) > 1e-3
    assert law.stateful == (entry == "tuned-gain-pair")
    if law.stateful:        # the position term acts: without it the law differs
        plain = correction(law, angle[1:], e_w, tr[1:, K.TRACE.OMEGA_CMD])
        assert np.max(np.abs(plain - expected)) > 1e-3
    assert (law.friction_a > 0.0) == (mode == "servo")


FILTERED = ("velocity-feedback", "sensorless-damping")


def _filtered_run(entry, knowledge, speed, until_s=0.2):
    """A run of a filtered-feedback entry: each agent step's speed and position
    errors as its policy read them (rad/s, rad), the current its action held (A),
    and every PWM period (kernel.TRACE columns), per step."""
    policy = resolve_policy(entry).make()
    seen, held = [], []
    act = policy.act

    def recording(observation):
        action = act(observation)
        seen.append(np.array(observation, dtype=np.float64))
        held.append(float(action[6]))
        return action

    policy.act = recording
    result = run_episode(policy, knowledge, knowledge.plant, mode="open-loop", speed_rps=speed,
                         seed=3, measure_from_s=0.0, window_s=until_s, until_s=until_s,
                         on_step=lambda env, obs, start: env.step_trace, pwm_trace=True)
    assert not result.terminated
    obs = np.array(seen)
    nominal = knowledge.nominal
    e_w = obs[:, OBS.velocity_error] * (2.0 * math.pi * abs(speed))
    e_theta = obs[:, OBS.position_error] * nominal.motor.full_step_rad
    return e_w, e_theta, np.array(held), result.trace


@pytest.mark.parametrize("entry", FILTERED)
def test_the_filtered_feedback_is_what_the_simulation_applies(knowledge, entry):
    """velocity-feedback and sensorless-damping: the exported law's update, fed the
    errors the policy read at each agent step, gives its action's current bit for
    bit; the table plus the held current is the kernel's injected q current at
    every PWM period, to 1e-12 A."""
    plant = knowledge.plant
    speed = plant.predicted_resonances_rps()[4]
    law = entry_law(entry, knowledge, speed_rps=speed)
    f = law.filtered_feedback
    assert f is not None and f.kind == ("encoder" if entry == "velocity-feedback"
                                        else "back-emf")
    assert to_json(law)["format"].endswith("/3") and from_json(to_json(law)) == law
    e_w, e_theta, action, trace = _filtered_run(entry, knowledge, speed)
    currents = filtered_feedback_currents(law, e_w, e_theta)
    np.testing.assert_array_equal(currents, action.astype(np.float32).astype(np.float64)
                                  * f.current_scale_a)
    assert np.max(np.abs(currents)) > 1e-3                  # the feedback acts
    m = plant.motor
    step = m.full_step_rad / plant.drive.microsteps
    for k, rows in enumerate(trace):
        assert len(rows) == f.periods_per_update
        angle = m.Nr * (np.floor(rows[:, K.TRACE.THETA_CMD] * (1.0 / step)) * step)
        np.testing.assert_allclose(rows[:, K.TRACE.IQ_FF], correction(law, angle) + currents[k],
                                   rtol=0.0, atol=1e-12)
    # The law with another gain differs: the test sees the gains.
    other = FilteredFeedback(**{**f.__dict__, "gain_a": f.gain_a * 1.5})
    assert not np.array_equal(filtered_feedback_currents(
        FirmwareLaw(**{**law.__dict__, "filtered_feedback": other}), e_w, e_theta), currents)


_FILTERED_DRIVER = """#include <stdio.h>
#include "{prefix}.h"

int main(void)
{{
    struct {prefix}_feedback_state state = {{0.0, 0.0, 0.0, 0}};
    double e, p;

    while (scanf("%lf %lf", &e, &p) == 2) {{
        printf("%.17g\\n", {prefix}_feedback_update_a(e, p, &state));
    }}
    return 0;
}}
"""


@pytest.mark.parametrize("entry", FILTERED)
def test_the_c_filtered_feedback_computes_the_simulations_currents(tmp_path, knowledge, entry):
    """The C update function, compiled with the strict flags and fed a simulated
    run's errors step by step, returns the currents the simulation held, cell for
    cell; the schedule over speed carries the same function."""
    c_compiler()                     # skips before the run without a compiler
    plant = knowledge.plant
    speed = plant.predicted_resonances_rps()[4]
    law = entry_law(entry, knowledge, speed_rps=speed)
    e_w, e_theta, action, _ = _filtered_run(entry, knowledge, speed, until_s=0.1)
    # Far errors too: both sides of the bound.
    e_w = np.concatenate([e_w, [40.0, -40.0, 0.0, 1e3, -1e3]])
    e_theta = np.concatenate([e_theta, [0.02, -0.02, 0.0, 0.5, -0.5]])
    expected = filtered_feedback_currents(law, e_w, e_theta)
    assert set(np.round(np.abs(expected[-5:]) / law.filtered_feedback.current_scale_a, 9)) \
        & {1.0}
    held = action.astype(np.float32).astype(np.float64) * law.filtered_feedback.current_scale_a
    np.testing.assert_array_equal(expected[:len(held)], held)
    text = "".join(f"{a!r} {b!r}\n" for a, b in zip(e_w.tolist(), e_theta.tolist()))
    for kind in ("law", "schedule"):
        out_dir = tmp_path / kind
        if kind == "law":
            paths = export_law(law, "c", out_dir, "law_under_test")
        else:
            schedule = build_schedule(lambda v: entry_law(entry, knowledge, speed_rps=v),
                                      0.5 * speed, 1.5 * speed, 3)
            data = json.loads(json.dumps(schedule_to_json(schedule)))
            assert data["format"].endswith("/2") and data["filtered_feedback"]["kind"] \
                == law.filtered_feedback.kind
            assert schedule_from_json(data) == schedule
            paths = export_schedule(schedule, "c", out_dir, "law_under_test")
        exe = compiled_driver(paths[1], _FILTERED_DRIVER.format(prefix="law_under_test"),
                              out_dir)
        run = subprocess.run([exe], input=text, capture_output=True, text=True, timeout=60)
        assert run.returncode == 0, run.stderr
        got = np.array([float(v) for v in run.stdout.split()])
        np.testing.assert_array_equal(got, expected)



_DRIVER = """#include <stdio.h>
#include "{prefix}.h"

int main(void)
{{
    double x, e, w;
    int k;

    for (k = 0; k < {macro}_TABLE_SIZE; ++k) {{
        printf("%.17g\\n", {prefix}_microstep_table_a[k]);
    }}
    while (scanf("%lf %lf %lf", &x, &e, &w) == 3) {{
        printf("%.17g\\n", {prefix}_iq_correction_a(x, e, w));
    }}
    return 0;
}}
"""
# A law with the position term keeps one state (the high-pass's), the caller's.
_STATEFUL_DRIVER = """#include <stdio.h>
#include "{prefix}.h"

int main(void)
{{
    double x, e, w, p;
    double lowpass = 0.0;
    int k;

    for (k = 0; k < {macro}_TABLE_SIZE; ++k) {{
        printf("%.17g\\n", {prefix}_microstep_table_a[k]);
    }}
    while (scanf("%lf %lf %lf %lf", &x, &e, &w, &p) == 4) {{
        printf("%.17g\\n", {prefix}_iq_correction_a(x, e, w, p, &lowpass));
    }}
    return 0;
}}
"""


def _synthetic_law() -> FirmwareLaw:
    return FirmwareLaw(entry="synthetic", motor="test", mode="servo", speed_rps=1.0,
                       pwm_hz=20000.0, nr=50, microsteps=16, km_nm_per_a=0.3,
                       harmonics=(1, 2, 4), amplitude_a=(0.1, 0.0, 0.05),
                       phase_rad=(-3.0, 1.0, 2.5), friction_a=0.02,
                       velocity_gain_a_s_per_rad=-0.2, feedback_limit_a=1.5)


@pytest.mark.parametrize("which", ["tuned-constant-gain/servo", "ff-delay-comp/open-loop",
                                   "tuned-gain-pair/open-loop", "synthetic"])
def test_the_c_source_computes_the_python_law(tmp_path, which):
    c_compiler()                     # skips before the run without a compiler
    if which == "synthetic":
        law = _synthetic_law()
    else:
        entry, mode = which.split("/")
        law = entry_law(entry, firmware_knowledge(get_preset("patent")), mode=mode)
    prefix = "law_under_test"
    paths = export_law(law, "c", tmp_path, prefix)
    assert [os.path.basename(p) for p in paths] == [f"{prefix}.h", f"{prefix}.c"]
    driver = _STATEFUL_DRIVER if law.stateful else _DRIVER
    exe = compiled_driver(paths[1], driver.format(prefix=prefix, macro=prefix.upper()),
                          tmp_path)
    rng = np.random.default_rng(34)
    n = 1000
    x = rng.uniform(-2000.0, 2000.0, n)
    x[:16] = 2.0 * math.pi * np.arange(16) / law.table_size     # exact microsteps too
    e_w = rng.uniform(-30.0, 30.0, n)                           # both sides of the clamp
    w_cmd = rng.choice([-1.0, 0.0, 1.0], n) * rng.uniform(0.0, 100.0, n)
    e_theta = np.cumsum(rng.uniform(-0.01, 0.01, n))             # a wandering position error
    columns = (x, e_w, w_cmd, e_theta) if law.stateful else (x, e_w, w_cmd)
    text = "".join(" ".join(repr(float(v)) for v in row) + "\n" for row in zip(*columns))
    run = subprocess.run([exe], input=text, capture_output=True, text=True, timeout=60)
    assert run.returncode == 0, run.stderr
    out = np.array([float(v) for v in run.stdout.split()])
    assert len(out) == law.table_size + n
    np.testing.assert_array_equal(out[:law.table_size], microstep_table(law))
    np.testing.assert_allclose(out[law.table_size:], correction(
        law, x, e_w, w_cmd, e_theta, position_lowpass(law, e_theta)), rtol=0.0, atol=1e-9)
    # Every branch of the C was taken.
    if math.isfinite(law.feedback_limit_a) and law.velocity_gain_a_s_per_rad != 0.0:
        assert np.any(np.abs(law.velocity_gain_a_s_per_rad * e_w) > law.feedback_limit_a)


def test_the_header_declares_one_documented_function():
    header, source = c_source(_synthetic_law(), "demo")
    assert header.count("(double electrical_angle_rad") == 1
    for words in ("electrical_angle_rad  x (rad)", "velocity_error_rad_s  e_w = w_cmd - w_est",
                  "command_speed_rad_s   w_cmd", "Returns               the correction (A)"):
        assert words in header
    # Only sin from libm, no allocation, no mutable globals.
    for banned in ("malloc", "calloc", "free(", "exp(", "atan", "sqrt(", "pow("):
        assert banned not in source
    assert "sin(" in source and "\nstatic double" not in source and "\ndouble demo_" in source


def test_the_microstep_table_is_the_correction_at_each_microstep():
    law = entry_law("ff-delay-comp", firmware_knowledge(get_preset("patent")))
    table = microstep_table(law)
    assert table.shape == (4 * law.microsteps,)
    k = np.arange(len(table))
    np.testing.assert_array_equal(table, correction(law, 2.0 * math.pi * k / len(table)))
    # What the open-loop kernel takes as its Park angle at microstep count n, for
    # n past one period and negative, is the table's row n mod 4*microsteps.
    system = get_preset("patent")
    step = system.motor.full_step_rad / system.drive.microsteps
    n = np.arange(-300, 700)
    theta_cmd = (n + 0.5) * step
    angle = system.motor.Nr * (np.floor(theta_cmd * (1.0 / step)) * step)
    np.testing.assert_allclose(table[n % len(table)], correction(law, angle), rtol=0.0,
                               atol=1e-12)
    # Feedback and friction are not in the table.
    tcg = entry_law("tuned-constant-gain", firmware_knowledge(system), mode="servo")
    np.testing.assert_array_equal(microstep_table(tcg), correction(tcg, 2 * math.pi * k / 256,
                                                                   0.0, 0.0))


def test_json_round_trip(tmp_path):
    system = get_preset("patent")
    for law in (_synthetic_law(), entry_law("ff-delay-comp", firmware_knowledge(system)),
                entry_law("tuned-constant-gain", firmware_knowledge(system), mode="servo"),
                entry_law("tuned-gain-pair", firmware_knowledge(system))):
        data = to_json(law)
        # A law without the position term keeps format /1 (what older readers take).
        assert data["format"].endswith("/2" if law.stateful else "/1")
        assert ("position_gain_a_per_rad" in data) == law.stateful
        assert from_json(json.loads(json.dumps(data))) == law
        [path] = export_law(law, "json", tmp_path / "out")
        assert os.path.basename(path) == law.entry.replace("-", "_") + ".json"
        with open(path, encoding="utf-8") as fh:
            written = json.load(fh)
        assert from_json(written) == law
        assert written["microstep_table_a"] == microstep_table(law).tolist()
        assert [r["harmonic"] for r in written["harmonic_table"]] == [1, 2, 4]
    # No limit is written as null (JSON has no infinity) and read back as inf.
    ff = entry_law("ff-delay-comp", firmware_knowledge(system))
    assert to_json(ff)["feedback_limit_a"] is None and math.isinf(from_json(to_json(ff))
                                                                  .feedback_limit_a)
    with pytest.raises(ParameterError, match="format"):
        from_json({"entry": "x"})


class _Learned:
    name = "some-agent"
    card = PolicyCard(sensors="encoder", model="identified", learned=True)

    def env_options(self, knowledge):
        return {"base_controller": "patent-ff", "action_mode": "harmonic"}

    def reset(self, context):
        pass

    def act(self, observation):
        return np.zeros(6, dtype=np.float32)


@pytest.mark.parametrize("entry, why", [
    ("none", "adds no correction"), ("adaptive-ff", "adapts its harmonic table on line"),
    ("repetitive-control", "changes while it runs"), ("oracle-floor", "oracle"),
    ("velocity-feedback@servo", "in servo: the servo's own loop is velocity feedback"),
    ("sensorless-damping@servo", "in servo: a servo closes its loop on an encoder"),
    ("privileged-bound", "oracle"), ("plant-bound", "oracle")])
def test_entries_that_cannot_be_exported_say_why_in_one_line(entry, why):
    entry, _, mode = entry.partition("@")
    with pytest.raises(ParameterError, match=f"entry '{entry}' cannot be exported.*{why}") \
            as info:
        entry_law(entry, firmware_knowledge(get_preset("patent")), mode=mode or "open-loop")
    assert "\n" not in str(info.value)


def test_policies_without_a_law_and_missing_knowledge_are_one_line_errors():
    system = get_preset("patent")
    know = firmware_knowledge(system)
    with pytest.raises(ParameterError, match="'some-agent' cannot be exported: it is a learned"):
        policy_law(_Learned(), know)
    with pytest.raises(ParameterError, match="'test-nominal-ff' cannot be exported: it has no "
                                             "firmware_law"):
        entry_law(os.path.join(HERE, "leaderboard_policy.py") + ":NominalFeedforward", know)
    # A ValueError of the entry (here: no rig to calibrate on) becomes one line.
    no_rig = MotorKnowledge(nominal=system, identified=know.identified, exact=know.exact)
    with pytest.raises(ParameterError, match="'calibrated-table' cannot be exported: "
                                             "calibrated-table needs a calibration rig"):
        policy_law(make_baseline("calibrated-table"), no_rig)
    # A subclass that changes the filtered feedback's law is not exported as its parent's.
    louder_class = type("Louder", (type(make_baseline("velocity-feedback")),),
                        {"act_batch": lambda self, obs, rows: 2.0 * super(
                            louder_class, self).act_batch(obs, rows)})
    with pytest.raises(ParameterError, match="'velocity-feedback' cannot be exported: its "
                                             "law is not the filtered feedback "
                                             "VelocityFeedback exports"):
        policy_law(louder_class(), know)
    no_model = MotorKnowledge(nominal=system, identified=None, exact=know.exact)
    for entry in ("ff-delay-comp", "tuned-constant-gain"):
        with pytest.raises(ParameterError, match=f"'{entry}' cannot be exported: .*identified"):
            entry_law(entry, no_model)


def test_bad_arguments_name_the_parameter(tmp_path):
    law = _synthetic_law()
    know = firmware_knowledge(get_preset("patent"))
    with pytest.raises(ParameterError, match="mode='sideways'"):
        entry_law("ff-delay-comp", know, mode="sideways")
    with pytest.raises(ParameterError, match="speed_rps=-1.0"):
        entry_law("ff-delay-comp", know, speed_rps=-1.0)
    from stepdamp_env.analysis import bridge_limit_rps

    top = bridge_limit_rps(know.nominal)
    with pytest.raises(ParameterError, match=r"speed_rps=.* is above the top speed .*allowed: "
                                             r"\(0, "):
        entry_law("ff-delay-comp", know, speed_rps=1.01 * top)
    assert entry_law("ff-delay-comp", know, speed_rps=0.99 * top).speed_rps == 0.99 * top
    with pytest.raises(ParameterError, match="format='pdf'"):
        export_law(law, "pdf", tmp_path)
    for prefix in ("1law", "my-law", "_law", "double", ""):
        with pytest.raises(ParameterError, match="prefix="):
            export_law(law, "c", tmp_path, prefix)
    with pytest.raises(ParameterError, match="amplitude_a"):
        FirmwareLaw(**{**law.__dict__, "amplitude_a": (0.1, math.nan, 0.0)})
    with pytest.raises(ParameterError, match="feedback_limit_a"):
        FirmwareLaw(**{**law.__dict__, "feedback_limit_a": 0.0})
    good = dict(kind="encoder", periods_per_update=20, gain_a=0.02, gain_b=-40.0,
                lowpass_beta=0.17, highpass_alpha=0.15, current_scale_a=0.5)
    assert FilteredFeedback(**good).periods_per_update == 20
    for name, value in (("kind", "pid"), ("periods_per_update", 0), ("gain_a", math.inf),
                        ("lowpass_beta", 0.0), ("highpass_alpha", 1.5),
                        ("current_scale_a", -1.0)):
        with pytest.raises(ParameterError, match=f"{name}="):
            FilteredFeedback(**{**good, name: value})
    with pytest.raises(ParameterError, match="highpass_alpha must be 0 for kind 'back-emf'"):
        FilteredFeedback(**{**good, "kind": "back-emf"})
    with pytest.raises(ParameterError, match="no per-period gains"):
        FirmwareLaw(**{**law.__dict__, "filtered_feedback": FilteredFeedback(**good)})
    with pytest.raises(ParameterError, match="has no filtered feedback"):
        filtered_feedback_currents(law, [0.0])
    assert os.listdir(tmp_path) == []


def test_the_export_modes_an_entry_declares_are_those_export_writes():
    """export_modes and firmware_drives (what the board's firmware section says)
    against what entry_export does, for every default entry in both modes (and
    on both drives where the entry names its drives)."""
    from stepdamp_env.bench.firmware import FirmwareNetwork, OnlineTableLaw, entry_export, \
        export_kind, export_modes
    from stepdamp_env.bench.firmware_board import firmware_field, render_firmware
    from stepdamp_env.bench.registry import default_policy_names
    from stepdamp_env.cli.options import register_policies

    register_policies()
    kinds = set()
    for name in default_policy_names():
        policy = resolve_policy(name).make()
        drives = getattr(policy, "firmware_drives", None)
        for drive in ("current", "voltage") if drives is not None else ("current",):
            knowledge = firmware_knowledge(get_preset("patent").replace(drive_mode=drive))
            for mode in ("open-loop", "servo"):
                try:
                    written = entry_export(name, knowledge, mode=mode)
                except ParameterError:
                    written = None
                declared = mode in export_modes(policy) and (drives is None or drive in drives)
                assert (written is not None) == declared, (name, mode, drive)
                if written is not None:
                    kind = ("network" if isinstance(written, FirmwareNetwork) else
                            "online table" if isinstance(written, OnlineTableLaw) else "law")
                    assert kind == export_kind(policy), name
                    kinds.add(kind)
    assert kinds == {"law", "network", "online table"}
    # The mid-band networks: open loop, voltage-mode drive, and the board says so.
    board = {"firmware": firmware_field({n: resolve_policy(n) for n in ("ppo-mid-band",
                                                                          "ppo-open-loop")})}
    assert board["firmware"]["ppo-mid-band"] == {"kind": "network", "modes": ["open-loop"],
                                                 "drives": ["voltage"]}
    assert render_firmware(board)[4:] == [
        "- the policy network, in open loop only: `ppo-open-loop`",
        "- the policy network, in open loop only, on the voltage-mode drive only: "
        "`ppo-mid-band`"]
