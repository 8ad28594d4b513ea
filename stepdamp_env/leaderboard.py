"""Compatibility module: the leaderboard lives in :mod:`stepdamp_env.bench`.

The ``stepdamp-bench v0`` specification is the docstring of
:mod:`stepdamp_env.bench.protocol`, v1's that of :mod:`stepdamp_env.bench.protocol_v1`.
"""

from .bench import (POLICY_OPTIONS, PROTOCOL_NAME, PROTOCOL_VERSION, SUITES,
                    TRAINING_SEED_LIMIT, PolicySource, Protocol, ProtocolMotor,
                    default_policy_names, full_protocol, iqm, policy_context,
                    policy_env_options, protocol_motors, quick_protocol, render_markdown,
                    resolve_policy, run_leaderboard, speed_grid, stratified_bootstrap_ci,
                    write_outputs)
from .bench.protocol import FAILURE_RATIO
from .bench.registry import SB3Policy
from .bench.report import plot_resonance_traces, plot_ripple, trace_run

__all__ = ["POLICY_OPTIONS", "PROTOCOL_NAME", "PROTOCOL_VERSION", "SUITES",
           "TRAINING_SEED_LIMIT", "FAILURE_RATIO", "PolicySource", "Protocol", "ProtocolMotor",
           "SB3Policy", "default_policy_names", "full_protocol", "iqm", "policy_context",
           "policy_env_options", "protocol_motors", "quick_protocol", "render_markdown",
           "resolve_policy", "run_leaderboard", "speed_grid", "stratified_bootstrap_ci",
           "write_outputs", "plot_resonance_traces", "plot_ripple", "trace_run"]
