"""The recipes of docs/architecture.md, followed with throw-away code as an outside
package would write it: a baseline, a suite and a protocol, each run on a
one-motor board with no other change to the package."""

from __future__ import annotations

import dataclasses
from typing import Any, ClassVar, Sequence

import numpy as np
import pytest

from stepdamp_env.bench import protocols as protocol_registry
from stepdamp_env.bench import registry as policy_registry
from stepdamp_env.bench import suites as suite_registry
from stepdamp_env.bench.leaderboard import run_leaderboard
from stepdamp_env.bench.motors import protocol_motors
from stepdamp_env.bench.policy import MotorKnowledge, PolicyCard, PolicyContext, RowPolicy
from stepdamp_env.bench.protocols.v1 import quick_protocol_v1
from stepdamp_env.bench.protocols.decibels import DecibelProtocol
from stepdamp_env.bench.protocols.v3 import ProtocolV3, quick_protocol_v3
from stepdamp_env.bench.registry import register_policy
from stepdamp_env.bench.suites import Suite, register_suite
from stepdamp_env.cli import build_parser


@pytest.fixture
def registries(monkeypatch, tmp_path):
    """Whatever a test registers is gone after it (the plugins are loaded first, so
    the registry put back is the whole one), and what it computes is kept in its
    own cache, never the machine's."""
    monkeypatch.setenv("STEPDAMP_CACHE_DIR", str(tmp_path / "cache"))
    policy_registry.registered_policies()
    monkeypatch.setattr(policy_registry, "_REGISTRY", dict(policy_registry._REGISTRY))
    monkeypatch.setattr(protocol_registry, "_REGISTRY", dict(protocol_registry._REGISTRY))
    saved = dict(suite_registry._SUITES)
    yield
    suite_registry._SUITES.clear()
    suite_registry._SUITES.update(saved)


def _as(cls, protocol, **changes):
    """``protocol``'s settings in a protocol of class ``cls``."""
    fields = {f.name: getattr(protocol, f.name) for f in dataclasses.fields(protocol) if f.init}
    return cls(**{**fields, **changes})


def _one_motor(protocol):
    motors = protocol_motors(protocol)
    return protocol.with_custom_motors([motors[0].system])


def _choices(command: str, flag: str) -> list[str]:
    sub = next(a for a in build_parser()._actions if a.dest == "command")
    return next(a.choices for a in sub.choices[command]._actions if flag in a.option_strings)


# -- a baseline: one class, one registration ----------------------------------------------
class HalfCurrent(RowPolicy):
    """A throw-away baseline: a q current of a tenth of the current scale, the same
    for every row (written once, on rows)."""

    name = "half-current"

    def env_options(self, knowledge: MotorKnowledge) -> dict[str, Any]:
        return {"base_controller": "patent-ff", "action_mode": "current",
                "estimate": knowledge.identified}

    def configure(self, context: PolicyContext) -> None:
        self.suite = context.suite

    def reset_batch(self, contexts: Sequence[PolicyContext]) -> None:
        for context in contexts:
            self.configure(context)

    def act_batch(self, observations: np.ndarray, rows: np.ndarray) -> np.ndarray:
        return np.full((len(rows), 1), 0.1, dtype=np.float32)


def test_a_new_baseline_is_one_class_and_one_registration(registries):
    register_policy("half-current", HalfCurrent, kind="baseline",
                    description="a tenth of the current scale, always")
    protocol = _one_motor(quick_protocol_v1()).with_suites(("open-loop",))
    board = run_leaderboard(protocol, ["half-current"], workers=1, progress=False)
    rows = [e for e in board["entries"] if e["name"] == "half-current"]
    assert rows and all(len(e["runs"]) > 0 for e in rows)
    assert all(r["metrics"] is not None for e in rows for r in e["runs"])
    policy = HalfCurrent()
    assert policy.act(np.zeros(12, dtype=np.float32)).tolist() == [np.float32(0.1)]


# -- a suite: one record, and a protocol that runs it -------------------------------------
@dataclasses.dataclass(frozen=True)
class ProtocolWithVoltageServo(ProtocolV3):
    """v3 plus a throw-away suite: the servo on the voltage-mode drive, at the
    servo suite's speeds and settling."""

    known_suites: ClassVar[tuple[str, ...]] = (*ProtocolV3.known_suites, "voltage-servo")

    def suite_grids(self, system):
        grids = super().suite_grids(system)
        servo = next(g for g in grids if g[0] == "servo")
        return grids + (("voltage-servo", *servo[1:]),)

    def settle_times(self, system):
        out = super().settle_times(system)
        out["voltage-servo"] = out["servo"]
        return out


def test_a_new_suite_is_one_record_and_a_protocol_that_runs_it(registries):
    register_suite(Suite("voltage-servo", "servo", "voltage",
                         "the servo on the voltage-mode drive (a throw-away suite)",
                         "the servo suite's", "the same motor without torque harmonics", "v99"))
    protocol = _as(ProtocolWithVoltageServo, quick_protocol_v3())
    protocol = _one_motor(protocol).with_suites(("voltage-servo",))
    seen: list[str | None] = []

    class SeesSuite(HalfCurrent):
        name = "sees-suite"
        card = PolicyCard(sensors="none", model="none")     # runs in every suite

        def configure(self, context: PolicyContext) -> None:
            seen.append(context.suite)

    register_policy("sees-suite", SeesSuite, kind="baseline")
    board = run_leaderboard(protocol, ["sees-suite"], workers=1, progress=False)
    assert {e["suite"] for e in board["entries"]} == {"voltage-servo"}
    assert "sees-suite" in {e["name"] for e in board["entries"]}
    assert seen and set(seen) == {"voltage-servo"}
    assert all(r["metrics"] is not None for e in board["entries"] for r in e["runs"])


# -- a protocol: one module's worth, one registration -------------------------------------
@dataclasses.dataclass(frozen=True)
class ProtocolShortWindow(DecibelProtocol):
    """A throw-away version built as the recipe says (on the shared class, not
    on another version's): v3's row with a window of half its length."""

    version: str = "v99"


def test_a_new_protocol_is_one_class_and_one_registration(registries):
    base = quick_protocol_v3()

    def quick() -> ProtocolShortWindow:
        return _as(ProtocolShortWindow, base, version="v99", window_s=base.window_s / 2)

    protocol_registry.register_protocol({"version": "v99", "full": quick, "quick": quick,
                                         "about": "v3, half its window",
                                         "quick_about": "the same"})
    assert "v99" in _choices("leaderboard", "--protocol")
    protocol = _one_motor(protocol_registry.protocol_for("v99", quick=True))
    board = run_leaderboard(protocol.with_suites(("open-loop",)), ["none"], workers=1,
                            progress=False)
    assert board["protocol"]["version"] == "v99"
    assert board["protocol"]["window_s"] == base.window_s / 2
    assert {e["name"] for e in board["entries"]} >= {"none"}


def test_a_suite_record_is_checked_and_read_only(registries):
    from stepdamp_env.bench.suites import SuiteField, get_suite
    from stepdamp_env.params import ParameterError

    for bad in (Suite("all", "servo", "voltage", "", "", "", "v9"),
                Suite("typo", "open_loop", "current", "", "", "", "v9"),
                Suite("servo-2", "servo", "current", "", "", "", "v9"),     # servo's pair
                Suite("servo", "servo", "voltage", "", "", "", "v9")):      # servo's name
        with pytest.raises(ParameterError):
            register_suite(bad)
    with pytest.raises(ParameterError, match="suite 'nope' is not one of"):
        get_suite("nope")
    with pytest.raises(ValueError, match="not a field of Suite"):
        SuiteField("colour")
    task = get_suite("mid-band").training_task
    with pytest.raises(TypeError):
        task["mode"] = "servo"                                  # read-only
    assert get_suite("mid-band").training_task["overrides"] == {"drive_mode": "voltage"}
