"""The Ray backend gives the local backend's numbers (a local Ray: 2 CPUs, loopback only).

Skipped without Ray (extra ``[ray]``); CI installs it and runs this file.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

ray = pytest.importorskip("ray")
# One worker runs every Ray test (one local Ray at a time) under --dist loadgroup.
pytestmark = pytest.mark.xdist_group("ray")

from stepdamp_env.bench import protocol_motors, quick_protocol_v1, run_leaderboard  # noqa: E402
from stepdamp_env.motorfile import load_system  # noqa: E402
from stepdamp_env.ray_backend import ray_map  # noqa: E402
from stepdamp_env.simulation import RunSettings  # noqa: E402
from stepdamp_env.sweep import run_sweep  # noqa: E402


@pytest.fixture(scope="module")
def local_ray():
    ray.init(num_cpus=2, _node_ip_address="127.0.0.1", include_dashboard=False,
             object_store_memory=100 * 1024 ** 2, log_to_driver=False)
    yield ray_map(None)
    ray.shutdown()


def test_ray_leaderboard_equals_local(local_ray):
    protocol = quick_protocol_v1()
    motors = protocol_motors(protocol)
    protocol = protocol.with_custom_motors([motors[0].system])
    policies = ["ff-delay-comp", "velocity-feedback", "adaptive-ff", "ars-per-step"]
    local = run_leaderboard(protocol, policies, workers=2, progress=False)
    remote = run_leaderboard(protocol, policies, workers=2, progress=False, backend=local_ray)
    for key in ("protocol", "entries", "identification"):
        assert json.dumps(remote[key], sort_keys=True) == json.dumps(local[key], sort_keys=True)


def test_ray_sweep_equals_local(local_ray):
    system = load_system("patent")
    speeds = np.linspace(0.3, 0.9, 6)
    local = run_sweep(system, speeds, RunSettings(base_controller="patent-ff"), workers=2,
                      progress=False)
    remote = run_sweep(system, speeds, RunSettings(base_controller="patent-ff"), workers=2,
                       progress=False, backend=local_ray)
    assert json.dumps(remote.to_dict(), sort_keys=True) == \
        json.dumps(local.to_dict(), sort_keys=True)


def test_ray_multi_seed_training_equals_local(local_ray, tmp_path):
    """`stepdamp train --seeds 1-2 --backend ray`: the same models as one after the other."""
    import dataclasses as dc

    import torch

    from stepdamp_agents.policy import load_model
    from stepdamp_agents.train import Args, train_seeds

    base = Args(algo="ppo", seeds=(1, 2), total_timesteps=3200, eval_freq=0,
                checkpoint_freq=0, progress=False, tensorboard=False)
    train_seeds(dc.replace(base, out=str(tmp_path / "local")))
    train_seeds(dc.replace(base, out=str(tmp_path / "ray"), backend="ray"))
    for k in (1, 2):
        a = load_model(str(tmp_path / "local" / f"seed{k}" / "final.zip")).policy.state_dict()
        b = load_model(str(tmp_path / "ray" / f"seed{k}" / "final.zip")).policy.state_dict()
        assert a.keys() == b.keys()
        assert all(torch.equal(a[key], b[key]) for key in a)


def test_ray_runs_a_policy_file_and_reports_its_errors_in_one_line(local_ray, tmp_path):
    """A policy given by file path travels to the workers by value; an error in a
    worker comes back as the job's own exception, not Ray's remote traceback."""
    import os

    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    spec = os.path.join(root, "tests", "leaderboard_policy.py") + ":NominalFeedforward"
    protocol = quick_protocol_v1()
    protocol = protocol.with_custom_motors([protocol_motors(protocol)[0].system])
    local = run_leaderboard(protocol, [spec], workers=2, progress=False)
    remote = run_leaderboard(protocol, [spec], workers=2, progress=False, backend=local_ray)
    assert json.dumps(remote["entries"], sort_keys=True) == \
        json.dumps(local["entries"], sort_keys=True)

    bad = tmp_path / "bad_policy.py"
    bad.write_text(open(spec.rpartition(":")[0]).read() + '''

class Broken(NominalFeedforward):
    def act(self, observation):
        raise ArithmeticError("broken on purpose")
''')
    with pytest.raises(ArithmeticError, match="broken on purpose"):
        run_leaderboard(protocol, [f"{bad}:Broken"], workers=2, progress=False,
                        backend=local_ray)


def test_an_address_where_no_ray_answers_is_a_one_line_error(tmp_path, capsys):
    from stepdamp_env.cli import main

    args = ["sweep", "--speeds", "0.5:0.5:0.1", "--no-progress", "--out", str(tmp_path / "s"),
            "--backend", "ray", "--ray-address", "127.0.0.1:1"]
    assert main(args) == 2
    err = capsys.readouterr().err.strip()
    assert "--ray-address '127.0.0.1:1'" in err and len(err.splitlines()) == 1
