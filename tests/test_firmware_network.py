"""Learned entries for a drive's firmware: the policy network as JSON and C99
(:mod:`stepdamp_env.bench.firmware_net`), checked against the simulated policy."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np
import pytest

from conftest import compiled_driver, recorded_episode
from stepdamp_env.bench import run_episode
from stepdamp_env.bench.firmware import entry_export, firmware_knowledge
from stepdamp_env.bench.firmware_net import (FirmwareNetwork, export_network, network_actions,
                                             network_c_source, network_from_json,
                                             network_outputs, network_to_json)
from stepdamp_env.bench.registry import resolve_policy
from stepdamp_env.cli.options import register_policies
from stepdamp_env.params import ParameterError
from stepdamp_env.presets import get_preset

# tanh hidden layers (PPO), ReLU with a squashed tanh output (TD3), linear (ARS).
LEARNED = ("ppo-open-loop", "td3-per-step", "ars-open-loop")


@pytest.fixture(scope="module", autouse=True)
def _registered():
    register_policies()


def _knowledge():
    return firmware_knowledge(get_preset("patent"))


def _recorded_run(entry: str, until_s: float = 0.6):
    """A run of the entry at the patent motor's h=4 resonance: every observation
    its policy read and the action it gave (float32 rows)."""
    from stepdamp_env.bench import MotorKnowledge
    from stepdamp_env.params import FeedforwardModel

    plant = get_preset("patent")
    model = FeedforwardModel.from_motor(plant.motor)
    knowledge = MotorKnowledge(nominal=plant, identified=model, exact=model, plant=plant)
    obs, actions, speed, _ = recorded_episode(entry, knowledge, "open-loop", until_s)
    return obs, actions, speed


def _far_observations(net: FirmwareNetwork, n: int = 400) -> np.ndarray:
    """Observations over the whole observation box (+-10), to reach the clip and
    the tanh's every branch."""
    rng = np.random.default_rng(7)
    return rng.uniform(-10.0, 10.0, size=(n, net.sizes[0])).astype(np.float32)


@pytest.mark.parametrize("entry", LEARNED)
def test_the_exported_network_is_the_simulated_policy(entry):
    """The reference of the exported network, fed the observations the policy read
    in a simulated run, gives its actions bit for bit; it is the model's own
    (another seed's network differs)."""
    obs, actions, speed = _recorded_run(entry)
    net = entry_export(entry, _knowledge(), speed_rps=speed)
    assert isinstance(net, FirmwareNetwork) and net.sizes[0] == obs.shape[1]
    np.testing.assert_array_equal(network_actions(net, obs), actions)
    # td3-per-step's action layer is zero on every seed (docs/agents.md: it learned
    # nothing past its start, ff-delay-comp); the others act.
    assert (np.ptp(actions) == 0.0) == (entry == "td3-per-step")
    for name, value in net.constant_inputs.items():            # the run's own context
        np.testing.assert_array_equal(obs[:, net.observation_names.index(name)],
                                      np.float32(value))
    assert len(net.constant_inputs) == 9
    policy = resolve_policy(entry).make()
    far = _far_observations(net)
    np.testing.assert_array_equal(network_actions(net, far),
                                  policy.act_batch(far, np.zeros(len(far), dtype=np.int64)))
    assert net.decision_hz == float(policy.options.get("agent_hz", 100.0))
    other = FirmwareNetwork(**{**net.__dict__, "biases": tuple(b + 0.01 for b in net.biases)})
    assert not np.array_equal(network_actions(other, far), network_actions(net, far))



_DRIVER = """#include <stdio.h>
#include "{prefix}.h"

int main(void)
{{
    float obs[{macro}_N_OBSERVATION], act[{macro}_N_ACTION];
    double out[{macro}_N_ACTION];

    while (fread(obs, sizeof(float), {macro}_N_OBSERVATION, stdin)
           == {macro}_N_OBSERVATION) {{
        {prefix}_policy_action(obs, act);
        {prefix}_policy_output(obs, out);
        fwrite(act, sizeof(float), {macro}_N_ACTION, stdout);
        fwrite(out, sizeof(double), {macro}_N_ACTION, stdout);
    }}
    return 0;
}}
"""


def _compiled(net: FirmwareNetwork, rows: np.ndarray, tmp_path) -> np.ndarray:
    """The exported C, compiled with the strict flags, run on ``rows``: per row its
    float action and its double output."""
    paths = export_network(net, "c", str(tmp_path), "net_under_test")
    exe = compiled_driver(paths[1], _DRIVER.format(prefix="net_under_test",
                                                   macro="NET_UNDER_TEST"), tmp_path)
    run = subprocess.run([exe], input=rows.astype("<f4").tobytes(), capture_output=True,
                         timeout=60)
    assert run.returncode == 0, run.stderr
    k = net.sizes[-1]
    return np.frombuffer(run.stdout, dtype=np.dtype([("action", "<f4", k),
                                                     ("output", "<f8", k)]))


@pytest.mark.parametrize("entry", LEARNED)
def test_the_c_network_computes_the_simulated_policys_actions(tmp_path, entry):
    """The C99 network, compiled with the strict flags, fed the simulated run's
    observations and observations over the whole box, returns the policy's
    actions cell for cell, bit for bit."""
    obs, actions, speed = _recorded_run(entry, until_s=0.3)
    net = entry_export(entry, _knowledge(), speed_rps=speed)
    if entry == "td3-per-step":
        # Its zero action layer made random, so that the squashed output varies (the
        # recorded actions stay zero: they are the real network's).
        head = net.sizes[-2] * net.sizes[-1]
        w = np.array(net.weights)
        w[-head:] = np.random.default_rng(3).normal(0.0, 0.3, head)
        test_net = FirmwareNetwork(**{**net.__dict__, "weights": tuple(w)})
        actions = network_actions(test_net, obs)
        net = test_net
    rows = np.concatenate([obs, _far_observations(net)])
    expected = np.concatenate([actions, network_actions(net, rows[len(obs):])])
    got = _compiled(net, rows, tmp_path)
    np.testing.assert_array_equal(got["action"].view(np.uint32), expected.view(np.uint32))
    assert np.any(np.abs(expected) == 1.0)                   # the clip is reached
    # The double output: fixednet's to 1e-12 (the same operations, so in fact exactly).
    want = network_outputs(net, rows)
    np.testing.assert_allclose(got["output"], want, rtol=0.0, atol=1e-12)
    np.testing.assert_array_equal(got["output"], want)


def test_json_round_trip_and_the_header(tmp_path):
    net = entry_export("ppo-open-loop", _knowledge())
    path = export_network(net, "json", str(tmp_path))[0]
    with open(path) as fh:
        data = json.load(fh)
    assert data["format"] == "stepdamp-firmware-network/1"
    assert data["multiply_adds_per_decision"] == 36 * 64 + 64 * 64 + 64 * 8
    assert network_from_json(data) == net
    assert network_from_json(json.loads(json.dumps(network_to_json(net)))) == net
    header, _ = network_c_source(net, "pol")
    assert "void pol_policy_action(const float observation[POL_N_OBSERVATION]" in header
    assert "position_error_1" in header and "kv  (x " in header
    assert header.count("#define POL_N_OBSERVATION 36") == 1


def test_bad_networks_are_one_line_errors():
    net = entry_export("ars-open-loop", _knowledge())
    for change, name in [({"weights": net.weights[:-1]}, "weights must hold"),
                         ({"activations": ("softmax",)}, "activations must hold"),
                         ({"action_low": (0.1,) * 8}, "action_low must hold float32"),
                         ({"decision_hz": 0.0}, "decision_hz=0.0 must be > 0"),
                         ({"observation_names": ("a",)}, "observation_names must hold 36")]:
        with pytest.raises(ParameterError, match=name) as info:
            FirmwareNetwork(**{**net.__dict__, **change})
        assert "\n" not in str(info.value)
    with pytest.raises(ParameterError, match="not a stepdamp-firmware-network/1"):
        network_from_json({"format": "stepdamp-firmware-law/3"})
    # Only where it was trained: the mid-band agent on the voltage-mode drive.
    for entry, mode, text in [("ppo-mid-band", "open-loop", "trained for mid-band only"),
                              ("ars-servo", "open-loop", "runs in servo only"),
                              ("ppo-open-loop", "servo", "runs in open-loop only")]:
        with pytest.raises(ParameterError, match=text) as info:
            entry_export(entry, _knowledge(), mode=mode)
        assert "\n" not in str(info.value)
    voltage = firmware_knowledge(get_preset("patent").replace(drive_mode="voltage"))
    assert entry_export("ppo-mid-band", voltage).entry == "ppo-mid-band"


def test_the_cli_exports_a_learned_entry_and_refuses_a_schedule(tmp_path):
    cmd = [sys.executable, "-m", "stepdamp_env.cli", "export", "ppo-open-loop",
           "--motor", "patent", "--out", str(tmp_path)]
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    assert "network 36-64-64-8" in done.stdout and "6912 multiply-adds" in done.stdout
    assert os.path.isfile(tmp_path / "ppo_open_loop.c")
    done = subprocess.run(cmd + ["--speeds", "1:3:1"], capture_output=True, text=True,
                          timeout=300)
    assert done.returncode == 2 and "speed is one of its inputs" in done.stderr
    assert len(done.stderr.strip().splitlines()) == 1


def test_the_gain_selectors_network_is_the_one_it_runs(monkeypatch, tmp_path):
    """v0's ppo-gain-selector: the exported network, fed the inputs the policy gave
    its network in a simulated run (observation, velocity feature, the context
    constants, the RMS), gives its gains bit for bit, and so does the compiled C;
    the constants the export states are the ones the policy used."""
    import stepdamp_agents.policy as agent_policy

    from stepdamp_env.bench.network import predict_rows

    inputs, gains = [], []

    def recording(model, x):
        out = predict_rows(model, x)
        inputs.append(np.array(x, dtype=np.float32))
        gains.append(np.array(out, dtype=np.float32))
        return out

    monkeypatch.setattr(agent_policy, "predict_rows", recording)
    plant = get_preset("patent")
    from stepdamp_env.bench import MotorKnowledge
    from stepdamp_env.params import FeedforwardModel

    model = FeedforwardModel.from_motor(plant.motor)
    knowledge = MotorKnowledge(nominal=plant, identified=model, exact=model, plant=plant)
    speed = plant.predicted_resonances_rps()[4]
    policy = resolve_policy("ppo-gain-selector").make()
    result = run_episode(policy, knowledge, plant, mode="open-loop", speed_rps=speed, seed=3,
                         measure_from_s=0.0, window_s=0.6, until_s=0.6)
    assert not result.terminated and len(inputs) >= 5
    x, g = np.concatenate(inputs), np.concatenate(gains)
    net = entry_export("ppo-gain-selector", knowledge, speed_rps=speed)
    assert net.decision_hz == 10.0 and net.action_names == ("gain",)
    np.testing.assert_array_equal(network_actions(net, x), g)
    assert np.ptp(g) > 0.0
    for name, value in net.constant_inputs.items():           # the policy's own constants
        np.testing.assert_array_equal(x[:, net.observation_names.index(name)],
                                      np.float32(value))
    rows = np.concatenate([x, _far_observations(net)])
    got = _compiled(net, rows, tmp_path)
    np.testing.assert_array_equal(got["action"], network_actions(net, rows))
    np.testing.assert_array_equal(got["output"], network_outputs(net, rows))
