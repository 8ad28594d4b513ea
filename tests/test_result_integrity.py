"""Result integrity: every kept result is keyed on the content it stands for, read
when it is used (docs/caches.md lists each cache, its key and when it is read)."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from stepdamp_agents import reference_seeds
from stepdamp_agents.policy import clear_model_cache, load_model
from stepdamp_env.bench import protocol_motors, quick_protocol_v1
from stepdamp_env.bench.leaderboard import RESUME_DIR, run_leaderboard
from stepdamp_env.bench.protocols.v1 import load_motors_file
from stepdamp_env.bench.registry import resolve_policy
from stepdamp_env.io import related_files, tree_digest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
POLICY_SOURCE = os.path.join(ROOT, "tests", "leaderboard_policy.py")
ODD = "odd dir.ü"          # a dot, a space and a non-ASCII letter

def _kept(resume: str) -> list[str]:
    """The batch files in a resume directory (its hidden marker left out)."""
    return sorted(n for n in os.listdir(resume) if not n.startswith("."))


def _tiny():
    protocol = quick_protocol_v1()
    motors = protocol_motors(protocol)
    return protocol.with_custom_motors([motors[0].system]).with_suites(("open-loop",))


def _policy_file(folder) -> str:
    os.makedirs(folder, exist_ok=True)
    path = os.path.join(folder, "my_policy.py")
    shutil.copyfile(POLICY_SOURCE, path)
    return path


def _model_files(folder) -> list[str]:
    """A reference model as ``stepdamp train`` writes one: best.zip, best.agent.json."""
    os.makedirs(folder, exist_ok=True)
    src = reference_seeds("ars-per-step-25hz")[1]
    shutil.copyfile(src, os.path.join(folder, "best.zip"))
    shutil.copyfile(src[:-len(".zip")] + ".agent.json", os.path.join(folder, "best.agent.json"))
    return [os.path.join(folder, "best.zip"), os.path.join(folder, "best.agent.json")]


def _flip(path: str, position: float, mask: int) -> None:
    data = bytearray(open(path, "rb").read())
    data[int(position * (len(data) - 1))] ^= mask
    with open(path, "wb") as fh:
        fh.write(bytes(data))


def test_a_dotted_parent_folder_is_not_the_policys_stem(tmp_path):
    """The bug: the stem was cut at the first dot of the whole path, so the key
    hashed whatever in the parent started with "dot." instead of the file."""
    path = _policy_file(tmp_path / "dot.test" / "t")
    other = tmp_path / "dot.other"
    other.mkdir()
    (other / "big.bin").write_bytes(b"x" * 1000)
    source = resolve_policy(f"{path}:NominalFeedforward")
    before = source.fingerprint()
    (other / "big.bin").write_bytes(b"y" * 1000)
    assert source.fingerprint() == before
    assert related_files(path) == [path]
    side = os.path.join(os.path.dirname(path), "my_policy.json")
    with open(side, "w") as fh:
        fh.write("{}")
    assert source.fingerprint() != before
    assert related_files(path) == sorted([path, side])


@settings(max_examples=60, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(which=st.sampled_from(["policy", "policy side file", "model", "model side file"]),
       position=st.floats(0.0, 1.0), mask=st.integers(1, 255))
def test_changing_any_byte_of_a_file_an_entry_stands_for_changes_its_key(tmp_path_factory, which,
                                                                        position, mask):
    base = tmp_path_factory.mktemp(ODD)
    policy = _policy_file(base / "pol")
    with open(base / "pol" / "my_policy.json", "w") as fh:
        fh.write('{"note": "a side file"}')
    model, model_side = _model_files(base / "runs" / "seed1")
    spec = {"policy": f"{policy}:NominalFeedforward", "policy side file": f"{policy}:NominalFeedforward",
            "model": model, "model side file": model}[which]
    target = {"policy": policy, "policy side file": str(base / "pol" / "my_policy.json"),
              "model": model, "model side file": model_side}[which]
    source = resolve_policy(spec)
    before = source.fingerprint()
    assert source.fingerprint() == before              # nothing changed: the same key
    _flip(target, position, mask)
    assert source.fingerprint() != before              # in this process, read anew


@pytest.mark.slow
def test_the_key_is_the_same_in_another_process_and_follows_the_file(tmp_path):
    policy = _policy_file(tmp_path / ODD)
    spec = f"{policy}:NominalFeedforward"
    code = ("import sys; from stepdamp_env.bench.registry import resolve_policy; "
            "print(resolve_policy(sys.argv[1]).fingerprint())")

    def other_process() -> str:
        return subprocess.run([sys.executable, "-c", code, spec], check=True,
                              capture_output=True, text=True).stdout.strip()

    assert other_process() == resolve_policy(spec).fingerprint()
    before = other_process()
    with open(policy, "a") as fh:
        fh.write("# changed\n")
    assert other_process() != before


def test_a_model_rewritten_in_place_is_loaded_again(tmp_path):
    """SB3 models are kept per process by the sha256 of their bytes, not by path."""
    clear_model_cache()
    path = _model_files(tmp_path)[0]
    first = load_model(path)
    assert load_model(path) is first
    shutil.copyfile(reference_seeds("ars-per-step-25hz")[2], path)
    second = load_model(path)
    assert second is not first
    w1 = [p.detach().numpy().copy() for p in first.policy.parameters()]
    w2 = [p.detach().numpy().copy() for p in second.policy.parameters()]
    assert any((a != b).any() for a, b in zip(w1, w2))


@settings(max_examples=25, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(field=st.sampled_from(["Kd1", "Kd2", "Kd4", "J", "Km", "R", "L", "holding_current"]),
       factor=st.floats(0.5, 1.5).filter(lambda f: f != 1.0))
def test_a_changed_motor_file_is_a_new_key(tmp_path_factory, field, factor):
    """Motor files are keyed on the motors they describe (the resume header holds
    them): a changed value is a new key; a change of layout alone is not, and
    rightly so, since the runs would be the same."""
    base = tmp_path_factory.mktemp(ODD)
    motor = protocol_motors(_tiny())[0].system.to_dict()
    path = base / "motors.json"

    def header(m):
        path.write_text(json.dumps([m]))
        protocol = quick_protocol_v1()
        protocol = protocol.with_custom_motors(load_motors_file(str(path), protocol))
        return json.dumps([m.to_dict() for m in protocol_motors(protocol)], sort_keys=True)

    before = header(motor)
    path.write_text(json.dumps([motor], indent=4))
    protocol = quick_protocol_v1()
    same = json.dumps([m.to_dict() for m in protocol_motors(protocol.with_custom_motors(
        load_motors_file(str(path), protocol)))], sort_keys=True)
    assert same == before
    assert header({**motor, field: motor[field] * factor}) != before


@pytest.mark.parametrize("kind", ["policy file", "directory of trained models"])
def test_a_result_directory_inside_the_policys_folder_still_resumes(tmp_path, capsys, kind):
    folder = tmp_path / ODD / "work"
    if kind == "policy file":
        spec = f"{_policy_file(folder)}:NominalFeedforward"
    else:
        _model_files(folder / "seed1")
        spec = str(folder)
    resume = str(folder / "board" / RESUME_DIR)
    first = run_leaderboard(_tiny(), [spec], workers=1, progress=False, resume_dir=resume)
    kept = sorted(_kept(resume))
    capsys.readouterr()
    second = run_leaderboard(_tiny(), [spec], workers=1, progress=False, resume_dir=resume)
    err = capsys.readouterr().err
    assert "resuming: " in err and f"{len(kept)} of {len(kept)} batches" in err
    assert sorted(_kept(resume)) == kept
    assert json.dumps(first["entries"]) == json.dumps(second["entries"])


_RUN_TINY = """
import sys
sys.path.insert(0, {tests!r})
from test_result_integrity import _tiny
from stepdamp_env.bench.leaderboard import run_leaderboard
run_leaderboard(_tiny(), [sys.argv[1]], workers=1, progress=False, resume_dir=sys.argv[2])
"""


def test_kept_batches_are_not_reused_after_any_change_in_process_or_not(tmp_path):
    """In this process (a notebook, the API) and in a new one (the CLI)."""
    folder = tmp_path / ODD
    policy = _policy_file(folder)
    spec = f"{policy}:NominalFeedforward"
    resume = str(folder / "board" / RESUME_DIR)
    run_leaderboard(_tiny(), [spec], workers=1, progress=False, resume_dir=resume)
    first = set(_kept(resume))
    _flip(policy, 0.99, 0x01)       # the last byte: a newline becomes a tab or so
    run_leaderboard(_tiny(), [spec], workers=1, progress=False, resume_dir=resume)
    second = set(_kept(resume))
    assert first and second and not first & second

    def other_process() -> str:
        code = _RUN_TINY.format(tests=os.path.join(ROOT, "tests"))
        out = subprocess.run([sys.executable, "-c", code, spec, resume], capture_output=True,
                             text=True, env={**os.environ, "MPLBACKEND": "Agg"})
        assert out.returncode == 0, out.stderr[-2000:]
        return out.stderr

    assert "resuming: " in other_process()              # the same file: the same key
    _flip(policy, 0.99, 0x01)
    assert "resuming" not in other_process()            # changed: nothing kept is read
    assert not second & set(_kept(resume))


def test_tree_digest_skips_the_excluded_result_directory_and_hidden_names(tmp_path):
    (tmp_path / "a.txt").write_text("a")
    (tmp_path / "out").mkdir()
    before = tree_digest(tmp_path, exclude=[tmp_path / "out"])
    (tmp_path / "out" / "leaderboard.json").write_text("{}")
    (tmp_path / ".resume").mkdir()
    (tmp_path / ".resume" / "batch.json").write_text("[]")
    assert tree_digest(tmp_path, exclude=[tmp_path / "out"]) == before
    (tmp_path / "a.txt").write_text("b")
    assert tree_digest(tmp_path, exclude=[tmp_path / "out"]) != before
