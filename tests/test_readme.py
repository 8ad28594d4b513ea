"""The README states what the code does: its environment tables name the real
entries, and its result table is what `stepdamp report` prints for the committed
main-job results (never copied by hand)."""

from __future__ import annotations

import os
import re

import pytest

from stepdamp_env.bench.report import load_leaderboard, render_ladder
from stepdamp_env.env import ACTION_NAMES, observation_names

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
README = open(os.path.join(ROOT, "README.md"), encoding="utf-8").read()
ENVS = open(os.path.join(ROOT, "docs", "envs.md"), encoding="utf-8").read()
V0_ENV = ENVS[ENVS.index("## The environment: `StepperDamp-v0`"):]
RESULTS_PAGE = open(os.path.join(ROOT, "docs", "results.md"), encoding="utf-8").read()
AGENTS = open(os.path.join(ROOT, "docs", "agents.md"), encoding="utf-8").read()
RESULTS = os.path.join(ROOT, "docs", "results")


def test_observation_table_names_every_entry_in_order():
    section = V0_ENV[V0_ENV.index("**Observations**"):V0_ENV.index("**Actions**")]
    named = re.findall(r"`([a-z_0-9*]+)`", section)
    expected = [n for n in observation_names(privileged=True)
                if not n.startswith("last_action_")]
    listed = [n for n in named if n in expected]
    assert listed == expected
    assert "last_action_*" in named


def test_action_table_lists_every_mode():
    section = V0_ENV[V0_ENV.index("**Actions**"):V0_ENV.index("**Reward**")]
    for mode, names in ACTION_NAMES.items():
        assert f"| `{mode}`" in section and f"| {len(names)} |" in section


@pytest.mark.slow
def test_results_tables_are_generated_from_the_committed_leaderboards():
    import subprocess
    import sys

    v5 = load_leaderboard(os.path.join(RESULTS, "v5"), runs=False)
    assert render_ladder(v5).strip() in RESULTS_PAGE
    assert v5["protocol"]["variant"] == "full" and v5["protocol"]["version"] == "v5"
    v4 = load_leaderboard(os.path.join(RESULTS, "v4"), runs=False)
    assert render_ladder(v4).strip() in RESULTS_PAGE
    assert v4["protocol"]["variant"] == "full" and v4["protocol"]["version"] == "v4"
    v3 = load_leaderboard(os.path.join(RESULTS, "v3"))
    assert render_ladder(v3).strip() in RESULTS_PAGE
    assert v3["protocol"]["variant"] == "full" and v3["protocol"]["version"] == "v3"
    board = load_leaderboard(RESULTS)
    assert render_ladder(board).strip() in RESULTS_PAGE
    assert board["protocol"]["variant"] == "full" and board["protocol"]["version"] == "v1"
    v0 = load_leaderboard(os.path.join(RESULTS, "v0"))
    assert render_ladder(v0).strip() in RESULTS_PAGE
    assert v0["protocol"]["variant"] == "full" and v0["protocol"]["version"] == "v0"
    check = subprocess.run([sys.executable, os.path.join(ROOT, "scripts", "readme_table.py"),
                            "--check"], capture_output=True, text=True)
    assert check.returncode == 0, check.stderr


def test_readme_is_a_front_page_and_every_link_resolves():
    import re

    assert len(README.splitlines()) <= 250
    first = README[README.index("```python"):]
    first = first[:first.index("```", 3)]
    assert "gym.make(\"StepperDamp-v3\"" in first and "StepperDamp-v0" not in first
    pages = [os.path.join(ROOT, "README.md")] + [
        os.path.join(ROOT, "docs", n) for n in os.listdir(os.path.join(ROOT, "docs"))
        if n.endswith(".md")]
    for page in pages:
        text = open(page, encoding="utf-8").read()
        for target in re.findall(r"\]\(([^)\s]+)\)", text):
            if target.startswith(("http://", "https://", "#")):
                continue
            path = os.path.normpath(os.path.join(os.path.dirname(page), target.split("#")[0]))
            assert os.path.exists(path), f"{page}: {target}"


def test_overview_figure_is_the_committed_one():
    assert "](docs/figures/overview.png)" in README
    with open(os.path.join(ROOT, "docs", "figures", "overview.png"), "rb") as fh:
        assert fh.read(8) == b"\x89PNG\r\n\x1a\n"


def test_per_speed_figures_in_the_readme_come_from_the_committed_board():
    import subprocess
    import sys

    out = subprocess.run([sys.executable, os.path.join(ROOT, "scripts", "per_speed.py"), RESULTS],
                         capture_output=True, text=True, check=True).stdout
    # ars-per-step's medians as the README quotes them (h1, h2, h4, off), both splits.
    assert "| ars-per-step | 0.77; 0.76 | 0.35; 0.95 | 0.64; 0.90 | 0.87; 0.60 |" in out
    assert "| ars-per-step | 0.96; 0.56 | 0.45; 0.82 | 0.56; 0.68 | 1.56; 0.24 |" in out
    assert "(ARS 0.35\nand 0.64 inside the training range, 0.45 and 0.56 outside)" in AGENTS


def test_a_published_board_without_its_runs_file_says_how_to_get_it(tmp_path, capsys):
    """v4's published board keeps its scores only: `report` says in one line how
    to write the runs file again, and `--no-verify` shows the scores."""
    import shutil

    from stepdamp_env.cli import main

    v4 = str(tmp_path / "v4")        # the committed files (a run may write its runs file back)
    os.makedirs(v4)
    shutil.copy(os.path.join(RESULTS, "v4", "leaderboard.json"), v4)
    assert main(["report", v4]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "leaderboard_runs.json.xz" in err
    assert "--protocol v4" in err and "--no-verify" in err
    assert main(["report", v4, "--no-verify"]) == 0
    assert "plant-bound" in capsys.readouterr().out
    assert main(["report", v4, "--check", "--no-verify"]) == 2      # --check needs the runs
    assert "runs file" in capsys.readouterr().err
