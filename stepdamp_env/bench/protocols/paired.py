"""What ``stepdamp-bench`` v4 and later versions share: paired ranks, evaluation
seeds, per-cell eligibility, the catalogue split, the moves suite and the
tables' facts. The rules are specified in v4's module docstring
(:mod:`.v4`) and docs/protocol_v4.md; a version is a subclass that names
itself and its entries (and, v5, its bound).
"""

from __future__ import annotations

import dataclasses
import math
import multiprocessing
import os
from dataclasses import dataclass
from typing import Any, Callable, ClassVar, Mapping, Sequence

import numpy as np

from ...parallel import WorkerLostError, pool_map
from ...params import Allowed, ParameterError, SystemParams
from ..grid_cache import grids_cached
from ..motors import ProtocolMotor, holds_its_load
from ..moves import cell_command, moves_grid
from ..protocol import ALL_SUITES, REFERENCE_POLICY, REFERENCE_ROW, TRAINING_SEED_LIMIT
from ..scoring import db_row_fields
from ..stats import (iqm, median_difference, motor_mean_bootstrap, paired_ranks,
                     probability_of_improvement)
from ..verdicts import table_facts
from .decibels import DecibelProtocol, attenuation_db, ratio_of_db
from .drawn import QUICK_SETTINGS, DrawnProtocol, load_motors_file

__all__ = ["PairedProtocol", "SPLITS", "CATALOGUE_PATH", "QUICK_CATALOGUE", "quick_settings",
           "coverage", "evaluation_seeds", "catalogue_systems"]

SPLITS = ("dev", "interpolation", "extrapolation", "catalogue", "custom")
#: The catalogue split's motors (public datasheets; sources inside).
CATALOGUE_PATH = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))),
                              "catalogue.json")
#: The privileged entry that stands for what damping can reach (``headroom_db``).
BOUND_ENTRY = "plant-bound"
#: The run metric of the position score (``position_attenuation_db``).
POSITION_METRIC = "position_ripple_steps"
#: The moves suite's: the position error over the whole move and its settling.
MOVE_POSITION_METRIC = "run_position_error_steps"
#: v4's suites: v3's and the moves.
SUITES_V4 = ALL_SUITES + ("moves",)
#: How many evaluation seeds ``--eval-seeds`` may ask for.
MAX_EVAL_SEEDS = 20
#: The settings' ranges: (low, high, low end open, high end open).
_RANGES = {"coverage_min": (0.0, 1.0, True, False), "rank_confidence": (0.0, 1.0, True, True),
           "decisive_share": (0.5, 1.0, True, False), "bound_share_min": (0.0, 1.0, True, False),
           "saturation_db": (0.0, math.inf, False, True),
           "move_accel_rps2": (1.0, 1e4, False, False),
           "move_s_curve_accel_rps2": (1.0, 1e4, False, False),
           "move_torque_share": (0.0, 1.0, True, False),
           "min_paired_motors": (1, math.inf, False, True)}


def evaluation_seeds(count: int) -> tuple[int, ...]:
    """``count`` evaluation seeds from :data:`TRAINING_SEED_LIMIT` on (``--eval-seeds``)."""
    if not (isinstance(count, int) and 1 <= count <= MAX_EVAL_SEEDS):
        raise ParameterError(f"--eval-seeds {count!r} is outside [1, {MAX_EVAL_SEEDS}] (a count)")
    return tuple(TRAINING_SEED_LIMIT + k for k in range(count))


def catalogue_systems(protocol: DrawnProtocol, names: Sequence[str] = ()) -> tuple[SystemParams, ...]:
    """The catalogue's motors (all, or those named, in the file's order), with
    the protocol's sensors where the file gives none."""
    systems = load_motors_file(CATALOGUE_PATH, protocol)
    if not names:
        return systems
    known = {s.name for s in systems}
    bad = [n for n in names if n not in known]
    if bad:
        raise ParameterError(f"catalogue_motors: {bad} are not in {CATALOGUE_PATH}")
    return tuple(s for s in systems if s.name in set(names))


def coverage(trained_on: Sequence[Sequence[Any]], suite: str,
             cells: Sequence[tuple[Any, ...]]) -> tuple[float, frozenset]:
    """The share of ``cells`` ((motor, rev/s, label) tuples) whose speed a learned
    entry's ``trained_on`` ((suite, lowest rev/s, highest rev/s) ranges) covers
    in ``suite``, and the covered cells."""
    ranges = [(float(lo), float(hi)) for s, lo, hi in trained_on if s == suite]
    covered = frozenset(c for c in cells if any(lo <= c[1] <= hi for lo, hi in ranges))
    return (len(covered) / len(cells) if cells else 0.0), covered


@dataclass(frozen=True)
class ScoringTable:
    """One (suite, split)'s inputs to scoring: each row with its runs, the
    reference's runs by cell, the stand-ins, the common cells, the split's
    count of cells and the position metric."""
    rows: list[tuple[dict[str, Any], list[dict[str, Any]]]]
    none: Mapping[tuple, Mapping[str, Any]]
    stand_in: Mapping[tuple[str, int], float]
    common: frozenset
    n_cells: int
    position: str


#: What a forked scoring worker reads (set in the worker by :func:`_receive_tables`).
_FORKED: list[tuple["PairedProtocol", Sequence[ScoringTable]]] = []


def _receive_tables(protocol: "PairedProtocol", tables: Sequence[ScoringTable]) -> None:
    """A forked worker's initializer: the tables it scores (inherited by the
    fork, never pickled; the parent's :data:`_FORKED` stays empty)."""
    _FORKED[:] = [(protocol, tables)]


def _scored_table(index: int) -> list[dict[str, Any]]:
    """In a forked worker: table ``index`` of :data:`_FORKED`, scored, each row's
    runs left out (``None`` in their place, so that the keys keep their order)."""
    protocol, tables = _FORKED[0]
    rows = protocol.score_table(tables[index])
    for row in rows:
        row["runs"] = None
    return rows


@dataclass(frozen=True)
class PairedProtocol(DecibelProtocol):
    """The rules v4 and later versions share (v4's module docstring,
    docs/protocol_v4.md): every setting but the version and its entries."""

    splits: tuple[str, ...] = ("interpolation", "extrapolation", "catalogue")
    eval_seeds: tuple[int, ...] = evaluation_seeds(3)
    #: The catalogue motors run (empty: every one in the file).
    catalogue_motors: tuple[str, ...] = ()
    #: A learned entry is ranked where its training covers this share of cells.
    coverage_min: float = 0.9
    #: Paired ranks: the interval's confidence, the share of motors (or
    #: P(improvement)) that decides a pair, and the fewest motors a pair needs.
    rank_confidence: float = 0.95
    decisive_share: float = 0.95
    min_paired_motors: int = 3
    bound_entry: str = BOUND_ENTRY
    #: A table whose bound holds on this share of motors has a measured headroom.
    bound_share_min: float = 0.95
    #: Less headroom than this (dB) between the bound and the best entry: saturated.
    saturation_db: float = 3.0
    suites: tuple[str, ...] = SUITES_V4
    #: The moves suite: the trapezoid's acceleration and the S-curve's peak
    #: (rev/s^2; 4,000 and 8,000 mm/s^2 on a 40 mm/rev belt pulley), each at
    #: most ``move_torque_share`` of the holding torque over the rotor's (and
    #: load's) inertia.
    move_accel_rps2: float = 100.0
    move_s_curve_accel_rps2: float = 200.0
    move_torque_share: float = 0.3

    known_splits: ClassVar[tuple[str, ...]] = SPLITS
    known_suites: ClassVar[tuple[str, ...]] = SUITES_V4
    #: Every run metric, the position error's too.
    run_metrics: ClassVar[tuple[str, ...] | None] = None
    #: v3's bound, superseded here by ``plant-bound`` (BOUND_ENTRY).
    retired_entries: ClassVar[tuple[str, ...]] = ("privileged-bound",)
    #: ``--eval-seeds`` may change how many evaluation seeds run.
    eval_seeds_settable: ClassVar[bool] = True

    def __post_init__(self) -> None:
        super().__post_init__()
        for name, (low, high, low_open, high_open) in _RANGES.items():
            Allowed(low, high, low_open, high_open, integer=name == "min_paired_motors"
                    ).check(name, getattr(self, name))

    # -- the record --------------------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        out = super().to_dict()
        out["catalogue_motors"] = list(self.catalogue_motors)
        out["rank_rule"] = ("ranks from paired comparisons over motors: an entry shares rank "
                            "1 only if the leader does not beat it (paired interval, "
                            f"{self.decisive_share:.0%} of motors or P(improvement) >= "
                            f"{self.decisive_share:g}), never above a higher score")
        out["headline"] = (
            "attenuation_db as v3 on each table's common cells; a held run never scores "
            "below a lost one (lost -20 dB where 'none' held, 0 dB where it lost; held "
            "runs bounded below at -20 dB, or at 0 dB where 'none' lost); ranks from "
            f"paired comparisons over motors ({self.rank_confidence:g} interval or "
            f"{self.decisive_share:g} of motors), monotone in the headline")
        return out

    def with_eval_seeds(self, count: int) -> "PairedProtocol":
        """The same protocol with ``count`` evaluation seeds (``--eval-seeds``)."""
        return dataclasses.replace(self, eval_seeds=evaluation_seeds(count))

    # -- the moves suite (:mod:`..moves`) ------------------------------------------------
    def settle_times(self, system: SystemParams) -> dict[str, float]:
        """v3's; the moves settle as the open loop does (after the stop)."""
        out = super().settle_times(system)
        out["moves"] = out["open-loop"]
        return out

    def suite_grids(self, system: SystemParams
                    ) -> tuple[tuple[str, tuple[float, ...], tuple[str, ...]], ...]:
        """v3's grids, and the moves suite's (:func:`..moves.moves_grid`)."""
        grids = super().suite_grids(system)
        if "moves" not in self.suites:
            return grids
        speeds, labels = next((v, lb) for s, v, lb in grids if s == "open-loop")
        return grids + (("moves", *moves_grid(speeds, labels)),)

    def run_command(self, motor: ProtocolMotor, suite: str, index: int) -> dict[str, Any]:
        """The moves suite's cell ``index`` (:func:`..moves.cell_command`): a move
        cruising for ``window_s``; {} in the other suites."""
        if suite != "moves":
            return {}
        grid = motor.speeds(suite)
        return cell_command(motor.system, grid.speeds_rps[index], grid.labels[index],
                            {"trapezoid": self.move_accel_rps2,
                             "s-curve": self.move_s_curve_accel_rps2},
                            self.move_torque_share, self.window_s)

    # -- motors ------------------------------------------------------------------------
    def motors(self) -> tuple[ProtocolMotor, ...]:
        """dev (if run), v3's drawn splits or the custom motors, then the
        catalogue; their grids as v3's."""
        drafts = self._dev_motors() + DrawnProtocol.motors(self) + self._catalogue()
        grids = grids_cached(self, [m.system for m in drafts])
        return tuple(dataclasses.replace(m, speeds_rps=g[0][1], speed_labels=g[0][2], grids=g)
                     for m, g in zip(drafts, grids))

    def _catalogue(self) -> tuple[ProtocolMotor, ...]:
        if "catalogue" not in self.splits:
            return ()
        out = []
        for system in catalogue_systems(self, self.catalogue_motors):
            if not holds_its_load(system, self.holding_margin):
                raise ParameterError(f"catalogue motor {system.name!r} cannot hold its load "
                                     f"with margin {self.holding_margin:g}")
            out.append(self.build_motor(system.name, system, system, "catalogue",
                                        "catalogue", 0))
        return tuple(out)

    def motor_sensors(self, name: str, system: SystemParams, nominal: SystemParams,
                      split: str) -> tuple[SystemParams, SystemParams]:
        """A catalogue motor keeps its file's sensors (as a custom one); drawn
        motors v3's."""
        if split == "catalogue":
            return system, nominal
        return super().motor_sensors(name, system, nominal, split)

    # -- scoring -----------------------------------------------------------------------
    def entries(self, names: Mapping[str, tuple[str, str]],
                by_entry: Mapping[tuple[str, str], list[dict[str, Any]]],
                motors: Sequence[ProtocolMotor],
                meta: Mapping[str, dict[str, Any]], *, workers: int = 1
                ) -> list[dict[str, Any]]:
        """Rows per (suite, split): the reference, then every entry, scored on the
        table's common cells, ranked by paired comparisons (module docstring).
        ``workers`` > 1 scores the tables on that many forked processes (the
        same numbers: each table is scored whole in one process)."""
        split_of = {m.name: m.split for m in motors}
        tables: list[ScoringTable] = []
        for suite in self.suites:
            if (REFERENCE_POLICY, suite) not in by_entry:
                continue
            none = {(r["motor"], r["seed"], r["speed_rps"], r["speed_label"]): r
                    for r in by_entry[(REFERENCE_POLICY, suite)]}
            stand_in = self._stand_ins_of(none, "rms_velocity_error_rad_s")
            position = MOVE_POSITION_METRIC if suite == "moves" else POSITION_METRIC
            for split in self.splits:
                cells = sorted({(m.name, float(v), lbl) for m in motors if m.split == split
                                for v, lbl in zip(*m.speeds(suite))
                                if not lbl.startswith("off")}, key=str)
                specs = [(REFERENCE_ROW, REFERENCE_ROW, REFERENCE_ROW, {"reference": True})] + [
                    (spec, name, text, dict(meta[spec])) for spec, (name, text) in names.items()
                    if (spec, suite) in by_entry]
                rows, covered = [], []
                for spec, name, text, info in specs:
                    learned = bool(info.get("learned"))
                    share, mine = coverage(info.get("trained_on", ()), suite, cells) \
                        if learned else (1.0, frozenset(cells))
                    row = {"name": name, "spec": text, "suite": suite, "split": split,
                           **info, "reference": bool(info.get("reference")),
                           "learned": learned, "privileged": bool(info.get("oracle")),
                           "zero_shot": learned and share < self.coverage_min,
                           "coverage": share}
                    runs = [r for r in by_entry.get((spec, suite), [])
                            if split_of[r["motor"]] == split]
                    rows.append((row, runs))
                    if learned and not row["zero_shot"]:
                        covered.append(mine)
                common = frozenset(cells).intersection(*covered) if covered else frozenset(cells)
                tables.append(ScoringTable(rows, none, stand_in, common, len(cells), position))
        return [row for scored in self._score_tables(tables, workers) for row in scored]

    def score_table(self, table: ScoringTable) -> list[dict[str, Any]]:
        """One table's rows (``table``: as :meth:`entries` builds them), scored,
        compared and ranked."""
        scored = [self._score(row, runs, table.none, table.stand_in, table.common,
                              table.n_cells, table.position) for row, runs in table.rows]
        self._gap(scored)
        self._compare(scored)
        return scored

    def _score_tables(self, tables: Sequence[ScoringTable], workers: int
                      ) -> list[list[dict[str, Any]]]:
        """Every table scored, here or (``workers`` > 1, where processes fork) on
        forked workers that read the tables from :data:`_FORKED` and send back
        the rows without their runs (the parent puts its own back, in place).
        If a worker dies, every table is scored here."""
        if workers <= 1 or len(tables) < 2 or \
                "fork" not in multiprocessing.get_all_start_methods():
            return [self.score_table(t) for t in tables]
        # The largest tables first, so that the last one to finish is short.
        order = sorted(range(len(tables)),
                       key=lambda k: -sum(len(runs) for _, runs in tables[k].rows))
        try:
            got = pool_map(_scored_table, order, min(workers, len(tables)),
                           initializer=_receive_tables, initargs=(self, tables))
        except WorkerLostError:     # the runs are done: score them here rather than lose them
            return [self.score_table(t) for t in tables]
        out: list[list[dict[str, Any]]] = [[] for _ in tables]
        for k, rows in zip(order, got):
            for row, (_, runs) in zip(rows, tables[k].rows):
                row["runs"] = runs
            out[k] = rows
        return out

    def _score(self, row: dict[str, Any], runs: list[dict[str, Any]],
               none: Mapping[tuple, Mapping[str, Any]],
               stand_in: Mapping[tuple[str, int], float], common: frozenset,
               n_cells: int, position: str = POSITION_METRIC) -> dict[str, Any]:
        """A row's scores on the ``common`` cells (``_cells``, ``_motor_db`` and
        ``_seed_motor_db``: taken off by :meth:`_compare`)."""
        cell_runs: dict[tuple[str, Any], list[float]] = {}
        by_seed: dict[tuple[int, str], list[float]] = {}
        ratios = []
        for r in runs:
            n = none.get((r["motor"], r["seed"], r["speed_rps"], r["speed_label"]))
            db = self.run_db(r, n, stand_in.get((r["motor"], r["seed"]), math.nan))
            ratios.append(ratio_of_db(db))
            if (r["motor"], float(r["speed_rps"]), r["speed_label"]) in common and math.isfinite(db) \
                    and not r["speed_label"].startswith("off"):
                cell_runs.setdefault((r["motor"], r.get("training_seed")), []).append(db)
                by_seed.setdefault((r["seed"], r["motor"]), []).append(db)
        keys = sorted(cell_runs, key=str)
        cell_db = [float(np.mean(cell_runs[k])) for k in keys]
        cell_motor = [k[0] for k in keys]
        motor_db = {m: float(np.mean([v for v, k in zip(cell_db, cell_motor) if k == m]))
                    for m in sorted(set(cell_motor))}
        seed_motor_db: dict[int, dict[str, float]] = {}
        for (seed, motor), v in sorted(by_seed.items(), key=str):
            seed_motor_db.setdefault(seed, {})[motor] = float(np.mean(v))
        stats = dict(resamples=self.bootstrap_resamples, seed=self.bootstrap_seed,
                     confidence=self.confidence)
        att = motor_mean_bootstrap(cell_db, cell_motor, **stats)
        ratio = motor_mean_bootstrap([ratio_of_db(v) for v in cell_db], cell_motor,
                                     positive=True, **stats)
        row["cells"] = {"scored": len(common), "split": n_cells}
        row["training_seeds"] = sorted({r["training_seed"] for r in runs
                                        if r.get("training_seed") is not None})
        row["attenuation_db"] = att
        row["ratio"] = ratio
        row.update(db_row_fields(runs, keys, cell_db, ratios, ratio, motor_db, ratio_of_db))
        row["position_metric"] = position
        row.update(self._position_scores(runs, none, common, stats, position))
        row["runs"] = runs
        row["_cells"] = (cell_db, cell_motor)
        row["_seed_motor_db"] = seed_motor_db
        return row

    def _position_scores(self, runs: Sequence[Mapping[str, Any]],
                         none: Mapping[tuple, Mapping[str, Any]], common: frozenset,
                         stats: Mapping[str, Any], metric: str = POSITION_METRIC
                         ) -> dict[str, Any]:
        """``position_attenuation_db`` (IQM over motors [interval]) and
        ``per_motor_position_db``: the velocity score's rules (:meth:`run_db`,
        its stand-ins, cells and motors) on the position ``metric``: the ripple
        (``position_ripple_steps``, the RMS position error about its window
        mean), in the moves suite the error over the move and its settling
        (``run_position_error_steps``, the RMS about the command)."""
        stand_in = self._stand_ins_of(none, metric)
        cells: dict[tuple[str, Any], list[float]] = {}
        for r in runs:
            n = none.get((r["motor"], r["seed"], r["speed_rps"], r["speed_label"]))
            db = self.run_db(r, n, stand_in.get((r["motor"], r["seed"]), math.nan), metric)
            if (r["motor"], float(r["speed_rps"]), r["speed_label"]) in common and math.isfinite(db) \
                    and not r["speed_label"].startswith("off"):
                cells.setdefault((r["motor"], r.get("training_seed")), []).append(db)
        keys = sorted(cells, key=str)
        cell_db = [float(np.mean(cells[k])) for k in keys]
        cell_motor = [k[0] for k in keys]
        per_motor = {m: float(np.mean([v for v, k in zip(cell_db, cell_motor) if k == m]))
                     for m in sorted(set(cell_motor))}
        return {"position_attenuation_db": motor_mean_bootstrap(cell_db, cell_motor, **stats),
                "per_motor_position_db": per_motor}

    @staticmethod
    def _stand_ins_of(none: Mapping[tuple, Mapping[str, Any]], metric: str
                      ) -> dict[tuple[str, int], float]:
        """v3's stand-ins (``_stand_ins``) of another run metric."""
        got: dict[tuple[str, int], list[float]] = {}
        for (motor, seed, *_), r in none.items():
            if r["metrics"] is not None and not r["speed_label"].startswith("off") \
                    and not r["failed"] and metric in r["metrics"]:
                got.setdefault((motor, seed), []).append(r["metrics"][metric])
        return {k: float(np.mean(v)) for k, v in got.items()}

    def headline_run_db(self, runs: Sequence[Mapping[str, Any]],
                        none_runs: Sequence[Mapping[str, Any]]
                        ) -> dict[tuple[str, int, float], float]:
        """v4's :meth:`run_db` of each headline run of the velocity ripple against
        ``none``'s run of the same cell and seed, keyed (motor, seed, speed_rps);
        runs without a finite score are left out."""
        score = self.run_scorer(none_runs)
        out: dict[tuple[str, int, float], float] = {}
        for r in runs:
            if r["speed_label"].startswith("off"):
                continue
            db = score(r)
            if math.isfinite(db):
                out[(r["motor"], r["seed"], r["speed_rps"])] = db
        return out

    def run_scorer(self, none_runs: Sequence[Mapping[str, Any]]
                   ) -> Callable[[Mapping[str, Any]], float]:
        """A run's :meth:`run_db` of the velocity ripple against ``none``'s run of
        the same cell and seed (or its stand-in), as a function of the run."""
        none = {(r["motor"], r["seed"], r["speed_rps"], r["speed_label"]): r for r in none_runs}
        stand_in = self._stand_ins_of(none, "rms_velocity_error_rad_s")

        def score(r: Mapping[str, Any]) -> float:
            n = none.get((r["motor"], r["seed"], r["speed_rps"], r["speed_label"]))
            return self.run_db(r, n, stand_in.get((r["motor"], r["seed"]), math.nan))
        return score

    def run_db(self, run: Mapping[str, Any], none: Mapping[str, Any] | None,
               stand_in: float, metric: str = "rms_velocity_error_rad_s") -> float:
        """One run's attenuation in dB (module docstring, "Runs") of ``metric``
        (the velocity ripple; the position ripple, ``POSITION_METRIC``)."""
        none_held = none is not None and not none["failed"] and none["metrics"] is not None \
            and metric in none["metrics"]
        if run["failed"]:
            # Where `none` lost and held nothing on this motor and seed, the cell has
            # no score for any row (a lost run must not outscore a held one).
            return self.failure_db if none_held else 0.0 if math.isfinite(stand_in) \
                else math.nan
        own = run["metrics"].get(metric, math.nan) if run["metrics"] else math.nan
        if none_held:
            return attenuation_db(none["metrics"][metric], own, self.failure_db)
        return attenuation_db(stand_in, own, 0.0)

    def _gap(self, rows: list[dict[str, Any]]) -> None:
        """``gap_closed`` per row: attenuation / the reference row's, per motor."""
        ref = next((r for r in rows if r["reference"]), None)
        ref_db = ref["per_motor_db"] if ref is not None else {}
        stats = dict(resamples=self.bootstrap_resamples, seed=self.bootstrap_seed,
                     confidence=self.confidence)
        for r in rows:
            if r["reference"]:
                r["gap_closed"] = {"iqm": 1.0, "ci": [1.0, 1.0],
                                   "motors": len(r["per_motor_db"])}
                continue
            cell_db, cell_motor = r["_cells"]
            gap = [v / ref_db[m] if ref_db.get(m, 0.0) > 0.0 else math.nan
                   for v, m in zip(cell_db, cell_motor)]
            r["gap_closed"] = motor_mean_bootstrap(gap, cell_motor, **stats)

    def _ranks(self, per_motor: Mapping[str, Mapping[str, float]],
               estimates: Mapping[str, float],
               probability: Mapping[tuple[str, str], float] | None = None
               ) -> dict[str, int | None]:
        return paired_ranks(estimates, per_motor, confidence=self.rank_confidence,
                            decisive_share=self.decisive_share,
                            min_motors=self.min_paired_motors,
                            resamples=self.bootstrap_resamples, seed=self.bootstrap_seed,
                            probability=probability)

    def _compare(self, rows: list[dict[str, Any]]) -> None:
        """P(improvement) and effect sizes between rows; paired ranks (overall,
        where a board P of at least ``decisive_share`` also decides, and per
        evaluation seed)."""
        self._improvements(rows)
        ranked = [r for r in rows if not (r["reference"] or r["privileged"] or r["zero_shot"])]
        est = {r["name"]: r["attenuation_db"]["iqm"] for r in ranked}
        p = {(a["name"], b["name"]): a["probability_of_improvement"][b["name"]]
             for a in ranked for b in ranked if a is not b}
        ranks = self._ranks({r["name"]: r["per_motor_db"] for r in ranked}, est, p)
        seeds = sorted({s for r in ranked for s in r["_seed_motor_db"]})
        by_seed = {}
        for s in seeds:
            per = {r["name"]: r["_seed_motor_db"].get(s, {}) for r in ranked}
            by_seed[s] = self._ranks(per, {
                n: iqm(list(v.values())) if v else math.nan
                for n, v in per.items()})
        is_ranked = {id(r) for r in ranked}
        for r in rows:
            r["rank"] = ranks.get(r["name"]) if id(r) in is_ranked else None
            r["rank_by_seed"] = {str(s): by_seed[s].get(r["name"]) for s in seeds} \
                if id(r) in is_ranked else {}
        self._notes(rows)
        for r in rows:
            r.pop("_cells", None)
            r.pop("_seed_motor_db", None)

    def _improvements(self, rows: list[dict[str, Any]]) -> None:
        """P(improvement) and the effect in dB of every pair of rows."""
        stats = dict(resamples=self.bootstrap_resamples, seed=self.bootstrap_seed,
                     confidence=self.confidence)
        for r in rows:
            r["probability_of_improvement"], r["effect_db"] = {}, {}
        for i, a in enumerate(rows):
            for b in rows[i + 1:]:
                (xa, ma), (xb, mb) = a["_cells"], b["_cells"]
                p = probability_of_improvement(
                    [-v for v in xa], ma, [-v for v in xb], mb, interval=False, **stats)["p"]
                a["probability_of_improvement"][b["name"]] = p
                b["probability_of_improvement"][a["name"]] = 1.0 - p
                eff = median_difference(a["per_motor_db"], b["per_motor_db"], **stats)
                a["effect_db"][b["name"]] = {"median": eff["median"], "ci": eff["ci"]}
                b["effect_db"][a["name"]] = {"median": -eff["median"],
                                             "ci": [-eff["ci"][1], -eff["ci"][0]]}

    def _notes(self, rows: list[dict[str, Any]]) -> None:
        """Each row's ``notes``, stated from the table's own data."""
        none = next((r for r in rows if r["spec"] == REFERENCE_POLICY and not r["reference"]),
                    None)
        for r in rows:
            notes = []
            sl = r["step_losses"]
            if not r["reference"] and sl["runs"] and sl["runs_lost"] == sl["runs"]:
                if none is not None and none["step_losses"]["runs_lost"] == \
                        none["step_losses"]["runs"]:
                    notes.append("loses every run, as `none` does: the rotor falls behind "
                                 "the command at every speed of this suite on these motors")
                elif none is not None:
                    held = none["step_losses"]["runs"] - none["step_losses"]["runs_lost"]
                    notes.append(f"loses every run, where `none` holds {held} of "
                                 f"{none['step_losses']['runs']}")
                else:
                    notes.append("loses every run")
            n = r["cells"]["split"]
            if r["learned"] and r["coverage"] == 0.0:
                notes.append("not trained for this suite or these speeds: none of the "
                             f"table's {n} cells lies in its training")
            elif r["learned"] and r["coverage"] < 1.0:
                notes.append(f"trained on {round(r['coverage'] * n)} of the table's {n} cells"
                             + (f" (under {self.coverage_min:.0%}: unranked)"
                                if r["zero_shot"] else ""))
            errors = [x["error"] for x in r.get("runs", []) if x.get("error")]
            if errors:
                notes.append(f"could not run in {len(errors)} of {sl['runs']} runs, each "
                             f"counted as lost (first: {errors[0]})")
            r["notes"] = notes

    # -- the tables --------------------------------------------------------------------
    def tables(self, entries: Sequence[Mapping[str, Any]]) -> list[dict[str, Any]]:
        """Per suite and split: ``headroom_db``, ``saturated``, ``bound_check`` and
        ``rank_stability`` (module docstring), from the rows alone."""
        out = []
        for suite in self.suites:
            for split in self.splits:
                rows = [e for e in entries if e["suite"] == suite and e["split"] == split]
                if rows:
                    out.append({"suite": suite, "split": split, **table_facts(self, rows)})
        return out


#: The quick board's catalogue motors: a NEMA 11 from its manual, a NEMA 17 whose
#: inertia is estimated, a 0.9 degree NEMA 17.
QUICK_CATALOGUE = ("qsh2818-32-07-006", "ms17hd6p4200", "17hm19-2004s")


def quick_settings() -> dict[str, Any]:
    """The CI variant's settings (v4's module docstring, ``--quick``): v3's quick
    motors, three catalogue motors, two evaluation seeds."""
    return {**QUICK_SETTINGS, "servo_factors": (0.28, 0.56, 1.1), "servo_headline": 2,
            "midband_factors": (0.3, 0.7), "dev_per_preset": 1,
            "eval_seeds": evaluation_seeds(2), "catalogue_motors": QUICK_CATALOGUE}
