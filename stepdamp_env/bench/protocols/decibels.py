"""What stepdamp-bench v3 made a row, shared by v3 and v4: reference rows,
per-motor sensors, a dev split, headline speeds by dominance, scores in
decibels (:mod:`.v3`'s docstring specifies them).

v3 is published: a change here must leave its numbers as they are (the v3 and
v4 fingerprints in the tests, under the emulated CPUs).
"""

from __future__ import annotations

import dataclasses
import hashlib
import math
from dataclasses import dataclass
from typing import Any, ClassVar, Mapping, Sequence

import numpy as np

from ... import fixedmath as fm
from ...params import ParameterError, SystemParams
from ...presets import get_preset
from ...simulation import RunSettings, SpeedProfile, simulate
from ..grid_cache import grids_cached
from ..motors import ProtocolMotor, draw_around, holds_its_load, with_sensors
from ..protocol import ALL_SUITES, REFERENCE_POLICY, REFERENCE_ROW, SUITE_MODE
from ..scoring import db_row_fields
from ..stats import (median_difference, motor_mean_bootstrap, probability_of_improvement,
                     rank_groups)
from .drawn import DrawnProtocol, MidBandProtocol, midband_grid

__all__ = ["DecibelProtocol", "SPLITS", "ENCODER_CPRS", "FAILURE_DB", "attenuation_db",
           "ratio_of_db", "eligible", "improvement_interval"]

SPLITS = ("dev", "interpolation", "extrapolation", "custom")
#: Encoders a drawn motor may have (counts/rev after quadrature): 1000, 2000 and
#: 2500 lines, 14, 15, 16 and 17 bit.
ENCODER_CPRS = (4000, 8000, 10000, 16384, 32768, 65536, 131072)
#: What a lost run scores, and the lower bound of every run's attenuation (dB).
FAILURE_DB = -20.0


_LN10 = 2.302585092994046



def ratio_of_db(db: float) -> float:
    """The ripple ratio 10^(-db/20) of an attenuation (fixed-order exp)."""
    return fm.exp(-db * _LN10 / 20.0) if math.isfinite(db) else math.nan


def attenuation_db(none_rms: float, entry_rms: float, floor_db: float = FAILURE_DB) -> float:
    """20 log10(none_rms / entry_rms), bounded below at ``floor_db`` (fixed-order log)."""
    if not (math.isfinite(none_rms) and math.isfinite(entry_rms)) or none_rms <= 0.0:
        return math.nan
    if entry_rms <= 0.0:
        return math.inf
    return max(floor_db, 20.0 * fm.log(none_rms / entry_rms) / _LN10)


@dataclass(frozen=True)
class DecibelProtocol(MidBandProtocol):
    """v3's definition of a row, which v4 keeps and extends: reference rows,
    per-motor sensors, a dev split, headline speeds by dominance, scores in
    dB (:mod:`.v3`'s docstring and docs/protocol_v3.md specify them). A
    version subclasses it with its own values."""

    #: The servo's candidate speeds (factors of f4); the headline keeps the
    #: ``servo_headline`` where ``none`` ripples most.
    servo_factors: tuple[float, ...] = (0.2, 0.28, 0.4, 0.56, 0.8, 1.1, 1.6)
    servo_headline: int = 3
    #: A headline speed: the reference ripples at most this share of ``none``.
    dominance: float = 0.5
    encoder_choices: tuple[int, ...] = ENCODER_CPRS
    dev_per_preset: int = 4
    dev_motor_seed: int = 7_733_053
    #: The mid-band reference: the current-mode drive at this many times the bus.
    reference_bus_factor: float = 4.0
    failure_db: float = FAILURE_DB
    lag_limit_steps: float = 1e9
    # The mid-band analysis's speed grid (rev/s): v2's step of 0.05 five times
    # coarser; the edges are bisected to 1e-4 rev/s either way.
    midband_scan_rps: tuple[float, float, float] = (0.25, 30.0, 0.25)

    known_splits: ClassVar[tuple[str, ...]] = SPLITS
    known_suites: ClassVar[tuple[str, ...]] = ALL_SUITES
    records_training_coverage: ClassVar[bool] = True
    headline_unit: ClassVar[str] = "dB"

    def __post_init__(self) -> None:
        super().__post_init__()
        if not (isinstance(self.servo_headline, int) and 1 <= self.servo_headline
                <= len(self.servo_factors)):
            raise ParameterError(f"servo_headline={self.servo_headline!r} is outside [1, "
                                 f"{len(self.servo_factors)}] (integer)")
        if not 0.0 < self.dominance < 1.0:
            raise ParameterError(f"dominance={self.dominance!r} is outside (0, 1)")
        if not self.encoder_choices or not all(isinstance(c, int) and c >= 1
                                               for c in self.encoder_choices):
            raise ParameterError(f"encoder_choices={self.encoder_choices!r}: each must be an "
                                 "integer >= 1")
        if not (isinstance(self.dev_per_preset, int) and self.dev_per_preset >= 1):
            raise ParameterError(f"dev_per_preset={self.dev_per_preset!r} is outside [1, inf) "
                                 "(integer)")
        if not (math.isfinite(self.reference_bus_factor) and self.reference_bus_factor >= 1.0):
            raise ParameterError(f"reference_bus_factor={self.reference_bus_factor!r} is "
                                 "outside [1, inf)")
        if not (math.isfinite(self.lag_limit_steps) and 1.0 <= self.lag_limit_steps <= 1e9):
            raise ParameterError(f"lag_limit_steps={self.lag_limit_steps!r} is outside [1, 1e9]")
        if not (math.isfinite(self.failure_db) and self.failure_db < 0.0):
            raise ParameterError(f"failure_db={self.failure_db!r} is outside (-inf, 0) dB")

    # -- the record --------------------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        out = super().to_dict()
        out["encoder_choices"] = list(self.encoder_choices)
        out["headline"] = (
            "attenuation_db: 20 log10(ripple of 'none' / ripple of the entry) per run at "
            "the suite's headline speeds (where the reference ripples at most "
            f"{self.dominance:g} x 'none'), lost runs {self.failure_db:g} dB (0 dB where "
            "'none' lost too); mean per motor over speeds, seeds and training seeds; IQM "
            "over motors; two-level bootstrap interval widened for the number of motors. "
            "gap_closed = attenuation / the reference row's, per motor")
        out["reference"] = {
            "open-loop": "policy none on the motor with Kd1 = Kd2 = Kd4 = 0",
            "servo": "policy none on the motor with Kd1 = Kd2 = Kd4 = 0",
            "mid-band": (f"policy none on the current-mode drive with {self.reference_bus_factor:g}"
                         " x the bus voltage (a stiff current source: no voltage-fed "
                         "instability), detent kept")}
        return out

    def lag_limit(self) -> float:
        return self.lag_limit_steps

    def with_splits(self, splits: Sequence[str]) -> "DecibelProtocol":
        """The same protocol on other splits (``--split``)."""
        bad = [s for s in splits if s not in self.known_splits or s == "custom"]
        if bad or not splits:
            raise ParameterError(f"--split {', '.join(bad) or '(none)'}: choose from "
                                 f"{[s for s in self.known_splits if s != 'custom']} "
                                 "(custom: --motors FILE)")
        return dataclasses.replace(self, splits=tuple(splits))

    # -- motors ------------------------------------------------------------------------
    def motors(self) -> tuple[ProtocolMotor, ...]:
        """dev (if run), then v1's interpolation, extrapolation or custom motors. The
        draws come first (:meth:`build_motor` leaves the grids out); then every
        motor's grids (its nominal sweeps and mid-band analysis, about a quarter
        of a second a motor) are computed on every core at once, the same values
        on any number of workers, and kept on disk (:func:`grids_cached`)."""
        drafts = self._dev_motors() + super().motors()
        grids = grids_cached(self, [m.system for m in drafts])
        return tuple(dataclasses.replace(m, speeds_rps=g[0][1], speed_labels=g[0][2], grids=g)
                     for m, g in zip(drafts, grids))

    def build_motor(self, name: str, system: SystemParams, nominal: SystemParams, split: str,
                    family: str, attempts: int) -> ProtocolMotor:
        """A drawn (or custom) motor with its sensors and settling; its grids are
        filled in by :meth:`motors`, for all motors at once."""
        system, nominal = self.motor_sensors(name, system, nominal, split)
        settle = self.settle_times(system)
        return ProtocolMotor(name, system, nominal, (), (), attempts, split=split,
                             family=family, settle=tuple((s, settle[s]) for s in settle))

    def _dev_motors(self) -> tuple[ProtocolMotor, ...]:
        if "dev" not in self.splits:
            return ()
        rng = np.random.default_rng(self.dev_motor_seed)
        out = []
        for preset in self.presets:
            nom = with_sensors(get_preset(preset), self)
            for k in range(self.dev_per_preset):
                label = f"{preset}~d{k}"
                for attempt in range(1, self.max_draw_attempts + 1):
                    try:
                        system = nom.replace(name=label, **draw_around(
                            nom, rng, self.training_randomization))
                    except ParameterError:
                        continue
                    if holds_its_load(system, self.holding_margin):
                        break
                else:
                    raise RuntimeError(f"no draw for {label!r} passes the physics rule in "
                                       f"{self.max_draw_attempts} attempts")
                out.append(self.build_motor(label, system, nom, "dev", preset, attempt))
        return tuple(out)

    def motor_sensors(self, name: str, system: SystemParams, nominal: SystemParams,
                      split: str) -> tuple[SystemParams, SystemParams]:
        """A drawn motor's encoder from ``encoder_choices`` (by a hash of the motor
        seed and its name); a custom motor keeps its own."""
        if split == "custom":
            return system, nominal
        key = hashlib.sha256(f"{self.motor_seed}:{name}".encode()).digest()
        cpr = self.encoder_choices[int.from_bytes(key[:8], "big") % len(self.encoder_choices)]
        return system.replace(encoder_cpr=cpr), nominal.replace(encoder_cpr=cpr)

    def reference_motor(self, motor: ProtocolMotor, suite: str) -> ProtocolMotor:
        """The motor without the suite's phenomenon (see the module docstring)."""
        if suite == "mid-band":
            m = motor.for_suite("open-loop")      # the current-mode drive
            return dataclasses.replace(m, system=m.system.replace(
                Vdc=m.system.drive.Vdc * self.reference_bus_factor))
        m = motor.for_suite(suite)
        return dataclasses.replace(m, system=m.system.replace(Kd1=0.0, Kd2=0.0, Kd4=0.0))

    def suite_grids(self, system: SystemParams
                    ) -> tuple[tuple[str, tuple[float, ...], tuple[str, ...]], ...]:
        """v2's open-loop and mid-band grids, the servo candidates; each speed
        labelled headline or ``off-`` by the dominance rule on the nominal sweep."""
        f4 = system.predicted_resonances_rps()[4]
        out = []
        # v1's grids, and v2's mid-band rule (where that suite is run).
        grids = DrawnProtocol.suite_grids(self, system)
        if "mid-band" in self.suites:
            grids += (("mid-band", *midband_grid(system, self, self.midband_scan_rps,
                                                 first_band_only=True)),)
        for suite, speeds, labels in grids:
            if suite == "servo":
                speeds = tuple(float(f * f4) for f in self.servo_factors)
                labels = tuple(f"s{f:g}" for f in self.servo_factors)
            out.append((suite, speeds, self._headline_labels(system, suite, speeds, labels)))
        return tuple(out)

    def _headline_labels(self, system: SystemParams, suite: str, speeds: tuple[float, ...],
                         labels: tuple[str, ...]) -> tuple[str, ...]:
        settle = self.settle_times(system)[suite]
        probe = ProtocolMotor(system.name, system, system, speeds, labels)
        plant = probe.for_suite(suite).system
        reference = self.reference_motor(probe, suite).system
        candidates = [k for k, lbl in enumerate(labels) if not lbl.startswith("off")]
        none_rms, passes = {}, set()
        for k in candidates:
            a = self._sweep_rms(plant, suite, speeds[k], settle)
            b = self._sweep_rms(reference, suite, speeds[k], settle)
            none_rms[k] = a
            if math.isfinite(a) and math.isfinite(b) and b <= self.dominance * a:
                passes.add(k)
        if suite == "servo":                      # the servo's resonance: where none peaks
            best = sorted(passes, key=lambda k: (-none_rms[k], k))[:self.servo_headline]
            passes = set(best)
        return tuple(lbl if k in passes else
                     (lbl if lbl.startswith("off") else f"off-{lbl}")
                     for k, lbl in enumerate(labels))

    def _sweep_rms(self, system: SystemParams, suite: str, speed_rps: float,
                   settle_s: float) -> float:
        result = simulate(system, profile=SpeedProfile(speed_rps=speed_rps,
                                                       accel_rps2=self.accel_rps2),
                          settings=RunSettings(mode=SUITE_MODE[suite], settle_s=settle_s,
                                               window_s=self.window_s,
                                               noise_seed=self.eval_seeds[0]))
        return float(result.metrics.rms_velocity_error_rad_s)

    # -- scoring -----------------------------------------------------------------------
    def entries(self, names: Mapping[str, tuple[str, str]],
                by_entry: Mapping[tuple[str, str], list[dict[str, Any]]],
                motors: Sequence[ProtocolMotor],
                meta: Mapping[str, dict[str, Any]], *, workers: int = 1
                ) -> list[dict[str, Any]]:
        """Rows per (suite, split): the reference, then every entry; ranked rows,
        P(improvement) and effect sizes (see the module docstring)."""
        split_of = {m.name: m.split for m in motors}
        grid_of = {(m.name, s): m.speeds(s) for m in motors for s in self.suites}
        out = []
        for suite in self.suites:
            if (REFERENCE_POLICY, suite) not in by_entry:
                continue
            none = {(r["motor"], r["seed"], r["speed_rps"]): r
                    for r in by_entry[(REFERENCE_POLICY, suite)]}
            stand_in = self._stand_ins(none)
            for split in self.splits:
                def runs_of(key: tuple[str, str]) -> list[dict[str, Any]]:
                    return [r for r in by_entry.get(key, []) if split_of[r["motor"]] == split]

                headline = sorted({v for m in motors if m.split == split
                                   for v, lbl in zip(*grid_of[(m.name, suite)])
                                   if not lbl.startswith("off")})
                rows = []
                ref_runs = runs_of((REFERENCE_ROW, suite))
                ref_motor_db: dict[str, float] = {}
                if ref_runs:
                    ref = self._row(REFERENCE_ROW, REFERENCE_ROW, suite, split, ref_runs, none,
                                    stand_in, None, {"reference": True, "learned": False,
                                           "privileged": False, "zero_shot": False})
                    ref_motor_db = dict(ref["_motor_db"])
                    rows.append(ref)
                for spec, (name, spec_text) in names.items():
                    if (spec, suite) not in by_entry:
                        continue
                    info = meta[spec]
                    learned = bool(info.get("learned"))
                    row_meta = {"reference": False, "learned": learned,
                                "privileged": bool(info.get("oracle")), **info}
                    row_meta["zero_shot"] = learned and not eligible(
                        info.get("trained_on", ()), suite, headline)
                    rows.append(self._row(name, spec_text, suite, split, runs_of((spec, suite)),
                                          none, stand_in, ref_motor_db, row_meta))
                self._compare(rows)
                for r in rows:
                    r.pop("_motor_db", None)
                out += rows
        return out

    def _row(self, name: str, spec: str, suite: str, split: str, runs: list[dict[str, Any]],
             none: Mapping[tuple, Mapping[str, Any]],
             stand_in: Mapping[tuple[str, int], float],
             ref_motor_db: Mapping[str, float] | None,
             info: Mapping[str, Any]) -> dict[str, Any]:
        """One row's scores (``_motor_db``: per-motor attenuation, taken off later);
        ``stand_in``: :meth:`_stand_ins` of ``none``."""
        cells: dict[tuple[str, Any], list[float]] = {}
        ratios: list[float] = []
        for r in runs:
            n = none.get((r["motor"], r["seed"], r["speed_rps"]))
            db = self._run_db(r, n, stand_in.get((r["motor"], r["seed"]), math.nan))
            ratios.append(ratio_of_db(db))
            if not r["speed_label"].startswith("off") and math.isfinite(db):
                cells.setdefault((r["motor"], r.get("training_seed")), []).append(db)
        keys = sorted(cells, key=str)
        cell_db = [float(np.mean(cells[k])) for k in keys]
        cell_motor = [k[0] for k in keys]
        motor_db: dict[str, float] = {}
        for m in sorted(set(cell_motor)):
            motor_db[m] = float(np.mean([v for v, k in zip(cell_db, cell_motor) if k == m]))
        stats = dict(resamples=self.bootstrap_resamples, seed=self.bootstrap_seed,
                     confidence=self.confidence)
        att = motor_mean_bootstrap(cell_db, cell_motor, **stats)
        ratio = motor_mean_bootstrap([ratio_of_db(v) for v in cell_db], cell_motor,
                                     positive=True, **stats)
        row: dict[str, Any] = {"name": name, "spec": spec, "suite": suite, "split": split,
                               **{k: v for k, v in info.items()}}
        row["training_seeds"] = sorted({r["training_seed"] for r in runs
                                        if r.get("training_seed") is not None})
        row["attenuation_db"] = att
        row["ratio"] = ratio
        if ref_motor_db is not None:
            gap = [v / ref_motor_db[m] if ref_motor_db.get(m, 0.0) > 0.0 else math.nan
                   for v, m in zip(cell_db, cell_motor)]
            row["gap_closed"] = motor_mean_bootstrap(gap, cell_motor, **stats)
        else:
            row["gap_closed"] = {"iqm": 1.0, "ci": [1.0, 1.0], "motors": len(motor_db)}
        row.update(db_row_fields(runs, keys, cell_db, ratios, ratio, motor_db, ratio_of_db))
        row["runs"] = runs
        row["_motor_db"] = motor_db
        row["_cells"] = (cell_db, cell_motor)
        return row

    def headline_run_db(self, runs: Sequence[Mapping[str, Any]],
                        none_runs: Sequence[Mapping[str, Any]]
                        ) -> dict[tuple[str, int, float], float]:
        """Each headline run's attenuation (dB) against ``none``'s run of the same
        (motor, seed, speed), as a row scores it (lost runs and lost ``none`` runs
        by the same rules), keyed (motor, seed, speed_rps); runs without a finite
        score are left out."""
        none = {(r["motor"], r["seed"], r["speed_rps"]): r for r in none_runs}
        stand_in = self._stand_ins(none)
        out: dict[tuple[str, int, float], float] = {}
        for r in runs:
            if r["speed_label"].startswith("off"):
                continue
            key = (r["motor"], r["seed"], r["speed_rps"])
            db = self._run_db(r, none.get(key), stand_in.get((r["motor"], r["seed"]), math.nan))
            if math.isfinite(db):
                out[key] = db
        return out

    def _run_db(self, run: Mapping[str, Any], none: Mapping[str, Any] | None,
                stand_in: float) -> float:
        none_lost = none is not None and bool(none["failed"])
        if run["failed"]:
            return 0.0 if none_lost else self.failure_db
        # A lost `none` run (a stalled rotor: its error is the command speed) is no
        # measure of the resonance: the motor's runs of `none` that held stand in.
        none_rms = none["metrics"]["rms_velocity_error_rad_s"] \
            if none is not None and none["metrics"] is not None and not none_lost \
            else stand_in
        own = run["metrics"]["rms_velocity_error_rad_s"] if run["metrics"] else math.nan
        return attenuation_db(none_rms, own, self.failure_db)

    @staticmethod
    def _stand_ins(none: Mapping[tuple, Mapping[str, Any]]) -> dict[tuple[str, int], float]:
        """Per (motor, seed): the mean of the headline ripples of ``none``'s runs that
        held (none there where every one was lost: those cells are left out)."""
        got: dict[tuple[str, int], list[float]] = {}
        for (motor, seed, _), r in none.items():
            if r["metrics"] is not None and not r["speed_label"].startswith("off") \
                    and not r["failed"]:
                got.setdefault((motor, seed), []).append(r["metrics"]["rms_velocity_error_rad_s"])
        return {k: float(np.mean(v)) for k, v in got.items()}

    def _compare(self, rows: list[dict[str, Any]]) -> None:
        """Ranks (ranked rows only), P(improvement) and effect sizes between rows."""
        ranked = [r for r in rows if not (r["reference"] or r["privileged"] or r["zero_shot"])]
        ranks = rank_groups([r["attenuation_db"]["iqm"] for r in ranked],
                            [r["attenuation_db"]["ci"] for r in ranked])
        for r in rows:
            r["rank"] = None
        for r, k in zip(ranked, ranks):
            r["rank"] = k           # None: no finite score (no headline cell)
        stats = dict(resamples=self.bootstrap_resamples, seed=self.bootstrap_seed,
                     confidence=self.confidence)
        compared = rows             # the reference too: how often an entry beats it
        for r in compared:
            r["probability_of_improvement"], r["effect_db"] = {}, {}
        for i, a in enumerate(compared):
            for b in compared[i + 1:]:
                (xa, ma), (xb, mb) = a["_cells"], b["_cells"]
                keep_a = [k for k, v in enumerate(xa) if math.isfinite(v)]
                keep_b = [k for k, v in enumerate(xb) if math.isfinite(v)]
                p = probability_of_improvement(     # lower is better there: minus dB
                    [-xa[k] for k in keep_a], [ma[k] for k in keep_a],
                    [-xb[k] for k in keep_b], [mb[k] for k in keep_b], interval=False,
                    **stats)["p"]
                a["probability_of_improvement"][b["name"]] = p
                b["probability_of_improvement"][a["name"]] = 1.0 - p
                eff = median_difference(a["_motor_db"], b["_motor_db"], **stats)
                a["effect_db"][b["name"]] = {"median": eff["median"], "ci": eff["ci"]}
                b["effect_db"][a["name"]] = {"median": -eff["median"],
                                             "ci": [-eff["ci"][1], -eff["ci"][0]]}
        for r in rows:
            r.pop("_cells", None)


def eligible(trained_on: Sequence[Sequence[Any]], suite: str, speeds_rps: Sequence[float]
             ) -> bool:
    """Whether a learned entry's training covered a suite's headline speeds:
    ``trained_on`` holds (suite, lowest rev/s, highest rev/s) ranges (no
    headline speed: nothing to be ranked on)."""
    ranges = [(float(lo), float(hi)) for s, lo, hi in trained_on if s == suite]
    return bool(ranges) and bool(speeds_rps) and all(any(lo <= v <= hi for lo, hi in ranges) for v in speeds_rps)


def improvement_interval(a: Mapping[str, Any], b: Mapping[str, Any],
                         protocol: Mapping[str, Any]) -> dict[str, Any]:
    """P(row ``a`` attenuates more than row ``b``) and its two-level 95 % interval
    (motors, then cells), from the rows' cell scores (``scores`` of a loaded
    board) and the board's bootstrap settings (``protocol``). P is the value the
    board stores; the board leaves its interval out (one pair here, every pair
    there)."""
    def cells(row: Mapping[str, Any]) -> tuple[list[float], list[str]]:
        keep = [c for c in row["scores"] if math.isfinite(c["attenuation_db"])]
        return [-c["attenuation_db"] for c in keep], [c["motor"] for c in keep]

    (xa, ma), (xb, mb) = cells(a), cells(b)
    return probability_of_improvement(xa, ma, xb, mb, resamples=protocol["bootstrap_resamples"],
                                      seed=protocol["bootstrap_seed"],
                                      confidence=protocol["confidence"])
