"""stepdamp-bench: the protocol, the policy contract, the runner, the statistics, the report.

============  ================================================================
module        what it holds
============  ================================================================
suites        the suites, one ``Suite`` record each (mode, drive, headline
              rule, reference, training task)
protocol      the protocol contract (``Protocol``: what every version says)
              and the settings all versions share
protocols     the versions, one module each (its docstring is its spec):
              ``v0``, ``v1`` (splits, servo grid, settling, ``--motors``
              files), ``v2`` (the mid-band suite), ``v3`` (dB, reference
              rows, dev split), ``v4`` (paired ranks, seeds,
              per-cell eligibility, catalogue split, moves), ``v5`` (the
              default: v4 with the board's envelope as the bound);
              ``protocol_for`` by name
              (``full_protocol``/``quick_protocol`` are v0's, frozen)
motors        ``ProtocolMotor`` and what the versions share to draw motors
policy        the policy contract: ``Policy`` (and ``BatchPolicy``, one
              policy for many runs; ``RowPolicy``, a law written once on
              rows), ``PolicyContext``, ``MotorKnowledge``, estimate
              resolution, the fair env options
registry      registered policies (filled by ``stepdamp_baselines`` and
              ``stepdamp_agents`` through the ``stepdamp.policies`` entry
              points), policy specs -> fresh instances
runner        ``run_episode`` (one episode, scalar env) and ``run_episodes``
              (many, one compiled call per step; the same results)
stats         interquartile mean, stratified (v0) and two-level (v1)
              bootstrap intervals, probability of improvement
scoring       per-cell scores, a leaderboard entry (v0, v1)
leaderboard   ``run_leaderboard``: all of the above in batches on a process
              pool (or Ray), resumable (``resume``), warmed up (``warmup``)
report        the board's files; ``tables`` (LEADERBOARD.md) and ``figures``
============  ================================================================
"""

from .leaderboard import run_leaderboard
from .motors import ProtocolMotor, protocol_motors, speed_grid
from .policy import (BatchPolicy, MotorKnowledge, Policy, PolicyContext, RowPolicy,
                     ScalarPolicies, ZeroAction, policy_context, policy_env_options,
                     resolve_estimate)
from .protocol import (POLICY_OPTIONS, PROTOCOL_NAME, REFERENCE_POLICY, SUITES,
                       TRAINING_SEED_LIMIT, Protocol)
from .protocols import DEFAULT_VERSION, protocol_for, protocol_versions, register_protocol
from .protocols.v0 import ProtocolV0, full_protocol, quick_protocol
from .protocols.v1 import SPLITS, ProtocolV1, full_protocol_v1, load_motors_file, quick_protocol_v1
from .protocols.v2 import ProtocolV2, full_protocol_v2, quick_protocol_v2
from .protocols.v3 import ProtocolV3, full_protocol_v3, quick_protocol_v3
from .protocols.v4 import ProtocolV4, full_protocol_v4, quick_protocol_v4
from .protocols.v5 import ProtocolV5, full_protocol_v5, quick_protocol_v5
from .registry import (PolicySource, default_policy_names, register_loader, register_policy,
                       registered_policies, resolve_policy)
from .report import render_markdown, write_outputs
from .runner import EpisodeResult, EpisodeSpec, run_episode, run_episodes
from .scoring import make_entry, reference_index, score_runs
from .suites import Suite, get_suite, register_suite, suite_names
from .stats import (iqm, probability_of_improvement, stratified_bootstrap_ci, summary,
                    two_level_bootstrap)

__all__ = [
    "run_leaderboard", "ProtocolMotor", "protocol_motors", "speed_grid", "MotorKnowledge",
    "Policy", "PolicyContext", "ZeroAction", "policy_context", "policy_env_options",
    "resolve_estimate", "POLICY_OPTIONS", "PROTOCOL_NAME", "ProtocolV0",
    "protocol_versions", "register_protocol",
    "REFERENCE_POLICY", "SUITES", "TRAINING_SEED_LIMIT", "Protocol", "full_protocol",
    "quick_protocol", "PolicySource", "default_policy_names", "register_loader",
    "register_policy", "registered_policies", "resolve_policy", "render_markdown",
    "write_outputs", "EpisodeResult", "run_episode", "make_entry", "reference_index",
    "score_runs", "iqm", "stratified_bootstrap_ci", "summary", "SPLITS", "ProtocolV1",
    "full_protocol_v1", "quick_protocol_v1", "load_motors_file", "protocol_for",
    "ProtocolV2", "full_protocol_v2", "quick_protocol_v2",
    "probability_of_improvement", "two_level_bootstrap", "BatchPolicy", "ScalarPolicies",
    "EpisodeSpec", "run_episodes", "RowPolicy", "DEFAULT_VERSION", "ProtocolV3",
    "full_protocol_v3", "quick_protocol_v3", "ProtocolV4", "full_protocol_v4",
    "quick_protocol_v4", "ProtocolV5", "full_protocol_v5", "quick_protocol_v5", "Suite", "get_suite", "register_suite",
    "suite_names",
]
