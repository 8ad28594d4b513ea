"""The cost of a training episode's reset: a motor drawn, validated and built into a drive.

Run: ``python benchmarks/bench_episode_reset.py [ROOT ...]``: for each ROOT (a
checkout of the repository; default this one), alternating, twice, a child
process times, in microseconds per call:

* ``replace``: ``SystemParams.replace`` on the patent preset with three motor
  fields changed (20,000 calls);
* ``reset``: a drive's new episode in ``stepdamp train``'s open-loop task
  (``agents.task.task_options`` at 25 Hz, motors drawn around the patent
  preset; ``TaskV1.new_episode``, 5,000 calls, the best of three rounds).

Each line ends with a hash of what was built (the systems; the drive's
configuration and state rows): equal hashes, the same bits.
"""

from __future__ import annotations

import os
import subprocess
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
CHILD = """
import hashlib, sys, time
sys.path.insert(0, sys.argv[1])
import numpy as np
from agents.task import task_options
from stepdamp_env.env import StepperDampV1VectorEnv
from stepdamp_env.env.engine import DriveBatch
from stepdamp_env.presets import get_preset
p = get_preset("patent")
xs = np.random.default_rng(0).uniform(0.8, 1.2, size=(20000, 3))
t0 = time.perf_counter()
out = [p.replace(J=p.motor.J * a, Km=p.motor.Km * b, R=p.motor.R * c) for a, b, c in xs]
dt = time.perf_counter() - t0
print(f"{sys.argv[1]}: replace {dt / len(xs) * 1e6:6.1f} us, systems "
      f"{hashlib.sha256(repr(out).encode()).hexdigest()[:12]}")
task = StepperDampV1VectorEnv(1, **task_options({"agent_hz": 25.0})).task
drives = DriveBatch(task, 1)
best, digest = float("inf"), hashlib.sha256()
for round_ in range(3):
    rng = np.random.default_rng(1)
    t0 = time.perf_counter()
    for _ in range(5000):
        task.new_episode(rng, drives, 0)
        if round_ == 0:
            digest.update(drives.c[0].tobytes() + drives.s[0].tobytes())
    best = min(best, (time.perf_counter() - t0) / 5000)
print(f"{sys.argv[1]}: reset   {best * 1e6:6.1f} us, drives  {digest.hexdigest()[:12]}")
"""


def main() -> None:
    roots = [os.path.abspath(r) for r in sys.argv[1:]] or [ROOT]
    for _ in range(2):
        for root in roots:
            subprocess.run([sys.executable, "-c", CHILD, root], check=True, cwd="/")


if __name__ == "__main__":
    main()
