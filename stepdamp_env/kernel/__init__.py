"""Numba kernel of the drive: small njit pieces composed into one fused loop.

Everything here is a pure function of plain floats or of flat float64 arrays, so
each piece can be called and tested from Python and the fused loop
(:func:`run_periods`) can advance one drive or a batch (:func:`run_batch`) without
leaving compiled code. The arrays' layouts are declared once below
(:func:`stepdamp_env.fields.layout`): ``CONFIG`` (never changed by a step),
``STATE`` (changed by every step), ``ACC`` (accumulated metrics), ``INPUT``
(external inputs held for a call), ``LAW`` (the damping law's gains and state)
and ``TRACE`` (trace channels); ``PLANT`` and ``CTRL`` name the positions of the
parameter tuples the pieces share. :mod:`stepdamp_env.simulation` builds them.

One PWM period of length dt = 1/pwm_hz, starting at t_k = k*dt, does:

1. sample: the position command at t_k, the winding currents and the encoder;
2. control: Park angle, current commands (holding current or servo law, plus
   the harmonic feedforward and any external residual), PI current loops in DQ
   with back-calculation anti-windup, inverse Park, SVPWM legs clamped to
   [0, Vdc];
3. apply the leg voltages computed in the previous period: a real DSP samples
   at the start of a period and loads its compare registers for the next one,
   so the drive has one PWM period of computation delay on top of the
   zero-order hold of the legs over the period;
4. integrate the plant over the period with ``substeps`` RK4 steps at constant
   winding voltage (exact ZOH: voltages only change at period boundaries).

The pieces live in five modules: :mod:`.layout` (the rows), :mod:`.plant`,
:mod:`.control`, :mod:`.period` (one period, defined once for a drive's own
loop and for :mod:`stepdamp_env.lanes`) and :mod:`.loop`; every name is
importable from here.
"""

from __future__ import annotations

from .control import (command, command_in, constant_speed_command, control_step,
                      controller_params, current_command, current_command_lanes, current_loop,
                      estimate_velocity, estimate_velocity_lanes, feedforward_torque,
                      gaussian_pair, gaussian_pair_keyed, move_command, noise_key, quantise,
                      s_curve_command, s_curve_lanes, sense_currents, splitmix64, uniform_pair,
                      uniform_pair_keyed, voltage_drive, voltage_drive_lanes)
from .layout import (ACC, CONFIG, CTRL, DRIVE, INPUT, LAW, MODE, PLANT, PROFILE, STATE, TRACE,
                     TRACE_NAMES, TRACE_UNITS, VEL_EST, ControllerState, LawState, Metrics,
                     Sample)
from .loop import (merge_rows, run_batch,
                   run_batch_law, run_batch_law_parallel, run_batch_parallel, run_periods,
                   run_periods_law, step_batch, step_batch_parallel, without_law)
from .period import (accumulate, control_period, law_current, law_input, load_controller, load_law,
                     load_metrics, load_plant, resonant_phasor, store_controller, store_law,
                     store_metrics, store_plant)
from .plant import (detent_potential, detent_torque, driving_torque, driving_torque_sc,
                    electromagnetic_torque, friction_torque, harmonic_series, harmonics,
                    inverse_park, inverse_park_sc, motor_derivative, motor_derivative_sc, park,
                    park_sc, pi_output, pi_update, plant_params, plant_step, plant_step_in,
                    rk4_combine, rk4_moving, rk4_step, rk4_step_stuck, svpwm_legs)

__all__ = ["CONFIG", "DRIVE", "VEL_EST", "MODE", "PROFILE", "PLANT", "CTRL", "STATE", "ACC",
           "INPUT", "LAW", "TRACE", "TRACE_NAMES", "TRACE_UNITS", "park_sc", "inverse_park_sc",
           "park", "inverse_park", "svpwm_legs", "pi_output", "pi_update", "harmonics",
           "harmonic_series", "plant_params", "detent_torque", "detent_potential",
           "electromagnetic_torque", "friction_torque", "driving_torque", "driving_torque_sc",
           "motor_derivative_sc", "motor_derivative", "rk4_step", "rk4_combine", "plant_step",
           "rk4_step_stuck", "splitmix64", "noise_key", "uniform_pair_keyed", "uniform_pair",
           "gaussian_pair_keyed", "gaussian_pair", "quantise",
           "constant_speed_command", "move_command", "command", "controller_params",
           "feedforward_torque", "sense_currents", "estimate_velocity", "current_command",
           "voltage_drive", "current_loop", "control_step", "run_periods", "run_periods_law",
           "resonant_phasor", "law_input", "law_current", "run_batch", "run_batch_law",
           "run_batch_parallel", "run_batch_law_parallel", "merge_rows", "step_batch",
           "step_batch_parallel", "without_law", "ControllerState", "Sample", "Metrics",
           "command_in", "s_curve_command", "s_curve_lanes", "estimate_velocity_lanes",
           "current_command_lanes", "voltage_drive_lanes", "accumulate", "control_period", "load_controller",
           "store_controller", "load_plant", "store_plant", "load_metrics", "store_metrics",
           "load_law", "store_law", "LawState",
           "plant_step_in", "rk4_moving"]
