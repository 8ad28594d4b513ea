"""Fingerprints of StepperDamp-v0 and of the stepdamp-bench v0 leaderboard.

v0 is frozen: its rollouts and leaderboard numbers must stay bit-identical.
The stored values (``tests/data/v0_*.json``) were taken before the code moved;
``tests/test_v0_frozen.py`` recomputes them. To store them again (only when a
change is meant to alter v0, which makes it v1):

    python tests/v0_fingerprints.py --rollouts --quick --full

Hashes are SHA-256 over the raw bytes of every observation, reward, flag and
info value, or over canonical JSON (``repr`` floats round-trip exactly).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import sys
from typing import Any, Iterable

import numpy as np

DATA_DIR = os.path.join(os.path.dirname(os.path.abspath(__file__)), "data")
ROLLOUTS_FILE = os.path.join(DATA_DIR, "v0_rollouts.json")
QUICK_FILE = os.path.join(DATA_DIR, "v0_leaderboard_quick.json")
FULL_FILE = os.path.join(DATA_DIR, "v0_leaderboard_full.json")

# Env options of the fingerprinted rollouts: every mode, action mode, base
# controller, estimator and the randomiser.
ROLLOUT_CONFIGS: dict[str, dict[str, Any]] = {
    "default": {},
    "servo": {"mode": "servo"},
    "current": {"action_mode": "current"},
    "servo-current-none": {"action_mode": "current", "mode": "servo", "base_controller": "none"},
    "both-random-qsh4218": {"action_mode": "harmonic+current", "randomize": True,
                            "motor": "qsh4218-51-10-049"},
    "privileged-kalman-nominal-random": {"privileged": True, "velocity_estimator": "kalman",
                                         "estimate": "nominal", "randomize": True,
                                         "mode": "servo"},
    "qsh6018-4khz-noise": {"motor": "qsh6018-65-28-210", "agent_hz": 4000.0,
                           "overrides": {"current_noise_a": 0.01}},
}
# Full-protocol runs stored one by one (a drawn motor and a preset, one seed).
FULL_SPOT_MOTORS = ("qsh5718-56-28-126~r1", "patent")
FULL_SPOT_SEED = 1_000_002
V0_POLICIES = ("patent-ff-oracle", "patent-ff-identified", "ff-delay-comp", "adaptive-ff",
               "ppo-gain-selector")
# Entries renamed since the fingerprints were stored (new name -> stored name).
RENAMED = {"ppo-gain-selector": "ppo-residual"}


class _Hash:
    def __init__(self) -> None:
        self._h = hashlib.sha256()

    def add(self, *values: Any) -> None:
        for v in values:
            if isinstance(v, dict):
                for k in sorted(v):
                    if not str(k).startswith("_"):
                        self._h.update(str(k).encode())
                        self.add(v[k])
            elif isinstance(v, np.ndarray) and v.dtype == object:
                self.add(*[x if x is not None else "None" for x in v.tolist()])
            elif isinstance(v, (np.ndarray, np.generic)):
                self._h.update(np.ascontiguousarray(v).tobytes())
            elif isinstance(v, (bool, int, float)):
                self._h.update(np.float64(v).tobytes())
            else:
                self._h.update(repr(v).encode())

    def hexdigest(self) -> str:
        return self._h.hexdigest()


def _actions(rng: np.random.Generator, shape: tuple[int, ...]) -> np.ndarray:
    return (0.3 * rng.uniform(-1.0, 1.0, size=shape)).astype(np.float32)


def scalar_rollout(options: dict[str, Any], seed: int = 11, steps: int = 120) -> str:
    """Hash of two seeded episodes of the scalar env (through ``gym.make``)."""
    import gymnasium as gym

    import stepdamp_env  # noqa: F401  (registers the env)

    env = gym.make("StepperDamp-v0", **options)
    h = _Hash()
    rng = np.random.default_rng(seed)
    for episode in range(2):
        obs, info = env.reset(seed=seed + episode)
        h.add(obs, info)
        for _ in range(steps):
            obs, reward, term, trunc, info = env.step(_actions(rng, env.action_space.shape))
            h.add(obs, reward, term, trunc, info)
            if term or trunc:
                break
    env.close()
    return h.hexdigest()


def vector_rollout(options: dict[str, Any], seed: int = 21, steps: int = 90,
                   autoreset_mode: str = "NextStep") -> str:
    """Hash of the native vector env through autoresets (episodes of 40 steps)."""
    from stepdamp_env.env import StepperDampVectorEnv

    venv = StepperDampVectorEnv(num_envs=4, max_episode_steps=40, autoreset_mode=autoreset_mode,
                                **options)
    h = _Hash()
    rng = np.random.default_rng(seed)
    obs, info = venv.reset(seed=seed)
    h.add(obs, info)
    for _ in range(steps):
        out = venv.step(_actions(rng, venv.action_space.shape))
        h.add(*out)
    venv.close()
    return h.hexdigest()


def measured_rollout(seed: int = 5) -> dict[str, Any]:
    """Core metrics of a measured scalar episode (the leaderboard's way of running)."""
    from stepdamp_env.env import StepperDampEnv

    env = StepperDampEnv(motor="qsh5718-56-28-126", speed_rps=1.0, measure_from_s=0.2,
                         overrides={"current_noise_a": 0.01})
    env.reset(seed=seed)
    zero = np.zeros(env.action_space.shape, dtype=np.float32)
    while env.time_s < 0.35:
        env.step(zero)
    from stepdamp_env.metrics import METRICS_V0_V3

    return env.run_metrics().to_dict(METRICS_V0_V3)


def simulate_fingerprints() -> dict[str, str]:
    from stepdamp_env import get_preset, simulate
    from stepdamp_env.metrics import METRICS_V0_V3
    from stepdamp_env.simulation import RunSettings, SpeedProfile

    out = {}
    system = get_preset("patent")
    for name, settings, speed in (
            ("open-loop-ff-h4", RunSettings(damping="patent-ff"),
             system.predicted_resonances_rps()[4]),
            ("servo-kalman-none", RunSettings(mode="servo", velocity_estimator="kalman",
                                              noise_seed=3), 0.5)):
        res = simulate(system.replace(current_noise_a=0.01),
                       profile=SpeedProfile(speed_rps=speed), settings=settings, trace=True)
        h = _Hash()
        h.add(res.metrics.to_dict(METRICS_V0_V3), *[res.trace[k] for k in sorted(res.trace)])
        out[name] = h.hexdigest()
    return out


def rollout_fingerprints() -> dict[str, Any]:
    out: dict[str, Any] = {"scalar": {}, "vector": {}}
    for name, options in ROLLOUT_CONFIGS.items():
        out["scalar"][name] = scalar_rollout(options)
        out["vector"][name] = vector_rollout(options)
    out["vector_same_step"] = vector_rollout({"randomize": True}, autoreset_mode="SameStep")
    out["measured"] = measured_rollout()
    out["simulate"] = simulate_fingerprints()
    return out


# ---------------------------------------------------------------------------
# Leaderboard
# ---------------------------------------------------------------------------
RUN_KEYS = ("motor", "seed", "speed_rps", "speed_label", "terminated", "termination",
            "failed", "steps", "window_start_s", "window_s", "metrics")
SUMMARY_KEYS = ("headline", "sweep_mean_ratio", "sweep_worst_ratio", "rms_injected_current_a",
                "step_losses", "per_motor_headline_mean", "oracle")


def canonical_runs(runs: Iterable[dict[str, Any]]) -> list[dict[str, Any]]:
    rows = [{k: r[k] for k in RUN_KEYS} for r in runs]
    return sorted(rows, key=lambda r: (r["motor"], r["seed"], r["speed_rps"]))


def digest(obj: Any) -> str:
    return hashlib.sha256(json.dumps(obj, sort_keys=True).encode()).hexdigest()


def board_fingerprint(board: dict[str, Any], spot_motors: Iterable[str] = (),
                      spot_seed: int | None = None) -> dict[str, Any]:
    """Per entry: every summary number, the digest of all its runs and its scores;
    the identified models' digest; optionally some runs in full."""
    entries = {}
    spot = set(spot_motors)
    for e in board["entries"]:
        runs = canonical_runs(e["runs"])
        item = {k: e[k] for k in SUMMARY_KEYS}
        item["runs_sha256"] = digest(runs)
        item["scores_sha256"] = digest(sorted(e["scores"], key=lambda s: (s["motor"],
                                                                           s["seed"])))
        if spot:
            item["spot_runs"] = [r for r in runs if r["motor"] in spot and r["seed"] == spot_seed]
        entries[f"{RENAMED.get(e['name'], e['name'])}|{e['suite']}"] = item
    ident = sorted(board["identification"], key=lambda x: (x["motor"], x["seed"]))
    out = {"entries": entries, "identification_sha256": digest(ident),
           "motors_sha256": digest([m for m in board["protocol"]["motors"]])}
    if spot:
        out["spot_identification"] = [x for x in ident if x["motor"] in spot
                                      and x["seed"] == spot_seed]
    return out


def run_v0_board(variant: str, workers: int | None = None) -> dict[str, Any]:
    from stepdamp_env.bench import full_protocol, quick_protocol, run_leaderboard

    protocol = quick_protocol() if variant == "quick" else full_protocol()
    # v0's default board, named: an installed plugin must not change it.
    return run_leaderboard(protocol, V0_POLICIES, workers=workers, progress=False)


def _same(a: Any, b: Any) -> bool:
    """Equal as canonical JSON (NaN equals NaN there)."""
    return json.dumps(a, sort_keys=True) == json.dumps(b, sort_keys=True)


def _write(path: str, data: Any) -> None:
    os.makedirs(os.path.dirname(path), exist_ok=True)
    with open(path, "w", encoding="utf-8") as fh:
        json.dump(data, fh, indent=1, sort_keys=True)
        fh.write("\n")


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--rollouts", action="store_true")
    p.add_argument("--quick", action="store_true")
    p.add_argument("--full", action="store_true")
    p.add_argument("--check", action="store_true",
                   help="compare with the stored values instead of writing them")
    a = p.parse_args(argv)
    status = 0
    jobs = []
    if a.rollouts:
        jobs.append((ROLLOUTS_FILE, rollout_fingerprints))
    if a.quick:
        jobs.append((QUICK_FILE, lambda: board_fingerprint(run_v0_board("quick"))))
    if a.full:
        jobs.append((FULL_FILE, lambda: board_fingerprint(run_v0_board("full"),
                                                          FULL_SPOT_MOTORS, FULL_SPOT_SEED)))
    for path, make in jobs:
        data = json.loads(json.dumps(make()))
        if a.check:
            with open(path, encoding="utf-8") as fh:
                same = _same(json.load(fh), data)
            print(f"{os.path.basename(path)}: {'identical' if same else 'DIFFERENT'}")
            status |= 0 if same else 1
        else:
            _write(path, data)
            print(f"wrote {path}")
    return status


if __name__ == "__main__":
    sys.path.insert(0, os.path.dirname(DATA_DIR))
    sys.exit(main())
