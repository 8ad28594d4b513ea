"""v0 is frozen: StepperDamp-v0 rollouts and stepdamp-bench v0 numbers stay bit-identical.

The stored fingerprints (``tests/data/v0_*.json``) were taken before the code
moved into ``stepdamp_env/env`` and ``stepdamp_env/bench``. CI checks the
rollouts, the whole quick leaderboard and, of the full protocol, every run of
two motors (a drawn one and a preset) at one evaluation seed, with their
identified models. The whole full protocol is checked by
``python tests/v0_fingerprints.py --full --check`` (about 3 minutes on 2 cores).
"""

from __future__ import annotations

import json

import pytest

import v0_fingerprints as F
from stepdamp_env.bench import (MotorKnowledge, full_protocol, protocol_motors, resolve_policy,
                                run_episode)
from stepdamp_env.identify import identify
from stepdamp_env.parallel import pool_map
from stepdamp_env.params import FeedforwardModel


def _stored(path):
    with open(path, encoding="utf-8") as fh:
        return json.load(fh)


def _same(a, b):
    return json.dumps(a, sort_keys=True) == json.dumps(b, sort_keys=True)


def test_v0_rollouts_are_bit_identical():
    stored = _stored(F.ROLLOUTS_FILE)
    now = json.loads(json.dumps(F.rollout_fingerprints()))
    for group in stored:
        assert _same(now[group], stored[group]), group


def test_v0_quick_leaderboard_is_bit_identical():
    stored = _stored(F.QUICK_FILE)
    now = json.loads(json.dumps(F.board_fingerprint(F.run_v0_board("quick", workers=2))))
    assert sorted(now["entries"]) == sorted(stored["entries"])
    for key, entry in stored["entries"].items():
        assert _same(now["entries"][key], entry), key
    assert now["identification_sha256"] == stored["identification_sha256"]
    assert now["motors_sha256"] == stored["motors_sha256"]


_SPOT: dict = {}


# Stored entry name -> the name it is registered under now.
_CURRENT_NAME = {old: new for new, old in F.RENAMED.items()}


def _spot_run(job):
    spec, suite, motor_name, speed_index = job
    motor = _SPOT["motors"][motor_name]
    p = _SPOT["protocol"]
    speed = motor.speeds_rps[speed_index]
    result = run_episode(resolve_policy(_CURRENT_NAME.get(spec, spec)).make(), _SPOT["knowledge"][motor_name],
                         motor.system, mode=suite, speed_rps=speed, seed=F.FULL_SPOT_SEED,
                         accel_rps2=p.accel_rps2, window_s=p.window_s)
    record = result.record(motor.name, F.FULL_SPOT_SEED, speed, motor.speed_labels[speed_index])
    if record["metrics"] is not None:       # the metrics v0 records (as its boards do)
        record["metrics"] = {k: record["metrics"][k] for k in p.run_metrics}
    return record


@pytest.mark.slow
@pytest.mark.filterwarnings("ignore::DeprecationWarning")
def test_v0_full_protocol_spot_runs_are_bit_identical():
    stored = _stored(F.FULL_FILE)
    protocol = full_protocol()
    motors = {m.name: m for m in protocol_motors(protocol)}
    assert F.digest([m.to_dict() for m in motors.values()]) == stored["motors_sha256"]
    models = {name: identify(motors[name].system, method=protocol.identification_method,
                             noise_seed=F.FULL_SPOT_SEED).model for name in F.FULL_SPOT_MOTORS}
    ident = [{"motor": n, "seed": F.FULL_SPOT_SEED, "model": models[n].__dict__}
             for n in sorted(models)]
    assert _same(ident, stored["spot_identification"])
    _SPOT.update(protocol=protocol, motors=motors, knowledge={
        n: MotorKnowledge(nominal=motors[n].nominal, identified=models[n],
                          exact=FeedforwardModel.from_motor(motors[n].system.motor))
        for n in F.FULL_SPOT_MOTORS})
    keys = sorted(stored["entries"])
    specs = {k.split("|")[0] for k in keys}
    jobs = [(spec, suite, name, j) for spec in sorted(specs) for suite in protocol.suites
            for name in F.FULL_SPOT_MOTORS for j in range(len(motors[name].speeds_rps))]
    runs = pool_map(_spot_run, jobs, 2)
    for key in keys:
        spec, suite = key.split("|")
        mine = F.canonical_runs(r for (s, su, _, _), r in zip(jobs, runs)
                                if s == spec and su == suite)
        assert _same(mine, stored["entries"][key]["spot_runs"]), key
