"""Feedforward that is learned on the motor: a calibrated table and repetitive control.

Both act in ``action_mode="harmonic"`` on the identified patent feedforward and
describe the feedforward of detent harmonic h as a phasor A_h (N*m; see
:mod:`.harmonic`). Both start from ``ff-delay-comp``'s A_h = P_h/G_h.
"""

from __future__ import annotations

import math
import os
from typing import Sequence

import numpy as np

from stepdamp_env import fixedmath as fm
from stepdamp_env.bench.firmware import RepetitiveTable
from stepdamp_env.bench.kept import KeptResults
from stepdamp_env.bench.policy import MotorKnowledge, PolicyCard, PolicyContext, estimate_model
from stepdamp_env.env.layout import HARMONIC_COS, HARMONIC_SIN, OBS
from stepdamp_env.params import DETENT_HARMONICS, ParameterError
from stepdamp_env.response import phasors, torque_paths, torque_to_velocity, velocity_filter

from .harmonic import (DelayCompensatedFF, OnlineTable, gather_rows, harmonic_action_rows,
                       harmonic_actions, online_table_fields, phasor_pairs)

__all__ = ["CalibratedTable", "RepetitiveControl", "golden_section"]

_INV_PHI = (math.sqrt(5.0) - 1.0) / 2.0


def golden_section(f, low: float, high: float, iterations: int,
                   start: float | None = None) -> float:
    """The minimiser of ``f`` on [low, high] by golden-section search
    (``iterations`` evaluations after the first two; the bracket shrinks by
    0.618 each). Returns the best point evaluated, ``start`` included if
    given: a measured objective is noisy and need not be unimodal, and a
    search must never end worse than where it began."""
    best_x, best_f = (start, f(start)) if start is not None else (None, math.inf)
    a, b = low, high
    c = b - _INV_PHI * (b - a)
    d = a + _INV_PHI * (b - a)
    fc, fd = f(c), f(d)
    seen = [(fc, c), (fd, d)]
    for _ in range(iterations):
        if fc <= fd:
            b, d, fd = d, c, fc
            c = b - _INV_PHI * (b - a)
            fc = f(c)
            seen.append((fc, c))
        else:
            a, c, fc = c, d, fd
            d = a + _INV_PHI * (b - a)
            fd = f(d)
            seen.append((fd, d))
    f_min, x_min = min(seen)
    return x_min if f_min < best_f else best_x


# One calibration per motor, drive mode and model (a drive calibrates its motor
# once); deterministic, so a cache per process (and the copy kept on disk,
# _kept_calibration) changes no number.
_TABLES: dict[tuple, tuple[np.ndarray, float]] = {}


def _kept_tables() -> KeptResults:
    """``calibrated-table``'s tables kept on disk (the code read now)."""
    return KeptResults("calibrated-table", code_root=os.path.dirname(__file__))


def _magnitude(z):
    """|z| in real arithmetic (abs of a complex goes through the C library's hypot,
    whose last bit depends on the CPU)."""
    return np.sqrt(np.real(z) * np.real(z) + np.imag(z) * np.imag(z))


class CalibratedTable(DelayCompensatedFF):
    """``calibrated-table``: a feedforward table found by measurement before the run.

    Source idea: US 5,659,234 (a test rig measures the speed ripple at a fixed
    step rate and corrects the microstep table until the ripple is least) and
    Prusa's phase stepping (at constant speed, one DFT bin per harmonic; each
    harmonic's correction tuned by golden-section search, phase first, then
    magnitude, coarse then fine). Senses nothing while it runs (a fixed table);
    calibrates on a rig (:class:`~stepdamp_env.bench.rig.CalibrationRig`: the
    same motor and drive, a noise-free reference speed sensor). Model: the
    identified one as the starting table, the nominal one to pick the speeds.

    Calibration: for h = 4, 2, 1, at the nominal model's resonant speed of
    harmonic h (where its ripple is largest), A_h = m*exp(j*phi)*A0_h with A0_h
    the ``ff-delay-comp`` value: phi by golden section on [-60, 60] degrees,
    then m on [0.5, 1.5], then both again on a bracket a quarter as wide
    (``iterations`` each); the objective is the rig's amplitude of harmonic h.
    The table is kept as the detent torque each A_h cancels (A_h times the
    current path G_h at its calibration speed) and sent at every run speed
    through that speed's G_h, as ``ff-delay-comp`` sends its model. Its
    simulated rig time is reported (``calibration_s``), not scored.
    """

    card = PolicyCard(sensors="none while running (a fixed table)",
                      model="identified (start), nominal (speeds)",
                      calibration="rig runs at the resonant speeds, golden-section search")

    def __init__(self, iterations: int = 10, window_s: float = 0.1) -> None:
        super().__init__()
        self.name = "calibrated-table"
        self.iterations = int(iterations)
        self.window_s = float(window_s)
        self.calibration_s = 0.0

    def configure(self, context: PolicyContext) -> None:
        knowledge = context.knowledge
        rig = knowledge.rig
        if rig is None:
            raise ValueError("calibrated-table needs a calibration rig (MotorKnowledge.rig)")
        model = estimate_model(self.estimate, knowledge)
        key = (rig.key, context.mode, repr(model), self.iterations, self.window_s)
        # The nominal model picks the calibration speeds: part of the key here too.
        memo = (*key, repr(knowledge.nominal))
        if memo not in _TABLES:
            _TABLES[memo] = self._kept_calibration(key, knowledge, context.mode, model)
        torque, self.calibration_s = _TABLES[memo]
        g = torque_paths(knowledge.nominal, context.mode, context.speed_rps, model)
        self._action = harmonic_actions(torque / g, phasors(model), context.action_scale)

    #: The batch's kept tables (one KeptResults per preparation: it reads the code once).
    _batch_kept: KeptResults | None = None

    def reset_batch(self, contexts: Sequence[PolicyContext]) -> None:
        outer, self._batch_kept = self._batch_kept, _kept_tables()
        try:
            super().reset_batch(contexts)
        finally:
            self._batch_kept = outer

    def _kept_calibration(self, key: tuple, knowledge: MotorKnowledge, mode: str, model
                          ) -> tuple[np.ndarray, float]:
        """:meth:`_calibrate`, kept on disk by ``key`` (:class:`KeptResults`: the
        calibration is deterministic, so a kept table is the one it would find)."""
        kept = self._batch_kept or _kept_tables()
        # On disk, shared by boards, protocols and sweeps: the nominal model too (it
        # picks the calibration speeds and the current paths).
        disk_key = [*key, knowledge.nominal]
        content = kept.get(disk_key)
        try:
            torque = np.array([complex(re, im) for re, im in content["torque_nm"]])
            if torque.shape == (len(DETENT_HARMONICS),):
                return torque, float(content["calibration_s"])
        except (TypeError, KeyError, ValueError):      # not kept, or not a table: calibrate
            pass
        torque, seconds = self._calibrate(knowledge, mode, model)
        kept.put(disk_key, {"torque_nm": [[float(z.real), float(z.imag)] for z in torque],
                             "calibration_s": seconds})
        return torque, seconds

    def _calibrate(self, knowledge: MotorKnowledge, mode: str, model) -> tuple[np.ndarray, float]:
        nominal = knowledge.nominal
        base = phasors(model)
        resonances = nominal.predicted_resonances_rps()
        table = np.array([base[i] / torque_paths(nominal, mode, resonances[h], model)[i]
                          for i, h in enumerate(DETENT_HARMONICS)])
        seconds = 0.0
        for h in (4, 2, 1):
            i = DETENT_HARMONICS.index(h)
            speed = resonances[h]
            start = table[i]

            def ripple(value: complex) -> float:
                nonlocal seconds
                trial = table.copy()
                trial[i] = value
                corr = np.empty(6)
                corr[0::2] = (trial - base).real
                corr[1::2] = (trial - base).imag
                amps, s = knowledge.rig.harmonic_ripple(mode, speed, model, corr, self.window_s)
                seconds += s
                return float(amps[i])

            phase, mag = 0.0, 1.0
            for width_phase, width_mag in ((math.pi / 3.0, 0.5), (math.pi / 12.0, 0.125)):
                phase = golden_section(
                    lambda p: ripple(start * mag * complex(fm.cos(p), fm.sin(p))),
                    phase - width_phase, phase + width_phase, self.iterations, start=phase)
                rot = start * complex(fm.cos(phase), fm.sin(phase))
                mag = golden_section(lambda m: ripple(rot * m), max(0.0, mag - width_mag),
                                     mag + width_mag, self.iterations, start=mag)
            table[i] = start * mag * complex(fm.cos(phase), fm.sin(phase))
        # Stored as the detent torque it cancels (times G at the calibration
        # speed), so each run speed gets it through its own current path.
        paths = np.array([torque_paths(nominal, mode, resonances[h], model)[i]
                          for i, h in enumerate(DETENT_HARMONICS)])
        return fm.cmul(table, paths), seconds


class RepetitiveControl(OnlineTable, DelayCompensatedFF):
    """``repetitive-control``: learns the periodic correction online, from the encoder.

    Source idea: repetitive control / iterative learning control of periodic
    torque ripple in PMSM drives: after each period of the disturbance,
    ``u_(k+1) = Q*(u_k + L*e_k)``. The detent is periodic in the electrical
    angle, so the period is one electrical revolution and the correction is
    held as the phasors of harmonics 1, 2, 4 (the kernel evaluates them at
    every PWM period, at the exact angle). Senses the encoder (the drive's
    velocity error estimate); model: nominal for the learning filter,
    identified for the starting table.

    After the ramp, each electrical period's velocity error is projected on
    sin(h*x) and cos(h*x) (one DFT bin per harmonic over the whole period,
    from the observation's own sin/cos entries), giving phasors R_h, and

        A_h <- A0_h + q*(A_h - A0_h) + gain * conj(P_h) / Pmax_h^2 * R_h

    with P = G*H*F: G the current path, H the rotor's torque-to-speed response
    and F the velocity estimate's, all at h*Nr*speed from the nominal model.
    conj(P) is the phase lead that compensates the plant's delay (a gradient
    step); Pmax_h, the largest |P| within the spread of resonances a motor of
    this type may have (0.7 to 1.4 times the frequency), bounds the loop gain
    by ``gain`` on any such motor. Q is the
    robustness filter: a harmonic is learned only where a period holds at
    least ``min_samples`` agent steps per cycle of it (a low-pass on the
    correction's frequency content; above it the DFT bin aliases) and the
    correction leaks towards the start by (1 - q) per period. A guard: a
    harmonic whose per-period ripple grows past ``guard_ratio`` times that of
    the least seen so far goes back to its start and stops learning.
    ``learning_gain`` was chosen on training motors (``scripts/ladder_tuning.py``).
    """

    card = PolicyCard(sensors="encoder (velocity estimate)",
                      model="nominal (learning filter), identified (start)")

    def __init__(self, learning_gain: float = 0.2, leak: float = 0.995,
                 min_samples: float = 6.0, guard_ratio: float = 3.0) -> None:
        super().__init__()
        self.name = "repetitive-control"
        self.guard_ratio = float(guard_ratio)
        self.learning_gain = float(learning_gain)
        self.leak = float(leak)
        self.min_samples = float(min_samples)

    #: The modes ``stepdamp export`` writes its online table for.
    firmware_modes: tuple[str, ...] = ("open-loop", "servo")

    def firmware_online(self, context: PolicyContext) -> RepetitiveTable:
        """The law this entry runs in ``context`` for a drive's firmware
        (:mod:`stepdamp_env.bench.firmware_online`): its start table, its
        learning gains, leak and guard."""
        if type(self) is not RepetitiveControl:   # a subclass may learn otherwise
            raise ParameterError(f"entry {self.name!r} cannot be exported: its law is not "
                                 "the online table RepetitiveControl exports")
        self.configure(context)
        return RepetitiveTable(
            **online_table_fields(context, entry=self.name, estimate=self.estimate,
                                  base=self._base, action=self._action, scale=self._scale,
                                  speed_ref_rad_s=self._w_ref),
            start_nm=phasor_pairs(self._start), learn=phasor_pairs(self._learn),
            wait_step=int(self._wait), leak=self.leak, guard_ratio=self.guard_ratio,
            notes=(f"{self.name}: ff-delay-comp's table on the {self.estimate} detent model "
                   "to start; once per electrical period the speed error's harmonics move "
                   "it through the conjugate of the plant's response at the held speed "
                   "(nominal model), bounded for the spread of resonances a motor of this "
                   "type may have."))

    def configure(self, context: PolicyContext) -> None:
        nominal = context.knowledge.nominal
        model = estimate_model(self.estimate, context.knowledge)
        self._base = phasors(model)
        g = torque_paths(nominal, context.mode, context.speed_rps, model)
        self._start = self._base / g
        self._table = self._start.copy()
        w = 2.0 * math.pi * abs(context.speed_rps)
        nr = nominal.motor.Nr
        def plant(h: int, w_h: float) -> complex:
            return (current_path_of(h, w_h) * torque_to_velocity(nominal, w_h, context.mode)
                    * velocity_filter(nominal, w_h))

        def current_path_of(h: int, w_h: float) -> complex:
            return g[DETENT_HARMONICS.index(h)]

        path = np.array([plant(h, h * nr * w) for h in DETENT_HARMONICS])
        # The step is normalised by the largest response within the spread of
        # resonances a motor of this type may have (wn x 0.7..1.4): a motor
        # whose true resonance sits on the harmonic must not see a loop gain
        # above ``learning_gain``.
        spread = 0.7 * fm.exp_array(np.arange(29) / 28.0 * fm.log(2.0))   # 0.7 .. 1.4, log-spaced
        peak = np.array([max(_magnitude(plant(h, f * h * nr * w)) for f in spread)
                         for h in DETENT_HARMONICS])
        cycle_steps = np.array([context.agent_hz / max(h * nr * abs(context.speed_rps), 1e-12)
                                for h in DETENT_HARMONICS])
        self._learn = (self.learning_gain * (cycle_steps >= self.min_samples)
                       * np.conj(path) / peak ** 2)
        self._w_ref = w
        self._scale = context.action_scale
        self._action = harmonic_actions(self._start, self._base, self._scale)
        self._wait = int(round(context.ramp_s * context.agent_hz))

    # The law on rows (RowPolicy: a scalar run is row 0); the angles go through
    # fixedmath.atan2 and Python's %
    # row by row (numpy's SIMD arctan2 differs from libm's in the last bit).
    _ROW_SETTINGS = ("_base", "_start", "_learn", "_w_ref", "_scale", "_action", "_table",
                     "_wait")
    LIVE_FROM = "_wait"

    def reset_batch(self, contexts: Sequence[PolicyContext]) -> None:
        self._rows = gather_rows(self, contexts,
                                 lambda: {k: getattr(self, k) for k in self._ROW_SETTINGS})
        n = len(contexts)
        self._rows.update(_angle=np.zeros(n), _turned=np.zeros(n),
                          _sums=np.zeros((n, 3), dtype=complex), _count=np.zeros(n, dtype=int),
                          _reference=np.zeros((n, 3)), _seen=np.zeros(n, dtype=bool),
                          _active=np.ones((n, 3), dtype=bool))
        self._rows_step = 0

    def row_calibration_s(self, row: int) -> float:
        return 0.0

    def _update_rows(self, observations: np.ndarray, idx: np.ndarray) -> None:
        r = self._rows
        s = observations[:, HARMONIC_SIN].astype(float)
        c = observations[:, HARMONIC_COS].astype(float)
        e = observations[:, OBS.velocity_error].astype(np.float64) * r["_w_ref"][idx]
        first = self._rows_step == r["_wait"][idx] + 1       # no previous angle yet
        angle = [fm.atan2(a, b) for a, b in zip(s[:, 0].tolist(), c[:, 0].tolist())]
        turned = r["_turned"][idx]
        for j, (a, prev) in enumerate(zip(angle, r["_angle"][idx].tolist())):
            if not first[j]:
                turned[j] += (a - prev + math.pi) % (2.0 * math.pi) - math.pi
        r["_angle"][idx] = angle
        r["_sums"][idx] += e[:, None] * (s + 1j * c)
        r["_count"][idx] += 1
        done = np.abs(turned) >= 2.0 * math.pi
        r["_turned"][idx] = turned
        if not done.any():
            return
        idx = idx[done]
        ripple = 2.0 * r["_sums"][idx] / r["_count"][idx][:, None]
        size = _magnitude(ripple)
        reference = np.where(r["_seen"][idx][:, None], np.minimum(r["_reference"][idx], size),
                             size)
        active = r["_active"][idx]
        diverged = active & (size > self.guard_ratio * reference)
        active &= ~diverged
        start = r["_start"][idx]
        table = np.where(diverged, start, r["_table"][idx])
        table = start + self.leak * (table - start) + active * fm.cmul(r["_learn"][idx], ripple)
        r["_action"][idx], r["_table"][idx] = harmonic_action_rows(table, r["_base"][idx],
                                                                   r["_scale"][idx])
        r["_reference"][idx] = reference
        r["_active"][idx] = active
        r["_seen"][idx] = True
        r["_turned"][idx] -= np.copysign(2.0 * math.pi, r["_turned"][idx])
        r["_sums"][idx] = 0.0
        r["_count"][idx] = 0
