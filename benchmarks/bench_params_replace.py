"""The cost of ``SystemParams.replace``, which training calls once per episode to draw a motor.

Run: ``python benchmarks/bench_params_replace.py [ROOT ...]``: for each ROOT (a
checkout of the repository; default this one), alternating, twice, a child
process times 20,000 calls on the patent preset with three motor fields changed
and prints microseconds per call and a hash of the first systems (equal hashes:
the same systems).
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
from stepdamp_env.presets import get_preset
p = get_preset("patent")
xs = np.random.default_rng(0).uniform(0.8, 1.2, size=(20000, 3))
t0 = time.perf_counter()
out = [p.replace(J=p.motor.J * a, Km=p.motor.Km * b, R=p.motor.R * c) for a, b, c in xs]
dt = time.perf_counter() - t0
print(f"{sys.argv[1]}: {dt / len(xs) * 1e6:.1f} us per replace, systems "
      f"{hashlib.sha256(repr(out).encode()).hexdigest()[:12]}")
"""


def main() -> None:
    roots = [os.path.abspath(r) for r in sys.argv[1:]] or [ROOT]
    for _ in range(2):
        for root in roots:
            subprocess.run([sys.executable, "-c", CHILD, root], check=True, cwd="/")


if __name__ == "__main__":
    main()
