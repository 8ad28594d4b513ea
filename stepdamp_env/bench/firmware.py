"""Firmware out: a damping law's tables and gains, as JSON or as C99 (issue #34, point 6).

A :class:`FirmwareLaw` describes what an entry's drive adds to its q-current
command at one operating point (motor, mode, held command speed), in the terms
the kernel (:mod:`stepdamp_env.kernel`) applies it::

    iq(x, e_w, w_cmd) = sum_h A_h * sin(h*x + phi_h)            harmonic table, h = 1, 2, 4
                      + F * sign(w_cmd)                           servo only: friction feedforward
                      + clip(Kv * e_w + Kp * hp(e_theta), -I_max, I_max)   feedback (if any)

* ``x``: the electrical angle of the drive's Park transform (rad), Nr times the
  shaft angle: in open loop Nr times the microstep-quantised command angle, in
  servo Nr times (the encoder angle + half a count), as the kernel takes it;
* ``e_w = w_cmd - w_est``: the command speed minus the drive's own speed
  estimate (shaft rad/s), positive while the rotor lags;
* ``e_theta = theta_cmd - theta_encoder``: the position error (shaft rad) and
  ``hp`` the kernel's first-order high-pass of it, one state ``e_lp`` kept
  from period to period: ``e_lp += alpha * (e_theta - e_lp)``, ``hp = e_theta
  - e_lp`` (``alpha`` = ``position_highpass_alpha``; the term only where
  ``Kp`` = ``position_gain_a_per_rad`` is not 0: laws of format /2);
* the result is in A; positive q current gives positive torque (the positive
  direction of rotation). ``A_h`` is the q-current amplitude (A): the detent
  torque amplitude (N*m) the feedforward cancels divided by the torque constant
  ``km_nm_per_a`` of the model it uses.

The harmonic table holds for the held command speed it was exported at
(``speed_rps``): a delay-compensated table leads by the current path's phase at
that speed (:func:`stepdamp_env.response.torque_paths`), as the benchmark's
entries compute it once per run. :func:`correction` is the Python reference,
:func:`microstep_table` the angle part at each microstep of one electrical
period (for table-driven drivers), :func:`c_source` a C99 header and source
with one function that computes the same to rounding, :func:`export_law` writes
either format.

Entries describe themselves: a policy with a ``firmware_law(context:
PolicyContext) -> FirmwareLaw`` method (duck-typed; the baselines build theirs
with :func:`harmonic_law`) can be exported; :class:`~.policy.ZeroAction` (the
``patent-ff-*`` entries) is handled here. :func:`entry_law` turns an entry name
and a :class:`~.policy.MotorKnowledge` (:func:`firmware_knowledge` for a motor
file) into its law, or a one-line ``ParameterError`` saying why it cannot be
exported (learned agents, laws that change while they run, oracles). A law's
state is the caller's: the high-pass of ``tuned-gain-pair``'s position term,
or the filters of a :class:`FilteredFeedback` (``velocity-feedback``,
``sensorless-damping``: a current computed every agent step from low-passed
signals and held in between, format /3; :func:`filtered_feedback_currents`
is its reference).

The law's definition, reference and JSON live in :mod:`.firmware_law`, its C in
:mod:`.firmware_c`; this module re-exports them and builds laws from entries.
"""


from __future__ import annotations

import math
import os
from typing import Any, Sequence

import numpy as np

from .. import fixedmath as fm
from ..analysis import bridge_limit_rps
from ..params import DETENT_HARMONICS, FeedforwardModel, ParameterError, SystemParams
from ..simulation import DEFAULT_ACCEL_RPS2, MODES
from .firmware_c import FORMATS, c_source, default_prefix, write_law_files
from .firmware_net import FirmwareNetwork, export_network
from .firmware_online import KalmanTable, OnlineTableLaw, RepetitiveTable
from .firmware_online_c import export_online
from .firmware_law import (FORMAT_ID, FilteredFeedback, FirmwareLaw, correction,
                           filtered_feedback_currents, from_json, microstep_table,
                           position_lowpass, to_json)
from .policy import (MotorKnowledge, PolicyContext, ZeroAction, estimate_model, policy_card,
                     policy_context, policy_env_options)
from .registry import resolve_policy
from .rig import CalibrationRig

__all__ = ["FirmwareLaw", "FilteredFeedback", "FORMATS", "FORMAT_ID", "correction",
           "microstep_table", "to_json", "from_json", "c_source", "export_law",
           "position_lowpass", "filtered_feedback_currents", "default_prefix",
           "harmonic_law", "firmware_knowledge", "default_speed_rps", "policy_law", "entry_law",
           "FirmwareNetwork", "export_network", "policy_export", "entry_export",
           "export_modes", "export_kind", "KalmanTable", "RepetitiveTable", "OnlineTableLaw",
           "export_online", "export_any", "HOOKS"]

#: An entry's export hooks, tried in this order: (hook, what it returns, the kind
#: :func:`export_kind` names): a learned entry's network, an online table (one
#: that adapts while it runs), a fixed law.
HOOKS = (("firmware_network", FirmwareNetwork, "network"),
         ("firmware_online", OnlineTableLaw, "online table"),
         ("firmware_law", FirmwareLaw, "law"))


def export_law(law: FirmwareLaw, fmt: str, out_dir: str | os.PathLike[str],
               prefix: str | None = None) -> list[str]:
    """Write the law into ``out_dir`` (made if needed), each file atomically:
    ``<prefix>.json`` (fmt "json", :func:`to_json`) or ``<prefix>.h`` and
    ``<prefix>.c`` (fmt "c", :func:`c_source`). ``prefix`` defaults to
    :func:`default_prefix` of the entry. Returns the paths written."""
    return write_law_files(fmt, out_dir, default_prefix(law.entry) if prefix is None else prefix,
                           lambda: to_json(law), lambda p: c_source(law, p))


def harmonic_law(context: PolicyContext, entry: str, coefficients_nm: Sequence[float],
                 model: FeedforwardModel, *, velocity_gain_a_s_per_rad: float = 0.0,
                 feedback_limit_a: float = math.inf, velocity_estimator: str = "",
                 notes: str = "", position_gain_a_per_rad: float = 0.0,
                 position_highpass_alpha: float = 0.0,
                 filtered_feedback: FilteredFeedback | None = None) -> FirmwareLaw:
    """The law of a drive whose base controller is the patent feedforward with
    ``model`` (its Km divides the torque; in servo its Fs is fed forward with the
    command's sign, as the kernel does), applying the torque coefficients
    ``coefficients_nm`` (N*m, (s1, c1, s2, c2, s4, c4): s_h sin(h x) + c_h cos(h x)),
    plus an optional velocity and high-passed position feedback per PWM period, or
    a filtered feedback held over agent steps, at ``context``'s mode and held
    speed on its knowledge's nominal drive."""
    c = [float(v) for v in coefficients_nm]
    if len(c) != 2 * len(DETENT_HARMONICS):
        raise ParameterError(f"coefficients_nm must hold {2 * len(DETENT_HARMONICS)} numbers "
                             f"(s, c per harmonic {list(DETENT_HARMONICS)}), got {len(c)}")
    system = context.knowledge.nominal
    inv_km = 1.0 / model.Km
    return FirmwareLaw(
        entry=entry, motor=system.name, mode=context.mode, speed_rps=float(context.speed_rps),
        pwm_hz=system.drive.pwm_hz, nr=system.motor.Nr, microsteps=system.drive.microsteps,
        km_nm_per_a=model.Km, harmonics=tuple(DETENT_HARMONICS),
        # s sin(hx) + c cos(hx) = hypot(s, c) * sin(hx + atan2(c, s))
        amplitude_a=tuple(fm.hypot(c[2 * i], c[2 * i + 1]) * inv_km
                          for i in range(len(DETENT_HARMONICS))),
        phase_rad=tuple(fm.atan2(c[2 * i + 1], c[2 * i]) for i in range(len(DETENT_HARMONICS))),
        friction_a=model.Fs * inv_km if context.mode == "servo" else 0.0,
        velocity_gain_a_s_per_rad=velocity_gain_a_s_per_rad, feedback_limit_a=feedback_limit_a,
        velocity_estimator=velocity_estimator, notes=notes,
        position_gain_a_per_rad=position_gain_a_per_rad,
        position_highpass_alpha=position_highpass_alpha, filtered_feedback=filtered_feedback)


def firmware_knowledge(system: SystemParams, identified: FeedforwardModel | None = None, *,
                       rig_seed: int = 0, accel_rps2: float = DEFAULT_ACCEL_RPS2
                       ) -> MotorKnowledge:
    """What a drive exported for the motor ``system`` knows: ``system`` is its
    datasheet (nominal) model; the identified detent model is ``identified``, by
    default the system's own (a motor file written by ``stepdamp identify`` holds
    the identified model); entries that calibrate get a rig on ``system``
    (:class:`~.rig.CalibrationRig`). No true plant: oracles cannot be exported."""
    exact = FeedforwardModel.from_motor(system.motor)
    return MotorKnowledge(nominal=system, identified=exact if identified is None else identified,
                          exact=exact, plant=None,
                          rig=CalibrationRig(system, rig_seed, accel_rps2))


def default_speed_rps(system: SystemParams) -> float:
    """The default design speed (rev/s): the motor's lowest predicted resonance,
    where the 4th detent harmonic meets the rotor's natural frequency (the
    protocol's "h4" speed)."""
    return float(system.predicted_resonances_rps()[4])


def _base_controller_law(policy: ZeroAction, context: PolicyContext) -> FirmwareLaw:
    """The ``patent-ff-*`` entries: the base controller's feedforward alone."""
    if policy.base_controller == "none":
        raise ParameterError(f"entry {policy.name!r} cannot be exported: it adds no correction "
                             "(the base controller without feedforward)")
    model = estimate_model(policy.estimate, context.knowledge)
    return harmonic_law(context, policy.name, model.coefficients(), model,
                        notes=f"The patent's harmonic feedforward (US 7,733,051, eq. 8) with "
                              f"the {policy.estimate} detent model: iq = detent torque model "
                              "/ Km, sent without delay compensation.")


def export_modes(policy: Any) -> tuple[str, ...]:
    """The modes ``stepdamp export`` writes something for ``policy`` in: the base
    controller's feedforward (``patent-ff-*``) in every mode, a policy with one
    of the :data:`HOOKS` in those its ``firmware_modes`` names (every mode where
    it names none), else none. Read from the policy, not computed (a law may
    calibrate first); ``tests/test_firmware.py`` checks it against
    :func:`entry_export` for every default entry."""
    if isinstance(policy, ZeroAction):
        return tuple(MODES) if policy.base_controller != "none" else ()
    if any(callable(getattr(policy, hook, None)) for hook, _, _ in HOOKS):
        declared = getattr(policy, "firmware_modes", tuple(MODES))
        return tuple(m for m in MODES if m in declared)
    return ()


def export_kind(policy: Any) -> str:
    """What ``stepdamp export`` writes for ``policy`` where :func:`export_modes`
    is not empty: "network" (a learned entry's policy network), "online table"
    (a harmonic table that adapts while it runs) or "law" (fixed)."""
    return next((kind for hook, _, kind in HOOKS if callable(getattr(policy, hook, None))),
                "law")


def _checked_speed(knowledge: MotorKnowledge, mode: str, speed_rps: float | None) -> float:
    """The held command speed an export is computed at (rev/s), checked."""
    if mode not in MODES:
        raise ParameterError(f"mode={mode!r} is not one of {list(MODES)}")
    speed = default_speed_rps(knowledge.nominal) if speed_rps is None else speed_rps
    if isinstance(speed, bool) or not isinstance(speed, (int, float, np.integer, np.floating)) \
            or not (math.isfinite(speed) and speed > 0.0):
        raise ParameterError(f"speed_rps={speed!r} is outside its allowed range (0, inf) rev/s")
    top = bridge_limit_rps(knowledge.nominal)
    if speed > top:
        # Past it the drive cannot push the current: a law there is never run.
        raise ParameterError(f"speed_rps={speed:g} is above the top speed of "
                             f"{knowledge.nominal.name!r} on its bus ({top:.4g} rev/s, the "
                             f"bridge circle Vdc/sqrt(2)); allowed: (0, {top:.4g}] rev/s")
    return float(speed)


def _call_hook(policy: Any, name: str, knowledge: MotorKnowledge, mode: str, speed: float,
               build: Any) -> Any:
    """``build(context)`` with the context the benchmark's runner gives ``policy``;
    a failure for want of knowledge is a one-line ``ParameterError`` naming it."""
    try:
        options = policy_env_options(policy, knowledge)
        return build(policy_context(options, knowledge, mode, speed))
    except ParameterError:
        raise
    except ValueError as exc:       # e.g. a model or rig the knowledge lacks
        first = (str(exc).strip().splitlines() or [""])[0]
        raise ParameterError(f"entry {name!r} cannot be exported: {first}") from None


def policy_law(policy: Any, knowledge: MotorKnowledge, *, mode: str = "open-loop",
               speed_rps: float | None = None) -> FirmwareLaw:
    """The law ``policy`` applies on the drive of ``knowledge`` in ``mode`` at the
    held command speed ``speed_rps`` (rev/s; default :func:`default_speed_rps` of
    the nominal motor): its ``firmware_law(context)`` with the context the
    benchmark's runner gives it, or a one-line ``ParameterError`` naming it and
    saying why it cannot be exported (a network or an online table is
    :func:`policy_export`'s)."""
    name = str(getattr(policy, "name", policy))
    speed = _checked_speed(knowledge, mode, speed_rps)
    hook = getattr(policy, "firmware_law", None)
    if not isinstance(policy, ZeroAction) and not callable(hook):
        card = policy_card(policy)
        network = ("export writes its network instead" if callable(
            getattr(policy, "firmware_network", None)) else
            "and it has no firmware_network that export could write")
        why = ("it is a learned agent: its action comes from a network at run time, not "
               f"from a fixed table and gains ({network})"
               if card is not None and card.learned else
               "it is an oracle: it reads what no drive has" if card is not None and card.oracle
               else "it has no firmware_law: its law is not a fixed table and gains")
        raise ParameterError(f"entry {name!r} cannot be exported: {why}")
    law = _call_hook(policy, name, knowledge, mode, speed,
                     lambda context: _base_controller_law(policy, context)
                     if isinstance(policy, ZeroAction) else hook(context))
    if not isinstance(law, FirmwareLaw):
        raise ParameterError(f"entry {name!r}: firmware_law returned {type(law).__name__}, "
                             "not a FirmwareLaw")
    return law


def policy_export(policy: Any, knowledge: MotorKnowledge, *, mode: str = "open-loop",
                  speed_rps: float | None = None
                  ) -> FirmwareLaw | FirmwareNetwork | OnlineTableLaw:
    """What ``export`` writes for ``policy``: a learned entry's network (its
    ``firmware_network(context)``, :mod:`.firmware_net`), an online table (its
    ``firmware_online(context)``, :mod:`.firmware_online`), else
    :func:`policy_law`."""
    for hook_name, kind, _ in HOOKS[:-1]:
        hook = getattr(policy, hook_name, None)
        if not callable(hook):
            continue
        name = str(getattr(policy, "name", policy))
        modes = export_modes(policy)
        if mode in MODES and mode not in modes:
            raise ParameterError(f"entry {name!r} cannot be exported in {mode}: it runs in "
                                 f"{' and '.join(modes) or 'no mode'} only")
        out = _call_hook(policy, name, knowledge, mode,
                         _checked_speed(knowledge, mode, speed_rps), hook)
        if not isinstance(out, kind):
            raise ParameterError(f"entry {name!r}: {hook_name} returned {type(out).__name__}, "
                                 f"not a {kind.__name__}")
        return out
    return policy_law(policy, knowledge, mode=mode, speed_rps=speed_rps)


def export_any(export: FirmwareLaw | FirmwareNetwork | OnlineTableLaw, fmt: str,
               out_dir: str | os.PathLike[str], prefix: str | None = None) -> list[str]:
    """Write what :func:`policy_export` returned (:func:`export_law`,
    :func:`export_network` or :func:`export_online`); the paths written."""
    if isinstance(export, FirmwareNetwork):
        return export_network(export, fmt, os.fspath(out_dir), prefix)
    if isinstance(export, OnlineTableLaw):
        return export_online(export, fmt, os.fspath(out_dir), prefix)
    return export_law(export, fmt, out_dir, prefix)


def entry_law(entry: str, knowledge: MotorKnowledge, *, mode: str = "open-loop",
              speed_rps: float | None = None) -> FirmwareLaw:
    """:func:`policy_law` of a fresh instance of the entry ``entry`` (a registered
    name or any policy spec, :func:`~.registry.resolve_policy`)."""
    return policy_law(resolve_policy(entry).make(), knowledge, mode=mode, speed_rps=speed_rps)


def entry_export(entry: str, knowledge: MotorKnowledge, *, mode: str = "open-loop",
                 speed_rps: float | None = None
                 ) -> FirmwareLaw | FirmwareNetwork | OnlineTableLaw:
    """:func:`policy_export` of a fresh instance of the entry ``entry``."""
    return policy_export(resolve_policy(entry).make(), knowledge, mode=mode,
                         speed_rps=speed_rps)
