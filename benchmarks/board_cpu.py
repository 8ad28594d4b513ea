"""Where a board's CPU time is spent: the parent process or its workers.

Run: ``python benchmarks/board_cpu.py leaderboard --out DIR --no-plots --workers 2
--no-progress`` (any ``stepdamp`` command line). It runs the command in this
process, then prints its wall time and the CPU time (user + system,
``resource.getrusage``) of this process and of its children (the pool's
workers and the scoring's forks, counted once they have ended). On 2 cores
with 2 workers, the parent's CPU time is taken from the runs.
"""

from __future__ import annotations

import resource
import sys
import time


def main() -> int:
    t0 = time.perf_counter()
    from stepdamp_env.cli import main as cli

    try:
        return cli(sys.argv[1:])
    finally:
        own = resource.getrusage(resource.RUSAGE_SELF)
        children = resource.getrusage(resource.RUSAGE_CHILDREN)
        print(f"wall {time.perf_counter() - t0:.1f} s, parent CPU "
              f"{own.ru_utime + own.ru_stime:.1f} s, workers' CPU "
              f"{children.ru_utime + children.ru_stime:.1f} s", file=sys.stderr)


if __name__ == "__main__":
    sys.exit(main())
