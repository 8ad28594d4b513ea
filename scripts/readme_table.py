"""Write the result tables of README.md and docs/results.md from the committed
boards (``docs/results/v3``: v3, the default; ``docs/results``: v1;
``docs/results/v0``: v0), between their markers ``<!-- results:begin -->`` /
``<!-- results:end -->`` (and ``results-v3:``, ``results-v0:``).
Never typed by hand: ``tests/test_readme.py`` checks them with ``--check``.

    python scripts/readme_table.py [--check]
"""

from __future__ import annotations

import argparse
import os
import re
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
# file -> (marker name, board directory) pairs
TARGETS = {
    "README.md": (("results", "docs/results/v3"),),
    "docs/results.md": (("results-v3", "docs/results/v3"), ("results", "docs/results"),
                        ("results-v0", "docs/results/v0")),
}


def rendered(board_dir: str) -> str:
    from stepdamp_env.bench.report import load_leaderboard, render_ladder

    return render_ladder(load_leaderboard(os.path.join(ROOT, board_dir))).strip()


def updated(text: str, marker: str, table: str) -> str:
    """``text`` with the block between the marker pair replaced by ``table``."""
    pattern = re.compile(rf"(<!-- {re.escape(marker)}:begin -->\n).*?(<!-- {re.escape(marker)}:end -->)",
                         re.S)
    if not pattern.search(text):
        raise SystemExit(f"readme_table: no <!-- {marker}:begin/end --> pair")
    return pattern.sub(lambda m: m.group(1) + "\n" + table + "\n\n" + m.group(2), text)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--check", action="store_true", help="exit 1 if a file is stale")
    args = p.parse_args(argv)
    stale = []
    for name, pairs in TARGETS.items():
        path = os.path.join(ROOT, name)
        with open(path, encoding="utf-8") as fh:
            text = fh.read()
        new = text
        for marker, board in pairs:
            new = updated(new, marker, rendered(board))
        if new != text:
            stale.append(name)
            if not args.check:
                tmp = path + ".tmp"
                with open(tmp, "w", encoding="utf-8") as fh:
                    fh.write(new)
                os.replace(tmp, path)
    if args.check and stale:
        print(f"stale: {', '.join(stale)} (run python scripts/readme_table.py)", file=sys.stderr)
        return 1
    print(("stale: " if args.check else "wrote: ") + (", ".join(stale) or "nothing"))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
