"""Reliability: nothing outside --out touched, no hang, no traceback, no silent
wrong number (files through links, lost workers, concurrent runs, hostile JSON,
edited caches and boards)."""

from __future__ import annotations

import gzip
import hashlib
import json
import lzma
import os
import shutil
import signal
import subprocess
import sys
import time

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from stepdamp_env import io as sio
from stepdamp_env.bench import leaderboard
from stepdamp_env.bench.leaderboard import (RESUME_DIR, clear_resume_dir, finish_resume_dir,
                                            identify_cached, open_resume_dir, run_leaderboard)
from stepdamp_env.bench.motors import protocol_motors
from stepdamp_env.bench.provenance import board_fingerprint
from stepdamp_env.bench.protocols.v1 import quick_protocol_v1
from stepdamp_env.cli import main
from stepdamp_env.identify import identify
from stepdamp_env.limits import LIMITS
from stepdamp_env.parallel import WorkerLostError, pool_map
from stepdamp_env.params import ParameterError

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
V3_BOARD = os.path.join(ROOT, "docs", "results", "v3")
BATCH = f"{'a' * 16}-{'b' * 24}.json"


def _tiny():
    """One motor in open loop: a board in seconds."""
    protocol = quick_protocol_v1()
    motors = protocol_motors(protocol)
    return protocol.with_custom_motors([motors[0].system]).with_suites(("open-loop",))


def _one_line_error(capsys, *words: str) -> str:
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err, err
    for w in words:
        assert w in err, err
    return err


# -- 1. links: nothing outside --out is deleted or written ---------------------------------
def test_a_linked_resume_dir_is_refused_and_what_it_points_to_is_untouched(tmp_path, capsys):
    victim, out = tmp_path / "v", tmp_path / "o"
    victim.mkdir()
    out.mkdir()
    (victim / "thesis.tex").write_text("a")
    os.symlink(victim, out / RESUME_DIR)
    assert main(["leaderboard", "--quick", "--suite", "open-loop", "--entries", "none",
                 "--no-progress", "--out", str(out)]) == 2
    _one_line_error(capsys, "symbolic link", ".resume")
    assert os.listdir(victim) == ["thesis.tex"]
    assert os.path.islink(out / RESUME_DIR)


def test_a_linked_out_is_refused_and_left_a_link(tmp_path, capsys):
    real = tmp_path / "real"
    real.mkdir()
    (real / "notes.txt").write_text("mine")
    os.symlink(real, tmp_path / "out")
    for argv in (["leaderboard", "--quick", "--entries", "none"], ["identify"],
                 ["sweep", "--speeds", "0.5:0.6:0.1"]):
        assert main([*argv, "--out", str(tmp_path / "out")]) == 2
        _one_line_error(capsys, "symbolic link", "--out")
    assert os.path.islink(tmp_path / "out") and os.listdir(real) == ["notes.txt"]
    assert sorted(os.listdir(tmp_path)) == ["out", "real"]          # no staging left over


def test_a_resume_dir_with_files_the_tool_did_not_write_is_refused(tmp_path):
    resume = tmp_path / RESUME_DIR
    resume.mkdir()
    (resume / "thesis.tex").write_text("a")
    with pytest.raises(ParameterError, match="did not write"):
        open_resume_dir(str(resume))
    assert os.listdir(resume) == ["thesis.tex"]


def test_only_the_tools_own_batch_files_are_removed(tmp_path):
    resume = tmp_path / RESUME_DIR
    resume.mkdir()
    (resume / BATCH).write_text("[]")                                  # an older run's
    (resume / f".{BATCH[:-5]}.abcd_123.tmp.json").write_text("[")    # its temporary file
    open_resume_dir(str(resume))                                       # adopted: ours only
    (resume / "notes.txt").write_text("mine")                         # added since
    clear_resume_dir(str(resume))
    assert sorted(os.listdir(resume)) == [".stepdamp-resume", "notes.txt"]


def test_a_linked_leftover_staging_dir_is_refused_and_its_target_kept(tmp_path):
    victim = tmp_path / "v"
    victim.mkdir()
    (victim / "keep.txt").write_text("a")
    os.symlink(victim, tmp_path / ".out.staging-999999999")          # no such process
    with pytest.raises(ParameterError, match="symbolic link"):
        with sio.staged_directory(tmp_path / "out", ["*.json"]):
            pass
    assert os.listdir(victim) == ["keep.txt"]


def test_the_output_keeps_hidden_files_and_links_it_did_not_write(tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    (out / ".gitignore").write_text("*\n")
    (out / "old.json").write_text("{}")
    os.symlink("/nonexistent/target", out / "link")
    with sio.staged_directory(out, ["*.json"]) as stage:
        sio.write_json(os.path.join(stage, "new.json"), {})
    assert sorted(os.listdir(out)) == [".gitignore", "link", "new.json"]
    assert os.readlink(out / "link") == "/nonexistent/target"


# -- 2. a lost worker ends the map at once -------------------------------------------------
def _dies_on_five(x: int) -> int:
    if x == 5:
        os.kill(os.getpid(), signal.SIGKILL)
    time.sleep(0.02)
    return x * x


def test_a_killed_worker_ends_the_map_within_seconds_keeping_finished_results():
    got: list[int] = []
    start = time.monotonic()
    with pytest.raises(WorkerLostError, match="worker process died"):
        pool_map(_dies_on_five, list(range(64)), 2, max_chunk=1,
                 on_result=lambda i, r: got.append(i))
    assert time.monotonic() - start < 10
    assert got and 5 not in got


def test_pool_results_stay_in_order_whatever_order_chunks_finish():
    assert pool_map(_sleep_inverse, list(range(12)), 2, max_chunk=1) == \
        [x * x for x in range(12)]


def _sleep_inverse(x: int) -> int:
    time.sleep(0.02 * (12 - x))
    return x * x


_REAL_RUN_BATCH = leaderboard._run_batch


def _run_batch_or_die(batch):
    """velocity-feedback's batch waits until another batch is kept on disk, then its
    worker is killed: the board loses a worker after some, not all, batches."""
    if batch.spec == "velocity-feedback":
        resume = os.environ["STEPDAMP_TEST_RESUME"]
        deadline = time.time() + 120
        while time.time() < deadline and not any(
                n.endswith(".json") and not n.startswith(".") for n in os.listdir(resume)):
            time.sleep(0.05)
        os.kill(os.getpid(), signal.SIGKILL)
    return _REAL_RUN_BATCH(batch)


@pytest.mark.slow
def test_killing_a_worker_of_a_board_ends_it_with_one_line_and_the_rerun_resumes(
        tmp_path, monkeypatch, capsys):
    out = tmp_path / "board"
    argv = ["leaderboard", "--quick", "--protocol", "v1", "--suite", "open-loop", "--entries",
            "ff-delay-comp", "velocity-feedback", "--workers", "2", "--no-progress",
            "--no-plots", "--out", str(out)]
    monkeypatch.setenv("STEPDAMP_TEST_RESUME", str(out / RESUME_DIR))
    monkeypatch.setattr(leaderboard, "_run_batch", _run_batch_or_die)   # forked workers see it
    start = time.time()
    assert main(argv) == 1
    assert time.time() - start < 150
    err = capsys.readouterr().err.strip()
    assert "Traceback" not in err and "worker process died" in err.splitlines()[-1], err
    monkeypatch.setattr(leaderboard, "_run_batch", _REAL_RUN_BATCH)
    assert main(argv) == 0
    assert "resuming: " in capsys.readouterr().err


# -- 5. one run per output directory -------------------------------------------------------
def test_a_second_run_on_a_locked_out_says_which_process_holds_it(tmp_path, capsys):
    out = tmp_path / "out"
    with sio.output_lock(out, "--out"):
        (out / RESUME_DIR).mkdir()
        half = out / RESUME_DIR / f".{BATCH[:-5]}.abcd_123.tmp.json"
        half.write_text("[")                                    # the first run's, half-written
        assert main(["leaderboard", "--quick", "--suite", "open-loop", "--entries", "none",
                     "--no-progress", "--out", str(out)]) == 2
        _one_line_error(capsys, f"process {os.getpid()}", "--out")
        assert half.exists()
    with sio.output_lock(out, "--out"):                         # released: free again
        pass


def test_the_lock_is_released_when_its_holder_dies(tmp_path):
    out = tmp_path / "out"
    code = ("import sys, time; from stepdamp_env.io import output_lock\n"
            "with output_lock(sys.argv[1], '--out'):\n    print('held', flush=True); "
            "time.sleep(60)\n")
    holder = subprocess.Popen([sys.executable, "-c", code, str(out)], stdout=subprocess.PIPE,
                              text=True)
    assert holder.stdout.readline().strip() == "held"
    with pytest.raises(ParameterError, match=f"process {holder.pid}"):
        with sio.output_lock(out, "--out"):
            pass
    holder.kill()
    holder.wait()
    with sio.output_lock(out, "--out"):
        pass


# -- 6. one JSON reader --------------------------------------------------------------------
JSON = st.recursive(
    st.none() | st.booleans() | st.integers(-2**53, 2**53) |
    st.floats(allow_nan=False, allow_infinity=False) | st.text(max_size=20),
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=8), inner,
                                                                  max_size=4),
    max_leaves=30)


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(value=JSON)
def test_the_reader_gives_back_what_was_written(tmp_path, value):
    path = tmp_path / "x.json"
    sio.write_json(path, value)
    assert sio.read_json(path, "file") == value


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.binary(max_size=300))
def test_any_bytes_give_a_value_or_a_one_line_error_naming_the_file(tmp_path, data):
    path = tmp_path / "x.json"
    path.write_bytes(data)
    try:
        sio.read_json(path, "motor file")
    except ParameterError as exc:
        assert "motor file" in str(exc) and str(path) in str(exc)
        assert "\n" not in str(exc)


@settings(max_examples=50, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(depth=st.integers(LIMITS.json_depth + 1, 20000), opener=st.sampled_from("[{"))
def test_deep_nesting_is_refused_before_parsing(tmp_path, depth, opener):
    path = tmp_path / "deep.json"
    path.write_text(('{"a":' * depth + "1" + "}" * depth) if opener == "{" else
                    ("[" * depth + "]" * depth))
    with pytest.raises(ParameterError, match="nests"):
        sio.read_json(path, "board")
    assert sio.read_json_or_none(path) is None


def test_brackets_inside_strings_do_not_count_as_nesting(tmp_path):
    path = tmp_path / "x.json"
    path.write_text(json.dumps({"name": "[" * 5000 + '\\"{' * 100}))
    assert sio.read_json(path, "file")["name"].startswith("[[[")


@pytest.mark.parametrize("argv", [
    ["motors", "{deep}"],
    ["simulate", "--motor", "{deep}", "--speed", "1"],
    ["leaderboard", "--quick", "--motors", "{deep}", "--out", "{tmp}/o"],
    ["simulate", "--speed", "1", "--estimate", "{deep}"],
    ["report", "{tmp}/board"],
])
def test_deep_json_anywhere_is_a_one_line_error(tmp_path, capsys, argv):
    deep = tmp_path / "deep.json"
    deep.write_text("[" * 1000 + "]" * 1000)
    (tmp_path / "board").mkdir()
    (tmp_path / "board" / "leaderboard.json").write_text("[" * 1000 + "]" * 1000)
    args = [a.format(deep=deep, tmp=tmp_path) for a in argv]
    assert main(args) == 2
    _one_line_error(capsys, "nests 1000 levels")


def test_a_list_file_naming_itself_is_a_one_line_error(tmp_path, capsys):
    (tmp_path / "a.json").write_text(json.dumps([str(tmp_path / "b.json")]))
    (tmp_path / "b.json").write_text(json.dumps(["patent", str(tmp_path / "a.json")]))
    assert main(["motors", str(tmp_path / "a.json")]) == 2
    _one_line_error(capsys, "names itself")


def test_an_array_for_a_choice_option_is_named():
    import gymnasium as gym

    import stepdamp_env  # noqa: F401 - registers the envs
    for env_id in ("StepperDamp-v0", "StepperDamp-v1"):
        with pytest.raises(ParameterError, match="action_mode="):
            gym.make(env_id, action_mode=np.array(["harmonic", "current"]))
    from stepdamp_env.simulation import RunSettings
    with pytest.raises(ParameterError, match="mode="):
        RunSettings(mode=np.array(["servo"]))


def test_a_bare_sb3_model_of_other_observations_is_a_one_line_error(tmp_path, capsys):
    from stepdamp_agents import reference_names

    source = os.path.join(ROOT, "agents", "reference")
    name = next(n for n in sorted(os.listdir(source))
                if n.startswith("ppo-open-loop.") and n.endswith(".zip"))
    assert reference_names()
    shutil.copy(os.path.join(source, name), tmp_path / "bare.zip")
    assert main(["leaderboard", "--quick", "--suite", "open-loop", "--entries", "none",
                 "--policy", str(tmp_path / "bare.zip"), "--no-progress",
                 "--out", str(tmp_path / "o")]) == 2
    _one_line_error(capsys, "takes observations of shape", "bare.json")


# -- 7. kept results carry a checksum; the board its fingerprint ---------------------------
@settings(max_examples=100, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(value=JSON, where=st.floats(0, 1, exclude_max=True), bit=st.integers(0, 7))
def test_a_changed_byte_in_a_kept_entry_is_never_read_as_another_value(tmp_path, value, where,
                                                                       bit):
    path = tmp_path / "entry.json"
    sio.write_checked_json(path, "key", value)
    data = bytearray(path.read_bytes())
    data[int(where * len(data))] ^= 1 << bit
    path.write_bytes(bytes(data))
    got = sio.read_checked_json(path, "key", "cache entry")
    assert got is None or got == value      # whitespace may change; the value never
    assert sio.read_checked_json(path, "other key", "cache entry") is None


def test_a_kept_entry_is_one_compact_encoding_of_its_key_and_content(tmp_path):
    # Keys in their own order, floats as repr, NaN kept: the file's content is the
    # checksum's text, and it reads back equal (the same order included).
    content = [{"z": 0.1, "a": float("nan"), "m": [1, -0.0, 1e300]}, {"b": np.float64(2.5)}]
    path = tmp_path / "entry.json"
    sio.write_checked_json(path, "k\u00e9y", content)
    text = path.read_text(encoding="utf-8")
    kept = json.loads(text)
    body = json.dumps(["k\u00e9y", kept["content"]])
    assert "\n" not in text.rstrip("\n") and kept["key"] == "k\u00e9y"
    assert kept["sha256"] == hashlib.sha256(body.encode("utf-8")).hexdigest()
    assert list(kept["content"][0]) == ["z", "a", "m"]
    got = sio.read_checked_json(path, "k\u00e9y", "cache entry")
    assert json.dumps(got) == json.dumps(json.loads(json.dumps(content, default=float)))


def test_an_edited_identification_is_computed_again_with_a_note(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("STEPDAMP_CACHE_DIR", str(tmp_path))
    system = protocol_motors(_tiny())[0].system
    truth = identify(system, method="iterative", noise_seed=7).model
    assert identify_cached(system, "iterative", 7) == truth
    for edit in ("scale", "failed"):
        (path,) = [tmp_path / "identify" / n for n in os.listdir(tmp_path / "identify")]
        kept = json.loads(path.read_text())
        if edit == "scale":
            kept["content"]["model"]["Kd4"] *= 1.01
        else:
            kept["content"] = {"model": None, "failed": "RuntimeError: made up"}
        path.write_text(json.dumps(kept))
        capsys.readouterr()
        assert identify_cached(system, "iterative", 7) == truth
        assert "damaged or edited" in capsys.readouterr().err


def test_an_edited_or_incomplete_resume_batch_is_run_again(tmp_path, capsys):
    protocol = _tiny()
    resume = str(tmp_path / RESUME_DIR)
    whole = run_leaderboard(protocol, ["ff-delay-comp"], workers=1, progress=False,
                            resume_dir=resume)
    names = sorted(n for n in os.listdir(resume) if not n.startswith("."))
    first = os.path.join(resume, names[0])
    kept = json.loads(open(first).read())
    kept["content"][0]["metrics"] = {k: (v * 1.5 if isinstance(v, float) else v)
                                     for k, v in kept["content"][0]["metrics"].items()}
    open(first, "w").write(json.dumps(kept))                     # edited by hand
    second = os.path.join(resume, names[1])
    kept = json.loads(open(second).read())
    del kept["content"][0]["metrics"]
    sio.write_checked_json(second, kept["key"], kept["content"])   # a consistent forgery
    capsys.readouterr()
    again = run_leaderboard(protocol, ["ff-delay-comp"], workers=1, progress=False,
                            resume_dir=resume)
    err = capsys.readouterr().err
    assert "damaged or edited" in err and "does not hold its runs" in err
    assert board_fingerprint(again) == board_fingerprint(whole)


@pytest.mark.slow
def test_report_refuses_an_edited_board_by_default(tmp_path, capsys):
    board = tmp_path / "b"
    shutil.copytree(V3_BOARD, board)
    assert main(["report", str(board)]) == 0
    capsys.readouterr()
    data = json.loads((board / "leaderboard.json").read_text())
    data["entries"][3]["headline"]["iqm"] += 0.5
    (board / "leaderboard.json").write_text(json.dumps(data))
    assert main(["report", str(board)]) == 2
    _one_line_error(capsys, "do not match its fingerprint")
    assert main(["report", str(board), "--no-verify"]) == 0


@pytest.mark.parametrize("damage", ["truncated", "not xz", "entries missing", "runs_file path"])
def test_a_damaged_runs_file_is_a_one_line_error(tmp_path, capsys, damage):
    board = tmp_path / "b"
    shutil.copytree(V3_BOARD, board)
    runs = board / "leaderboard_runs.json.xz"
    if damage == "truncated":
        runs.write_bytes(runs.read_bytes()[:5000])
    elif damage == "not xz":
        runs.write_bytes(gzip.compress(b"[]"))
    elif damage == "entries missing":
        with lzma.open(runs, "wt") as fh:
            fh.write('{"entries": []}')
    else:
        data = json.loads((board / "leaderboard.json").read_text())
        data["runs_file"] = "../../etc/passwd"
        (board / "leaderboard.json").write_text(json.dumps(data))
    assert main(["report", str(board)]) == 2
    _one_line_error(capsys, str(board))


@pytest.mark.slow
def test_published_boards_verify(capsys):
    from stepdamp_env.bench.report import load_leaderboard, verify_fingerprint

    for version in ("v0", "v2", "v3"):
        directory = os.path.join(ROOT, "docs", "results", version)
        verify_fingerprint(load_leaderboard(directory), directory)



# -- review findings: what a run finds in --out when it ends, odd files --------------------
def test_what_is_added_to_out_while_a_run_goes_on_is_kept(tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    (out / "old.json").write_text("{}")
    resume = out / RESUME_DIR
    open_resume_dir(str(resume))
    (resume / BATCH).write_text("[]")
    with sio.staged_directory(out, ["*.json"], own_dirs={RESUME_DIR: finish_resume_dir}) as stage:
        (out / "notes").mkdir()                                     # while the run goes on
        (out / "notes" / "a.txt").write_text("x")
        (resume / "my.txt").write_text("y")
        os.mkfifo(out / "pipe")
        (out / "late.txt").write_text("z")
        sio.write_json(os.path.join(stage, "new.json"), {})
    assert sorted(os.listdir(out)) == [RESUME_DIR, "late.txt", "new.json", "notes", "pipe"]
    assert os.listdir(resume) == ["my.txt"]                          # the batch and marker gone
    assert (out / "notes" / "a.txt").read_text() == "x"
    assert [n for n in os.listdir(tmp_path) if n != "out"] == []


def test_a_finished_leaderboard_removes_its_resume_dir(tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    open_resume_dir(str(out / RESUME_DIR))
    (out / RESUME_DIR / BATCH).write_text("[]")
    with sio.staged_directory(out, ["*.json"], own_dirs={RESUME_DIR: finish_resume_dir}):
        pass
    assert os.listdir(out) == []


def test_out_through_a_link_and_dotdot_is_the_directory_the_system_means(tmp_path):
    (tmp_path / "L" / "important").mkdir(parents=True)
    (tmp_path / "L" / "important" / "data.txt").write_text("p")
    (tmp_path / "A").mkdir()
    (tmp_path / "A" / "f.txt").write_text("f")
    os.symlink(tmp_path / "A" / "f.txt", tmp_path / "L" / "link")
    real = sio.check_output_dir(str(tmp_path / "L" / "link" / ".."), "--out")
    assert real == str(tmp_path / "A")                 # where the system goes, not L
    with sio.staged_directory(real, ["*.json"]):
        pass
    assert (tmp_path / "L" / "important" / "data.txt").read_text() == "p"
    assert os.listdir(tmp_path / "A") == ["f.txt"]
    os.symlink(tmp_path / "A", tmp_path / "linkdir")
    assert sio.check_output_dir(str(tmp_path / "linkdir") + "/.", "--out") == str(tmp_path / "A")


def test_a_previous_result_left_aside_by_a_killed_swap_is_put_back(tmp_path):
    aside = tmp_path / ".out.previous-999999999"
    aside.mkdir()
    (aside / "leaderboard.json").write_text("{}")
    (aside / "user.txt").write_text("p")
    assert sio.check_output_dir(str(tmp_path / "out"), "--out") == str(tmp_path / "out")
    assert sorted(os.listdir(tmp_path / "out")) == ["leaderboard.json", "user.txt"]


@pytest.mark.parametrize("kind", ["fifo", "hard link", "directory"])
def test_a_lock_file_that_is_not_a_plain_file_of_its_own_is_refused(tmp_path, kind):
    out = tmp_path / "out"
    out.mkdir()
    victim = tmp_path / "victim"
    victim.write_text("keep")
    lock = out / ".stepdamp.lock"
    if kind == "fifo":
        os.mkfifo(lock)
    elif kind == "hard link":
        os.link(victim, lock)
    else:
        lock.mkdir()
    with pytest.raises(ParameterError, match="lock file"):
        with sio.output_lock(out, "--out"):
            pass
    assert victim.read_text() == "keep"


@pytest.mark.parametrize("what", ["fifo", "/dev/zero"])
def test_a_pipe_or_device_is_refused_not_read(tmp_path, what):
    path = tmp_path / "x.json"
    if what == "fifo":
        os.mkfifo(path)
    else:
        os.symlink("/dev/zero", path)
    with pytest.raises(ParameterError, match="not a regular file"):
        sio.read_json(path, "motor file")
    assert sio.read_json_or_none(path) is None
    from stepdamp_env.drivelog import read_trace

    with pytest.raises(ParameterError, match="not a regular file"):
        read_trace(str(path))


def test_an_integer_of_thousands_of_digits_is_a_one_line_error(tmp_path):
    path = tmp_path / "m.json"
    path.write_text('{"Km": ' + "9" * 5000 + "}")
    with pytest.raises(ParameterError, match="not valid JSON"):
        sio.read_json(path, "motor file")
    assert sio.read_json_or_none(path) is None


def test_a_board_without_its_fingerprint_or_protocol_is_refused(tmp_path, capsys):
    board = tmp_path / "b"
    shutil.copytree(V3_BOARD, board)
    data = json.loads((board / "leaderboard.json").read_text())
    del data["fingerprint"]
    (board / "leaderboard.json").write_text(json.dumps(data))
    assert main(["report", str(board)]) == 2
    _one_line_error(capsys, "no fingerprint")
    data["protocol"] = "x"
    (board / "leaderboard.json").write_text(json.dumps(data))
    assert main(["report", str(board), "--no-verify"]) == 2
    _one_line_error(capsys, "not a leaderboard")


def test_list_files_nest_and_list_within_bounds(tmp_path, capsys):
    for k in range(LIMITS.list_file_depth + 1):
        (tmp_path / f"l{k}.json").write_text(json.dumps([str(tmp_path / f"l{k + 1}.json")] * 2))
    (tmp_path / f"l{LIMITS.list_file_depth + 1}.json").write_text('["patent"]')
    assert main(["motors", str(tmp_path / "l0.json")]) == 2
    _one_line_error(capsys, "list files naming list files")
    (tmp_path / "many.json").write_text(json.dumps(["patent"] * (LIMITS.custom_motors + 1)))
    assert main(["motors", str(tmp_path / "many.json")]) == 2
    _one_line_error(capsys, "allowed 1 to")


def test_a_resume_dir_whose_marker_went_is_moved_across_not_emptied(tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    open_resume_dir(str(out / RESUME_DIR))
    with sio.staged_directory(out, ["*.json"], own_dirs={RESUME_DIR: finish_resume_dir}):
        os.remove(out / RESUME_DIR / ".stepdamp-resume")             # while the run goes on
        (out / RESUME_DIR / "mine.txt").write_text("m")
    assert os.listdir(out / RESUME_DIR) == ["mine.txt"]
    assert os.listdir(tmp_path) == ["out"]
