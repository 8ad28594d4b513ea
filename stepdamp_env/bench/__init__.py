"""stepdamp-bench: the protocol, the policy contract, the runner, the statistics, the report.

============  ================================================================
module        what it holds
============  ================================================================
protocol      the frozen ``stepdamp-bench v0`` spec (its docstring) and settings
motors        the protocol's motors (presets and seeded draws), speed grids
policy        the policy contract: ``Policy``, ``PolicyContext``,
              ``MotorKnowledge``, estimate resolution, the fair env options
registry      registered policies (filled by ``stepdamp_baselines`` and
              ``stepdamp_agents`` through the ``stepdamp.policies`` entry
              points), policy specs -> fresh instances
runner        ``run_episode``: the one episode loop
stats         interquartile mean, stratified bootstrap interval
scoring       per-(motor, seed) scores, a leaderboard entry
leaderboard   ``run_leaderboard``: all of the above in a process pool
report        LEADERBOARD.md and the figures
============  ================================================================
"""

from .leaderboard import run_leaderboard
from .motors import ProtocolMotor, protocol_motors, speed_grid
from .policy import (MotorKnowledge, Policy, PolicyContext, ZeroAction, policy_context,
                     policy_env_options, resolve_estimate)
from .protocol import (POLICY_OPTIONS, PROTOCOL_NAME, PROTOCOL_VERSION, REFERENCE_POLICY,
                       SUITES, TRAINING_SEED_LIMIT, Protocol, full_protocol, quick_protocol)
from .registry import (PolicySource, default_policy_names, register_loader, register_policy,
                       registered_policies, resolve_policy)
from .report import render_markdown, write_outputs
from .runner import EpisodeResult, run_episode
from .scoring import make_entry, reference_index, score_runs
from .stats import iqm, stratified_bootstrap_ci, summary

__all__ = [
    "run_leaderboard", "ProtocolMotor", "protocol_motors", "speed_grid", "MotorKnowledge",
    "Policy", "PolicyContext", "ZeroAction", "policy_context", "policy_env_options",
    "resolve_estimate", "POLICY_OPTIONS", "PROTOCOL_NAME", "PROTOCOL_VERSION",
    "REFERENCE_POLICY", "SUITES", "TRAINING_SEED_LIMIT", "Protocol", "full_protocol",
    "quick_protocol", "PolicySource", "default_policy_names", "register_loader",
    "register_policy", "registered_policies", "resolve_policy", "render_markdown",
    "write_outputs", "EpisodeResult", "run_episode", "make_entry", "reference_index",
    "score_runs", "iqm", "stratified_bootstrap_ci", "summary",
]
