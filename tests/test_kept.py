"""Kept preparations (``stepdamp_env.bench.kept``): what ``plant-bound``'s
rehearsals and ``calibrated-table``'s calibration find is read back from disk
bit for bit, never reused by other code or another input, and computed again
when its file is damaged."""

import dataclasses
import json
import math
import os

import numpy as np
import pytest

from stepdamp_baselines import learning
from stepdamp_baselines import plant_bound as pb
from stepdamp_baselines.learning import CalibratedTable
from stepdamp_env.bench.kept import KeptResults, key_text
from stepdamp_env.bench.policy import (MotorKnowledge, PolicyContext, policy_context,
                                       policy_env_options)
from stepdamp_env.bench.rig import CalibrationRig
from stepdamp_env.params import FeedforwardModel
from stepdamp_env.presets import get_preset


@pytest.fixture
def cache(tmp_path, monkeypatch):
    monkeypatch.setenv("STEPDAMP_CACHE_DIR", str(tmp_path))
    return tmp_path


def _forbidden(what):
    """A stand-in that fails the test if called."""
    def call(*args, **kwargs):
        raise AssertionError(what)
    return call


def _files(root, kind):
    return sorted((root / kind).glob("*.json"))


def test_a_key_is_exact_and_names_what_it_cannot_hold(cache):
    x = 0.1 + 0.2
    assert json.loads(key_text([x]))[0] == x
    kept = KeptResults("k")
    kept.put(("a", 1.5, None), {"v": [x, math.pi]})
    assert kept.get(("a", 1.5, None)) == {"v": [x, math.pi]}
    assert kept.get(("a", 1.5000000000000002, None)) is None
    with pytest.raises(TypeError, match="cannot hold object"):
        key_text([object()])


def test_the_cache_off_keeps_nothing(monkeypatch):
    monkeypatch.setenv("STEPDAMP_CACHE_DIR", "off")
    kept = KeptResults("k")
    kept.put("a", 1)
    assert kept.get("a") is None


def test_a_kept_result_belongs_to_its_code_root(cache, tmp_path_factory):
    root = tmp_path_factory.mktemp("code")
    (root / "law.py").write_text("A = 1\n")
    KeptResults("k", code_root=str(root)).put("a", 1)
    assert KeptResults("k", code_root=str(root)).get("a") == 1
    (root / "law.py").write_text("A = 2\n")
    assert KeptResults("k", code_root=str(root)).get("a") is None


def _bound_case():
    system = get_preset("qsh4218-51-10-049")
    know = MotorKnowledge(nominal=system, identified=None,
                          exact=FeedforwardModel.from_motor(system.motor), plant=system)
    bound = pb.PlantBound(portfolio=(("zeta", 0.5), ("kv", 0.5)), table_steps=1)
    speed = min(system.predicted_resonances_rps().values())
    ctx = policy_context(policy_env_options(bound, know), know, "open-loop", speed, window_s=0.05)
    return bound, ctx


def test_plant_bound_reads_its_choice_back_without_rehearsing(cache, monkeypatch):
    bound, ctx = _bound_case()
    pb._CHOICES.clear()
    first = (bound.choice(ctx), bound.table(ctx))
    assert len(_files(cache, "plant-bound")) == 1
    pb._CHOICES.clear()
    with monkeypatch.context() as m:
        m.setattr(pb, "_rehearse", _forbidden("rehearsed although the choice was kept"))
        assert (bound.choice(ctx), bound.table(ctx)) == first
    # A damaged entry is rehearsed again, to the same choice.
    path = _files(cache, "plant-bound")[0]
    path.write_text(path.read_text().replace('"law"', '"lav"'))
    pb._CHOICES.clear()
    assert (bound.choice(ctx), bound.table(ctx)) == first
    pb._CHOICES.clear()


def test_calibrated_table_reads_its_table_back_bit_for_bit(cache, monkeypatch):
    system = get_preset("patent")
    exact = FeedforwardModel.from_motor(system.motor)
    rig = CalibrationRig(system, noise_seed=3, accel_rps2=50.0)
    ctx = PolicyContext(knowledge=MotorKnowledge(system, exact, exact, plant=system, rig=rig),
                        estimate=exact, mode="open-loop", speed_rps=1.0, action_mode="harmonic",
                        action_scale=0.05, agent_hz=1000.0, current_scale_a=1.0,
                        accel_rps2=50.0)
    learning._TABLES.clear()
    table = CalibratedTable(iterations=3)
    table.configure(ctx)
    first, seconds = table._action.copy(), table.calibration_s
    assert len(_files(cache, "calibrated-table")) == 1
    learning._TABLES.clear()
    with monkeypatch.context() as m:
        m.setattr(CalibrationRig, "harmonic_ripple",
                  _forbidden("calibrated although the table was kept"))
        again = CalibratedTable(iterations=3)
        again.configure(ctx)
    np.testing.assert_array_equal(again._action, first)
    assert again.calibration_s == seconds
    # Other search settings are another calibration.
    learning._TABLES.clear()
    CalibratedTable(iterations=2).configure(ctx)
    assert len(_files(cache, "calibrated-table")) == 2
    # So is another nominal motor (it picks the speeds), in this process too.
    heavier = system.replace(J=2.0 * system.motor.J)
    other = dataclasses.replace(ctx, knowledge=dataclasses.replace(ctx.knowledge, nominal=heavier))
    CalibratedTable(iterations=3).configure(ctx)
    CalibratedTable(iterations=3).configure(other)
    assert len(_files(cache, "calibrated-table")) == 3
    learning._TABLES.clear()
    assert os.path.isdir(cache / "calibrated-table")


def test_calibrated_table_reads_the_code_once_per_batch(cache, monkeypatch):
    """A KeptResults hashes the sources when made: one per batch (a preparation),
    not one per calibration; outside a batch, one per configure."""
    system = get_preset("patent")
    exact = FeedforwardModel.from_motor(system.motor)
    contexts = [PolicyContext(
        knowledge=MotorKnowledge(system, exact, exact, plant=system,
                                 rig=CalibrationRig(system, noise_seed=seed, accel_rps2=50.0)),
        estimate=exact, mode="open-loop", speed_rps=1.0, action_mode="harmonic",
        action_scale=0.05, agent_hz=1000.0, current_scale_a=1.0, accel_rps2=50.0)
        for seed in (3, 4, 5)]
    made = []
    real_init = KeptResults.__init__

    def counted(self, kind, *args, **kwargs):
        if kind == "calibrated-table":
            made.append(kind)
        real_init(self, kind, *args, **kwargs)

    monkeypatch.setattr(KeptResults, "__init__", counted)
    learning._TABLES.clear()
    table = CalibratedTable(iterations=2)
    table.reset_batch(contexts)
    assert len(made) == 1 and len(_files(cache, "calibrated-table")) == 3
    learning._TABLES.clear()
    table.reset_batch(contexts)                 # read back: one more reading of the code
    assert len(made) == 2
    learning._TABLES.clear()
    table.configure(contexts[0])
    assert len(made) == 3
    # A batch that fails (a run without a rig) leaves no batch's KeptResults behind.
    no_rig = dataclasses.replace(contexts[1], knowledge=dataclasses.replace(
        contexts[1].knowledge, rig=None))
    learning._TABLES.clear()
    with pytest.raises(ValueError, match="rig"):
        table.reset_batch([contexts[0], no_rig])
    assert len(made) == 4
    learning._TABLES.clear()
    table.configure(contexts[0])
    assert len(made) == 5
    learning._TABLES.clear()
