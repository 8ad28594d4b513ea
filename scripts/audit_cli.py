"""Audit of the ``stepdamp`` command line against user mistakes.

Feeds ``stepdamp_env.cli.main`` a fixed list of user mistakes, about 280 of
them, covering every subcommand (``sweep``, ``simulate``, ``identify``,
``leaderboard``, ``report``, ``train``, ``presets``) and the top level. The
list has bad numbers (nan, inf, -1, 0, 1e-300, 1e300, huge integers, words) for
every numeric option, malformed ``--speeds``, bad ``--set FIELD=VALUE``, bad
choices, missing, unreadable and malformed motor files, bad ``--estimate``,
unwritable output paths, policy specs that do not load, bad hyperparameter
files and the edge cases of ``simulate`` (``--duration`` at and just below the
window start, ``--speed 0``, a ``--move`` shorter than the ramp and settling,
``--accel 1e-300``). Every case is a mistake; none is a valid command.

Each case runs in this process with stdout and stderr captured; ``SystemExit``
(argparse exits 2) and every other exception are caught. A case is

* ``clean``: exit status 2 and stderr is one non-empty line (argparse's
  ``usage:`` lines before it allowed);
* ``traceback``: an exception escaped ``main``, or stderr holds ``Traceback``;
* ``exit0``: status 0 for a mistake (the line says whether stdout holds the
  word ``nan``, any case);
* ``other``: any other status, or a message of several lines.

Two guards keep an accepted mistake cheap, and count as ``other``: training
that reaches ``learn()`` with more than 64 timesteps, and a process pool of
more than 8 workers, are stopped before they start (the line says so).
A watchdog ends the audit (status 3) if one case runs longer than 240 s.

Cases are cheap: ``sweep`` gets one speed (``--speeds 0.5:0.5:0.1``),
``simulate`` ``--speed 0.5``, ``identify`` ``--method least-squares``,
``leaderboard`` ``--quick --no-plots --no-progress --suite open-loop
--entries none --workers 1``, ``train`` 8 PPO timesteps on one drive without
validation, wherever the mistake is elsewhere. The whole audit takes a few
minutes on 2 cores. Temporary files live in a ``tempfile.mkdtemp()`` directory
(also the working directory during the run) that is removed at the end.

``--glossary`` checks docs/cli.md's glossary (one flag, one meaning) against
the parser, and that each renamed flag is refused with one line naming its new
name; the full audit runs that check first.

Output: one line per case that is not clean (argv with the temporary directory
shown as ``$TMP``, class, first 200 characters of the message or the
exception), the wall time of any case over 5 s, then the summary line
``cli mistakes: N cases, C clean, T tracebacks, Z exit 0, O other``.
Exit status 0 if every case is clean, else 1.

Run it from the repository with the package installed::

    python scripts/audit_cli.py            # run the audit
    python scripts/audit_cli.py --list     # print the cases, run nothing
    python scripts/audit_cli.py --verbose  # every case with its message
"""

from __future__ import annotations

import argparse
import contextlib
import io
import itertools
import math
import os
import re
import shlex
import shutil
import sys
import tempfile
import threading
import time
import traceback
import warnings
import zipfile

os.environ.setdefault("MPLBACKEND", "Agg")

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
OMIT = object()                 # leave an option of the base command out
HUGE_INT = "1" + "0" * 30       # an integer no option can mean
SLOW_S = 5.0                    # report the wall time of cases slower than this
WATCHDOG_S = 240.0              # a case this slow ends the audit
LEARN_LIMIT = 64                # more timesteps than this: training was accepted
POOL_LIMIT = 8                  # more worker processes than this: accepted


class AuditGuard(BaseException):
    """Raised by the audit's guards inside ``main`` (a BaseException, so the
    package's ``except Exception`` does not swallow it)."""


# ---------------------------------------------------------------------------
# Temporary files the cases name
# ---------------------------------------------------------------------------
def make_files(tmp: str) -> dict[str, str]:
    """Create the files and directories the cases refer to; their paths by key."""
    f: dict[str, str] = {}

    def write(key: str, name: str, data: str | bytes) -> None:
        path = os.path.join(tmp, name)
        os.makedirs(os.path.dirname(path), exist_ok=True)
        with open(path, "wb") as fh:
            fh.write(data.encode("utf-8") if isinstance(data, str) else data)
        f[key] = path

    def mkdir(key: str, name: str) -> None:
        path = os.path.join(tmp, name)
        os.makedirs(path, exist_ok=True)
        f[key] = path

    write("file", "a-file.txt", "an ordinary file, not a directory\n")
    mkdir("dir", "a-directory")
    mkdir("dir_json", "motors/dir.json")
    write("m_empty", "motors/empty.json", "")
    write("m_bad", "motors/bad.json", '{"J": 1e-5,,}')
    write("m_list", "motors/list.json", "[1, 2, 3]")
    write("m_number", "motors/number.json", "5")
    write("m_null", "motors/null.json", '{"J": null, "Kd4": null}')
    write("m_unknown", "motors/unknown.json", '{"Jj": 1e-5, "colour": "red"}')
    write("m_string", "motors/string.json", '{"J": "heavy"}')
    write("m_nan", "motors/nan.json", '{"Kd4": NaN}')
    write("m_inf", "motors/inf.json", '{"R": Infinity}')
    write("m_nrfrac", "motors/nrfrac.json", '{"Nr": 50.5}')
    write("m_base", "motors/base.json", '{"base": "nosuch-preset"}')
    write("m_bool", "motors/bool.json", '{"J": true}')
    write("m_latin1", "motors/latin1.json", b'{"name": "r\xe9sum\xe9", "J": 1e-5}')
    write("m_noext", "motors/motor-without-extension", "not json at all\n")
    # policy specs
    write("p_notzip", "policies/notmodel.zip", "this is not a zip archive\n")
    zpath = os.path.join(tmp, "policies", "empty.zip")
    with zipfile.ZipFile(zpath, "w"):
        pass
    f["p_emptyzip"] = zpath
    write("p_syntax", "policies/syntax_error.py", "def policy(:\n    pass\n")
    write("p_raises", "policies/raises.py", "raise RuntimeError('this module fails on import')\n")
    write("p_noattr", "policies/no_attr.py", "VALUE = 1\n")
    write("p_badagent", "policies/badagent.zip", "not a model\n")
    write("p_badagent_json", "policies/badagent.agent.json", "{not json")
    write("p_fakeagent", "policies/fakeagent.zip", "not a model either\n")
    write("p_fakeagent_json", "policies/fakeagent.agent.json", '{"algo": "ppo", "name": "fake"}')
    # train hyperparameter files
    write("h_empty", "hyper/empty.yml", "")
    write("h_bad", "hyper/bad.yml", "StepperDamp-v0: [1, 2\n")
    write("h_nokey", "hyper/nokey.yml", "Pendulum-v1:\n  n_envs: 1\n")
    write("h_list", "hyper/list.yml", "- 1\n- 2\n")
    # report directories
    mkdir("r_empty", "report/empty")
    write("r_bad", "report/bad/leaderboard.json", "{not json")
    f["r_bad"] = os.path.dirname(f["r_bad"])
    write("r_list", "report/list/leaderboard.json", "[]")
    f["r_list"] = os.path.dirname(f["r_list"])
    return f


def window_start() -> float:
    """Start of the measuring window of ``simulate --speed 0.5`` with the defaults."""
    from stepdamp_env.motorfile import load_system
    from stepdamp_env.simulation import (DEFAULT_ACCEL_RPS2, RunSettings, SpeedProfile,
                                         measuring_window)

    start, _ = measuring_window(load_system("patent"),
                                SpeedProfile(speed_rps=0.5, accel_rps2=DEFAULT_ACCEL_RPS2),
                                RunSettings())
    return start


# ---------------------------------------------------------------------------
# The cases
# ---------------------------------------------------------------------------
def _argv(command: str, base: list[tuple[str, object]], over: dict[str, object],
          extra: tuple[str, ...]) -> list[str]:
    opts = dict(base)
    opts.update(over)
    argv = [command]
    for key, value in opts.items():
        if value is OMIT:
            continue
        if value is True:
            argv.append(key)
        elif isinstance(value, (list, tuple)):
            argv += [key, *value]
        else:
            argv += [key, str(value)]
    return argv + list(extra)


def build_cases(tmp: str) -> list[tuple[str, list[str]]]:
    """(label, argv) of every mistake."""
    f = make_files(tmp)
    counter = itertools.count()
    cases: list[tuple[str, list[str]]] = []

    def out() -> str:
        return os.path.join(tmp, "out", f"case{next(counter)}")

    def add(label: str, *argv: str) -> None:
        cases.append((label, list(argv)))

    def sim(label: str, *extra: str, **over: object) -> None:
        add(label, *_argv("simulate", [("--speed", "0.5")], over, extra))

    def sweep(label: str, *extra: str, **over: object) -> None:
        base = [("--speeds", "0.5:0.5:0.1"), ("--no-progress", True), ("--out", out())]
        add(label, *_argv("sweep", base, over, extra))

    def ident(label: str, *extra: str, **over: object) -> None:
        base = [("--method", "least-squares"), ("--out", out())]
        add(label, *_argv("identify", base, over, extra))

    def board(label: str, *extra: str, **over: object) -> None:
        base = [("--quick", True), ("--no-plots", True), ("--no-progress", True),
                ("--suite", "open-loop"), ("--entries", "none"), ("--workers", "1"),
                ("--out", out())]
        add(label, *_argv("leaderboard", base, over, extra))

    def train(label: str, *extra: str, **over: object) -> None:
        base = [("--algo", "ppo"), ("--total-timesteps", "8"), ("--eval-freq", "0"),
                ("--checkpoint-freq", "0"), ("--no-progress", True),
                ("--no-tensorboard", True), ("--presets", "patent"),
                ("--envs-per-preset", "1"), ("--out", out())]
        add(label, *_argv("train", base, over, extra))

    # --- top level --------------------------------------------------------
    add("no command")
    add("unknown command", "nosuch")
    add("misspelled command", "simulat", "--speed", "0.5")
    add("empty command", "")
    add("misspelled top-level flag", "--versoin")
    add("subcommand option before the command", "--motor", "patent", "simulate", "--speed", "0.5")
    add("presets with a stray argument", "presets", "extra")
    add("presets with an option it does not take", "presets", "--motor", "patent")
    add("simulate without --speed", "simulate")
    add("analyse with an unknown motor", "analyse", "--motor", "nosuch")
    add("analyse with a bad drive_mode", "analyse", "--set", "drive_mode=fast")
    add("analyse with a numeric drive_mode", "analyse", "--set", "drive_mode=1")
    add("analyse with an out-of-range field", "analyse", "--set", "L=-1")
    add("analyse with a stray argument", "analyse", "extra")
    add("simulate with a bad drive_mode", "simulate", "--speed", "1", "--set",
        "drive_mode=chopper")
    add("mid-band suite on v1", "leaderboard", "--quick", "--protocol", "v1", "--suite",
        "mid-band", "--out", os.path.join(tmp, "mb"))
    add("unknown protocol", "leaderboard", "--protocol", "v99", "--out",
        os.path.join(tmp, "p99"))
    add("sweep without --out", "sweep", "--speeds", "0.5:0.5:0.1", "--no-progress")
    add("identify without --out", "identify", "--method", "least-squares")
    add("leaderboard without --out", "leaderboard", "--quick", "--no-plots")
    add("option without its value", "simulate", "--speed")
    add("misspelled option", "simulate", "--sped", "0.5")

    # --- simulate: numbers ------------------------------------------------
    for v in ("nan", "inf", "-inf", "1e300", "-1e300", "1001", HUGE_INT, "abc", "",
              "0.5rps", "0,5"):
        sim(f"--speed {v!r}", **{"--speed": v})
    sim("--speed 0 (the ripple is relative to a moving command)", **{"--speed": "0"})
    for v in ("nan", "inf", "-1", "0", "1e-300", "1e300", HUGE_INT, "abc"):
        sim(f"--accel {v!r}", "--accel", v)
    start = window_start()
    for v in ("nan", "inf", "-1", "0", "1e-300", "1e300", HUGE_INT, "abc", "0.01"):
        sim(f"--duration {v!r}", "--duration", v)
    sim("--duration exactly at the window start", "--duration", repr(start))
    sim("--duration just below the window start", "--duration",
        repr(math.nextafter(start, 0.0)))
    for v in ("nan", "inf", "0", "1e-300", "1e300", HUGE_INT, "abc"):
        sim(f"--move {v!r}", "--move", v)
    sim("--move shorter than the ramp and settling", "--move", "0.001")
    sim("--move with --speed 0", "--move", "1", **{"--speed": "0"})
    for v in ("0", "-1", "1.5", "nan", "1e300", "1001", HUGE_INT, "abc"):
        sim(f"--substeps {v!r}", "--substeps", v)
    for v in ("-1", "nan", "inf", "1.5", str(2 ** 53), HUGE_INT, "abc"):
        sim(f"--noise-seed {v!r}", "--noise-seed", v)

    # --- simulate: choices, motor files, --set, --estimate, --trace ---------
    sim("--mode not a choice", "--mode", "closed-loop")
    sim("--mode in capitals", "--mode", "SERVO")
    sim("--base-controller not a choice", "--base-controller", "patent")
    sim("--base-controller empty", "--base-controller", "")
    sim("--velocity-estimator misspelled", "--mode", "servo", "--velocity-estimator", "kalmann")
    sim("--motor unknown preset", "--motor", "nosuch")
    sim("--motor empty", "--motor", "")
    sim("--motor missing .json file", "--motor", os.path.join(tmp, "motors", "missing.json"))
    sim("--motor a directory", "--motor", f["dir"])
    sim("--motor a directory named .json", "--motor", f["dir_json"])
    sim("--motor /dev/null", "--motor", "/dev/null")
    sim("--motor unreadable (/proc/self/mem)", "--motor", "/proc/self/mem")
    sim("--motor empty file", "--motor", f["m_empty"])
    sim("--motor invalid JSON", "--motor", f["m_bad"])
    sim("--motor JSON list", "--motor", f["m_list"])
    sim("--motor JSON number", "--motor", f["m_number"])
    sim("--motor JSON with null values", "--motor", f["m_null"])
    sim("--motor JSON with unknown keys", "--motor", f["m_unknown"])
    sim("--motor JSON with a string value", "--motor", f["m_string"])
    sim("--motor JSON with NaN", "--motor", f["m_nan"])
    sim("--motor JSON with Infinity", "--motor", f["m_inf"])
    sim("--motor JSON with Nr=50.5", "--motor", f["m_nrfrac"])
    sim("--motor JSON with true for a number", "--motor", f["m_bool"])
    sim("--motor JSON with an unknown base preset", "--motor", f["m_base"])
    sim("--motor file not UTF-8", "--motor", f["m_latin1"])
    sim("--motor file without .json, not JSON", "--motor", f["m_noext"])
    for item in ("foo=1", "J", "=1", "J=", "J=nan", "J=inf", "J=-inf", "J=None", "J=null",
                 "J=true", "J=abc", "J=0", "J=-1", "R=1e300", "J=1e-300", "j=1e-5",
                 "J=1e-5,2", "encoder_cpr=1000.5", "Nr=50.5", "microsteps=2.5", "Nr=0",
                 "microsteps=0", "Nr=1e300", f"Nr={HUGE_INT}", "encoder_cpr=nan",
                 "microsteps=inf", "pwm_hz=-1", "Vdc=0"):
        sim(f"--set {item!r}", "--set", item)
    sim("--estimate unknown preset", "--base-controller", "patent-ff", "--estimate", "nosuch")
    sim("--estimate empty", "--base-controller", "patent-ff", "--estimate", "")
    sim("--estimate missing file", "--base-controller", "patent-ff", "--estimate",
        os.path.join(tmp, "motors", "missing.json"))
    sim("--estimate invalid JSON", "--base-controller", "patent-ff", "--estimate", f["m_bad"])
    sim("--estimate JSON list", "--base-controller", "patent-ff", "--estimate", f["m_list"])
    sim("--estimate JSON with null values", "--base-controller", "patent-ff", "--estimate",
        f["m_null"])
    sim("--trace a directory", "--trace", f["dir"])
    sim("--trace under /proc", "--trace", "/proc/stepdamp-audit.npz")
    sim("--trace under a non-existent /proc directory", "--trace",
        "/proc/stepdamp-audit/trace.npz")
    sim("--trace under a file", "--trace", os.path.join(f["file"], "trace.npz"))
    sim("--trace empty", "--trace", "")

    # --- sweep ------------------------------------------------------------
    for v in ("", "0.5", "0.5:1", "0.5:1:0.1:2", "a:b:c", "nan:1:0.1", "0.5:inf:0.1",
              "0.5:1:0", "0.5:1:-0.1", "1:0.5:0.1", "0:1:0.5", "0.5:1e300:1e-300",
              "0.5:1e6:0.001", "0.5,1.0,1.5", "0.5:0.5:nan", "2000:2000:1",
              "1e300:1e300:1", ":::", "0.5::0.1", "1e-300:1e-300:0.1"):
        sweep(f"--speeds {v!r}", **{"--speeds": v})
    sweep("--speeds negative start (--speeds=-1:1:0.5)", "--speeds=-1:1:0.5",
          **{"--speeds": OMIT})
    for v in ("0", "-1", "nan", "1.5", "1e300", HUGE_INT, "abc"):
        sweep(f"--workers {v!r}", "--workers", v)
    for v in ("nan", "0", "1e-300"):
        sweep(f"--accel {v!r}", "--accel", v)
    sweep("--substeps 0", "--substeps", "0")
    sweep("--noise-seed -1", "--noise-seed", "-1")
    sweep("--base-controller not a choice", "--base-controller", "patent")
    sweep("--base-controller one good, one not", "--base-controller", "none", "nosuch")
    sweep("--mode not a choice", "--mode", "closed-loop")
    sweep("--velocity-estimator not a choice", "--velocity-estimator", "ekf")
    sweep("--motor unknown preset", "--motor", "nosuch")
    sweep("--motor invalid JSON", "--motor", f["m_bad"])
    sweep("--motor a directory", "--motor", f["dir"])
    sweep("--set unknown field", "--set", "foo=1")
    sweep("--set Nr=50.5", "--set", "Nr=50.5")
    sweep("--set J=nan", "--set", "J=nan")
    sweep("--estimate unknown", "--base-controller", "patent-ff", "--estimate", "nosuch")
    sweep("--out an existing file", **{"--out": f["file"]})
    sweep("--out under /proc", **{"--out": "/proc/stepdamp-audit/out"})
    sweep("--out under a file", **{"--out": os.path.join(f["file"], "out")})
    sweep("--out empty", **{"--out": ""})

    # --- identify ---------------------------------------------------------
    ident("--method not a choice", **{"--method": "lsq"})
    ident("--method empty", **{"--method": ""})
    for v in ("-1", "nan", "inf", "1.5", str(2 ** 53), HUGE_INT, "abc"):
        ident(f"--noise-seed {v!r}", "--noise-seed", v)
    ident("--motor unknown preset", "--motor", "nosuch")
    ident("--motor empty file", "--motor", f["m_empty"])
    ident("--motor JSON list", "--motor", f["m_list"])
    ident("--motor JSON with null values", "--motor", f["m_null"])
    ident("--set unknown field", "--set", "foo=1")
    ident("--set encoder_cpr=1000.5", "--set", "encoder_cpr=1000.5")
    ident("--set J=nan", "--set", "J=nan")
    ident("--set missing '='", "--set", "Kd4")
    sweep("--backend not a choice", **{"--backend": "dask"})
    sweep("--ray-address without --backend ray", **{"--ray-address": "auto"})
    ident("--out an existing file", **{"--out": f["file"]})
    ident("--out under /proc", **{"--out": "/proc/stepdamp-audit/out"})
    ident("--out under a file", **{"--out": os.path.join(f["file"], "out")})
    ident("--out empty", **{"--out": ""})

    # --- leaderboard ------------------------------------------------------
    board("--suite not a choice", **{"--suite": "both"})
    board("--suite empty", **{"--suite": ""})
    board("--entries unknown", **{"--entries": "nosuch"})
    board("--entries one good, one unknown", **{"--entries": ["none", "nosuch"]})
    board("--entries empty name", **{"--entries": ""})
    board("--policy module that does not exist", "--policy", "nosuch_module_xyz:attr")
    board("--policy missing .py file", "--policy",
          os.path.join(tmp, "policies", "missing.py") + ":Policy")
    board("--policy .zip that is not a model", "--policy", f["p_notzip"])
    board("--policy empty .zip archive", "--policy", f["p_emptyzip"])
    board("--policy missing .zip", "--policy", os.path.join(tmp, "policies", "missing.zip"))
    board("--policy .zip with an invalid .agent.json", "--policy", f["p_badagent"])
    board("--policy .zip with an .agent.json but no model", "--policy", f["p_fakeagent"])
    board("--policy .py with a syntax error", "--policy", f["p_syntax"] + ":policy")
    board("--policy .py that raises on import", "--policy", f["p_raises"] + ":Policy")
    board("--policy .py without that attribute", "--policy", f["p_noattr"] + ":Policy")
    board("--policy a number, not a policy", "--policy", "math:pi")
    board("--policy a class that is not a policy", "--policy", "builtins:object")
    board("--policy a function returning a string", "--policy", "os:getcwd")
    board("--policy unknown bare name", "--policy", "nosuch")
    board("--policy empty", "--policy", "")
    board("--policy a directory", "--policy", f["dir"])
    for v in ("0", "-1", "nan", "1.5", HUGE_INT, "abc"):
        board(f"--workers {v!r}", **{"--workers": v})
    board("--backend not a choice", **{"--backend": "dask"})
    board("--ray-address without --backend ray", **{"--ray-address": "auto"})
    board("--out an existing file", **{"--out": f["file"]})
    board("--out under /proc", **{"--out": "/proc/stepdamp-audit/out"})
    board("--out under a file", **{"--out": os.path.join(f["file"], "out")})
    board("--out empty", **{"--out": ""})

    # --- report -----------------------------------------------------------
    add("report without DIR", "report")
    add("report missing DIR", "report", os.path.join(tmp, "no-such-dir"))
    add("report a file", "report", f["file"])
    add("report a directory without leaderboard.json", "report", f["r_empty"])
    add("report invalid leaderboard.json", "report", f["r_bad"])
    add("report leaderboard.json holding a list", "report", f["r_list"])
    add("report --suite not a choice", "report", "--suite", "both", f["r_empty"])

    # --- train ------------------------------------------------------------
    train("--algo not a choice", **{"--algo": "a2c"})
    train("--backend not a choice", **{"--backend": "dask"})
    train("--ray-address without --backend ray", "--seeds", "1-2", **{"--ray-address": "auto"})
    for v in ("nan", "inf", "-1", "0", "1e300", HUGE_INT, "abc", "1.5"):
        train(f"--total-timesteps {v!r}", **{"--total-timesteps": v})
    for v in ("-1", "1000", HUGE_INT, "nan"):
        train(f"--seed {v!r}", "--seed", v)
    for v in ("0", "-1"):
        train(f"--envs-per-preset {v!r}", **{"--envs-per-preset": v})
    train("--eval-freq -1", **{"--eval-freq": "-1"})
    train("--checkpoint-freq -1", **{"--checkpoint-freq": "-1"})
    train("--val-seed -1", "--val-seed", "-1", **{"--eval-freq": "1000"})
    train("--val-motors-per-preset -1", "--val-motors-per-preset", "-1",
          **{"--eval-freq": "1000"})
    train("--presets unknown preset", **{"--presets": "nosuch"})
    train("--presets empty name", **{"--presets": ""})
    train("--hyperparams missing file", "--hyperparams", os.path.join(tmp, "hyper", "missing.yml"))
    train("--hyperparams empty file", "--hyperparams", f["h_empty"])
    train("--hyperparams invalid YAML", "--hyperparams", f["h_bad"])
    train("--hyperparams without the StepperDamp-v0 entry", "--hyperparams", f["h_nokey"])
    train("--hyperparams a YAML list", "--hyperparams", f["h_list"])
    train("--hyperparams a directory", "--hyperparams", f["dir"])
    train("--hyperparam missing '='", "--hyperparam", "learning_rate")
    train("--hyperparam unknown hyperparameter", "--hyperparam", "no_such_kwarg=1")
    train("--hyperparam learning_rate=nan", "--hyperparam", "learning_rate=nan")
    train("--hyperparam learning_rate=abc", "--hyperparam", "learning_rate=abc")
    train("--hyperparam n_epochs=-1", "--hyperparam", "n_epochs=-1")
    train("--hyperparam batch_size=0", "--hyperparam", "batch_size=0")
    train("--out an existing file", **{"--out": f["file"]})
    train("--out under /proc", **{"--out": "/proc/stepdamp-audit/out"})
    train("--out under a file", **{"--out": os.path.join(f["file"], "out")})
    return cases


# ---------------------------------------------------------------------------
# Guards: an accepted mistake must not start a long job
# ---------------------------------------------------------------------------
def install_guards() -> None:
    import multiprocessing.context

    original_pool = multiprocessing.context.BaseContext.Pool

    def guarded_pool(self, processes=None, *args, **kwargs):
        if processes is not None and processes > POOL_LIMIT:
            raise AuditGuard(f"accepted: a pool of {processes} worker processes was about "
                             "to start (stopped by the audit's guard)")
        return original_pool(self, processes, *args, **kwargs)

    multiprocessing.context.BaseContext.Pool = guarded_pool
    try:
        from stable_baselines3.common.off_policy_algorithm import OffPolicyAlgorithm
        from stable_baselines3.common.on_policy_algorithm import OnPolicyAlgorithm
    except ImportError:
        return
    for cls in (OnPolicyAlgorithm, OffPolicyAlgorithm):
        original = cls.learn

        def guarded_learn(self, total_timesteps, *args, __original=original, **kwargs):
            if total_timesteps > LEARN_LIMIT:
                raise AuditGuard(f"accepted: training started, learn(total_timesteps="
                                 f"{total_timesteps}) (stopped by the audit's guard)")
            return __original(self, total_timesteps, *args, **kwargs)

        cls.learn = guarded_learn


class Watchdog:
    """Ends the audit if one case runs longer than ``WATCHDOG_S``."""

    def __init__(self) -> None:
        self.case: str | None = None
        self.since = 0.0
        self.lock = threading.Lock()
        threading.Thread(target=self._watch, daemon=True).start()

    def start(self, case: str) -> None:
        with self.lock:
            self.case, self.since = case, time.monotonic()

    def stop(self) -> None:
        with self.lock:
            self.case = None

    def _watch(self) -> None:
        while True:
            time.sleep(1.0)
            with self.lock:
                if self.case is not None and time.monotonic() - self.since > WATCHDOG_S:
                    os.write(2, f"audit_cli: case still running after {WATCHDOG_S:.0f} s, "
                                f"audit aborted: {self.case}\n".encode())
                    os._exit(3)


# ---------------------------------------------------------------------------
# Running and classifying
# ---------------------------------------------------------------------------
def run_case(main, argv: list[str]) -> dict:
    out, err = io.StringIO(), io.StringIO()
    status: int | None = None
    exc_text = None
    guard = None
    t0 = time.perf_counter()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err), \
            warnings.catch_warnings():
        # A filter change clears the "already shown" registries, so every case
        # shows its warnings as a fresh process would; the appended filter is
        # the interpreter's own default action.
        warnings.simplefilter("default", append=True)
        try:
            status = main(argv)
        except SystemExit as exc:
            code = exc.code
            if code is None:
                status = 0
            elif isinstance(code, int):
                status = code
            else:                          # sys.exit("message"): printed, status 1
                print(code, file=sys.stderr)
                status = 1
        except AuditGuard as exc:
            guard = str(exc)
        except KeyboardInterrupt:
            raise
        except BaseException as exc:  # noqa: BLE001 - every escape is a finding
            exc_text = f"{exc!r} at {_where(exc)}"
    return {"status": status, "stdout": out.getvalue(), "stderr": err.getvalue(),
            "exception": exc_text, "guard": guard, "wall_s": time.perf_counter() - t0}


def _where(exc: BaseException) -> str:
    """Where it was raised: the innermost frame of the project's code (not this
    script), and the innermost frame when that lies elsewhere (a library)."""
    frames = traceback.extract_tb(exc.__traceback__)
    if not frames:
        return "?"

    def name(fr: traceback.FrameSummary) -> str:
        return f"{os.path.basename(fr.filename)}:{fr.lineno} ({fr.name})"

    ours = [fr for fr in frames if os.path.abspath(fr.filename).startswith(REPO + os.sep)
            and os.path.abspath(fr.filename) != os.path.abspath(__file__)]
    if ours and ours[-1] is not frames[-1]:
        return f"{name(ours[-1])} -> {name(frames[-1])}"
    return name(frames[-1])


def _strip_usage(lines: list[str]) -> list[str]:
    """Drop argparse's ``usage:`` block (its first line and indented continuations)."""
    if lines and lines[0].startswith("usage:"):
        i = 1
        while i < len(lines) and lines[i][:1].isspace():
            i += 1
        return lines[i:]
    return lines


def classify(r: dict) -> tuple[str, str]:
    """(class, message) of one run."""
    err = r["stderr"].strip()
    if r["guard"] is not None:
        return "other", r["guard"]
    if r["exception"] is not None:
        return "traceback", r["exception"]
    if "Traceback" in err:
        tail = [ln for ln in err.splitlines() if ln.strip()]
        return "traceback", f"status {r['status']}: {tail[-1] if tail else err}"
    if r["status"] == 0:
        nan = "yes" if re.search(r"\bnan\b", r["stdout"], re.IGNORECASE) else "no"
        shown = f"stdout: {_one_line(r['stdout'])}" if r["stdout"].strip() else \
            f"stderr: {_one_line(err)}"
        return "exit0", f"nan in stdout: {nan}; {shown}"
    lines = _strip_usage([ln for ln in err.splitlines() if ln.strip()])
    if r["status"] == 2 and len(lines) == 1:
        return "clean", lines[0].strip()
    return "other", f"status {r['status']}: {_one_line(err) or '(no message)'}"


def _one_line(text: str) -> str:
    return " | ".join(ln.strip() for ln in text.strip().splitlines() if ln.strip())


def parser_flags() -> tuple[dict[str, set[str]], dict[tuple[str, str], str]]:
    """Every command's options: flag -> commands, and the renamed ones, (command,
    old flag) -> None (their help is suppressed; the error names the new flag)."""
    from stepdamp_env.cli import build_parser

    sub = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    flags: dict[str, set[str]] = {}
    hidden: dict[tuple[str, str], str] = {}
    for name, command in sub.choices.items():
        for action in command._actions:
            for flag in action.option_strings:
                if flag in ("-h", "--help"):
                    continue
                if action.help == argparse.SUPPRESS:
                    hidden[(name, flag)] = ""
                else:
                    flags.setdefault(flag, set()).add(name)
    return flags, hidden


def _table(text: str, heading: str) -> list[list[str]]:
    """The rows of the first Markdown table after ``heading``, cells stripped of `."""
    rows, seen = [], False
    for line in text[text.index(heading):].splitlines()[1:]:
        if line.startswith("|"):
            seen = True
            cells = [c.strip().strip("`") for c in line.strip().strip("|").split("|")]
            if not set(cells[0]) <= set("-") and cells[0] not in ("flag", "command"):
                rows.append(cells)
        elif seen:
            break
    return rows


def glossary_problems(path: str = os.path.join(REPO, "docs", "cli.md")) -> list[str]:
    """What differs between the glossary of docs/cli.md and the parser: a flag
    not listed, listed twice or with other commands, a meaning given two flags,
    a renamed flag that is not refused with one line naming its new name."""
    from stepdamp_env.cli import main as cli_main

    text = open(path, encoding="utf-8").read()
    listed = _table(text, "## Glossary: one flag, one meaning")
    renamed = _table(text, "Renamed in ")
    flags, hidden = parser_flags()
    problems = []
    names = [r[0] for r in listed]
    meanings = [r[1] for r in listed]
    problems += [f"{f}: listed twice" for f in sorted({n for n in names if names.count(n) > 1})]
    problems += [f"meaning {m!r}: given to two flags"
                 for m in sorted({m for m in meanings if meanings.count(m) > 1})]
    for flag, _, commands in listed:
        have = flags.get(flag)
        if have is None:
            problems.append(f"{flag}: in the glossary, in no command")
        elif set(c.strip() for c in commands.split(",")) != have:
            problems.append(f"{flag}: the glossary says {commands}; the parser has "
                            f"{', '.join(sorted(have))}")
    problems += [f"{f}: not in the glossary ({', '.join(sorted(c))})"
                 for f, c in sorted(flags.items()) if f not in names]
    table = {(c, old): new for c, old, new in renamed}
    problems += [f"{c} {old}: hidden, not in the renamed table" for c, old in sorted(hidden)
                 if (c, old) not in table]
    for (command, old), new in sorted(table.items()):
        if (command, old) not in hidden:
            problems.append(f"{command} {old}: in the renamed table, not in the parser")
            continue
        err = io.StringIO()
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
            try:
                status = cli_main([command, old, "1"])
            except SystemExit as exc:
                status = exc.code
        last = err.getvalue().strip().splitlines()[-1:]
        if status != 2 or not last or f"{old} was renamed to {new}" not in last[0]:
            problems.append(f"{command} {old}: exit {status}, {last} (expected one line "
                            f"naming {new})")
    return problems


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--list", action="store_true", help="print the cases, run nothing")
    parser.add_argument("--glossary", action="store_true",
                        help="check docs/cli.md's glossary against the parser, run nothing else")
    parser.add_argument("--verbose", action="store_true",
                        help="print every case with its message")
    opts = parser.parse_args(argv)
    problems = glossary_problems()
    for p in problems:
        print(f"glossary  {p}")
    if opts.glossary:
        print(f"cli glossary: {len(problems)} problems")
        return 1 if problems else 0

    tmp = tempfile.mkdtemp(prefix="stepdamp-audit-")
    here = os.getcwd()

    def show(text: str) -> str:
        return text.replace(tmp, "$TMP")

    try:
        cases = build_cases(tmp)
        keys = [tuple(re.sub(r"case\d+", "caseN", a) for a in argv) for _, argv in cases]
        dupes = {k for k in keys if keys.count(k) > 1}
        if dupes:
            raise SystemExit(f"audit_cli: duplicate cases {sorted(dupes)}")
        if opts.list:
            for i, (label, argv) in enumerate(cases, 1):
                print(f"{i:3d}. {label}: stepdamp {show(shlex.join(argv))}")
            print(f"{len(cases)} cases")
            return 0

        from stepdamp_env.cli import main as cli_main

        install_guards()
        watchdog = Watchdog()
        os.chdir(tmp)               # stray relative outputs land in the temp directory
        counts = {"clean": 0, "traceback": 0, "exit0": 0, "other": 0}
        for label, argv in cases:
            cmd = f"stepdamp {show(shlex.join(argv))}"
            watchdog.start(cmd)
            r = run_case(cli_main, argv)
            watchdog.stop()
            kind, message = classify(r)
            counts[kind] += 1
            slow = f" [{r['wall_s']:.1f} s]" if r["wall_s"] > SLOW_S else ""
            if kind != "clean" or opts.verbose:
                print(f"{kind:9s} {cmd}{slow} -> {show(message)[:200]}", flush=True)
            elif slow:
                print(f"slow      {cmd}{slow}", flush=True)
        print(f"cli mistakes: {len(cases)} cases, {counts['clean']} clean, "
              f"{counts['traceback']} tracebacks, {counts['exit0']} exit 0, "
              f"{counts['other']} other")
        return 0 if counts["clean"] == len(cases) and not problems else 1
    finally:
        os.chdir(here)
        shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    sys.exit(main())
