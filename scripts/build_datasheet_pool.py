"""Build ``stepdamp_env/datasheet_pool.json``: the training pool of real catalogue
motors (:mod:`stepdamp_env.motorpool`), from a public source, none in a scored split.

    python scripts/build_datasheet_pool.py --database stepper-db.ts --commit <its commit>

``--database``: ``src/lib/stepper-db.ts`` of the public ``TheDevMinerTV/stepper-simulator``
project, a table of datasheet values (each entry's comments link its datasheet):
step angle, rated current, holding torque (N*cm), R, L (mH) and rotor inertia
(g*cm^2) for every motor. Left out, each for a stated reason (counted in the
file's ``excluded``):

* every motor of v4's scored ``catalogue`` split: the same model (names compared
  without case and punctuation, either containing the other) or the same five
  datasheet values; every Trinamic QSH motor (the split's other source) and the
  17HS4401 (the docs' worked example);
* a step angle other than 1.8 or 0.9 degrees, L/R outside 0.3-10 ms (what
  catalogue motors span, docs/motors.md);
* a motor whose values repeat an earlier one's (one motor sold under two names).

A motor is in the ``dev`` part when its name's sha256 starts with a byte
divisible by 5, else in ``train``.

``--exclude-relatives`` (written to ``stepdamp_env/datasheet_pool_unrelated.json``,
the pool ``datasheets-unrelated``; the default pool keeps 42 relatives of scored
motors: docs/motors.md) also leaves out every relative of a scored motor:
one of the same series (the model name without its brand, up to its first
``-``, ``_`` or ``(``, five characters or more: another winding of the same
frame) or a near twin (the same step angle, and rated current, holding torque,
R and L each within x1.25: wider than what training draws around a motor); and
a hash-dev motor with a twin in ``train`` (the same series, or within x1.10)
goes to ``train``, so that no dev motor is a twin of a training motor.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import re
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
CATALOGUE = os.path.join(HERE, "..", "stepdamp_env", "bench", "catalogue.json")
OUT = os.path.join(HERE, "..", "stepdamp_env", "datasheet_pool.json")
OUT_UNRELATED = os.path.join(HERE, "..", "stepdamp_env", "datasheet_pool_unrelated.json")
REPO, PATH = "TheDevMinerTV/stepper-simulator", "src/lib/stepper-db.ts"
KEYS = ("step_angle_deg", "rated_current_A", "holding_torque_Nm", "phase_resistance_ohm",
        "phase_inductance_H")
TAU_S = (3e-4, 1e-2)
EXCLUDED_NAMES = ("qsh", "17hs4401")
ENTRY = re.compile(r"\{\s*brand: '([^']*)',\s*model: '([^']*)',(.*?)\n\t\t\t\t\}", re.S)
FIELD = re.compile(r"(\w+): ([0-9.e-]+) as (\w+)")


def split_of(name: str) -> str:
    return "dev" if hashlib.sha256(name.encode()).digest()[0] % 5 == 0 else "train"


def plain(name: str) -> str:
    return re.sub(r"[^a-z0-9]", "", name.lower())


NEAR_KEYS = ("rated_current_A", "holding_torque_Nm", "phase_resistance_ohm", "phase_inductance_H")


def series(name: str) -> str | None:
    """The model's series: its name (without the brand) up to the first -, _ or (."""
    model = name.split(" ", 1)[1] if " " in name else name
    head = plain(re.split(r"[-_(]", model)[0])
    return head if len(head) >= 5 else None


def related(a: dict, b: dict, factor: float) -> bool:
    """The same series, or the same step angle with NEAR_KEYS within ``factor``."""
    sa = series(a["name"])
    return (sa is not None and sa == series(b["name"])) or (
        a["step_angle_deg"] == b["step_angle_deg"]
        and all(1.0 / factor <= a[k] / b[k] <= factor for k in NEAR_KEYS))


def values_key(m: dict) -> tuple:
    return tuple(round(float(m[k]), 9) for k in KEYS)


def database_motors(path: str, commit: str) -> list[dict]:
    with open(path, encoding="utf-8") as fh:
        text = fh.read()
    out = []
    for match in ENTRY.finditer(text):
        brand, model, body = match.groups()
        f = {k: float(v) for k, v, _ in FIELD.findall(body)}
        line = text.count("\n", 0, match.start()) + 1
        out.append({
            "name": f"{brand} {model}",
            "step_angle_deg": f["stepAngle"],
            "rated_current_A": f["ratedCurrent"],
            "holding_torque_Nm": round(f["torque"] * 0.01, 12),
            "phase_resistance_ohm": f["resistance"],
            "phase_inductance_H": round(f["inductance"] * 1e-3, 12),
            "rotor_inertia_kgm2": round(f["rotorInertia"] * 1e-7, 15),
            "source": f"{REPO} on GitHub, {PATH} (commit {commit}), the entry at line {line} "
                      "(torque in N*cm, inductance in mH, rotor inertia in g*cm^2)"})
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--database", required=True)
    p.add_argument("--commit", required=True)
    p.add_argument("--out", default=None,
                   help="default: stepdamp_env/datasheet_pool.json, or with --exclude-relatives "
                        "stepdamp_env/datasheet_pool_unrelated.json")
    p.add_argument("--exclude-relatives", action="store_true")
    a = p.parse_args(argv)
    out = a.out or (OUT_UNRELATED if a.exclude_relatives else OUT)
    with open(CATALOGUE, encoding="utf-8") as fh:
        scored = json.load(fh)
    scored_names = [plain(m["name"]) for m in scored]
    scored_values = {values_key(m) for m in scored}
    excluded = {"scored": 0, "step_angle": 0, "electrical_time_constant": 0, "repeated": 0}
    pool, seen = [], set()
    for m in database_motors(a.database, a.commit):
        name = plain(m["name"])
        if any(s in name or name in s for s in scored_names) \
                or any(s in name for s in EXCLUDED_NAMES) or values_key(m) in scored_values:
            excluded["scored"] += 1
        elif a.exclude_relatives and any(related(m, s, 1.25) for s in scored):
            excluded["scored_relative"] = excluded.get("scored_relative", 0) + 1
        elif m["step_angle_deg"] not in (1.8, 0.9):
            excluded["step_angle"] += 1
        elif not TAU_S[0] <= m["phase_inductance_H"] / m["phase_resistance_ohm"] <= TAU_S[1]:
            excluded["electrical_time_constant"] += 1
        elif values_key(m) in seen:
            excluded["repeated"] += 1
        else:
            seen.add(values_key(m))
            pool.append({**m, "split": split_of(m["name"])})
    if a.exclude_relatives:
        train = [m for m in pool if m["split"] == "train"]
        for m in pool:
            if m["split"] == "dev" and any(related(m, t, 1.10) for t in train):
                m["split"] = "train"
    doc = {"about": "Training pool of real catalogue motors (stepdamp_env.motorpool): "
                    "datasheet values from a public table, none in a scored split; built by "
                    "scripts/build_datasheet_pool.py, which states what was left out and why."
                    + (" Without the scored motors' relatives (--exclude-relatives)."
                       if a.exclude_relatives else ""),
           "excluded": excluded, "motors": pool}
    tmp = out + ".tmp"
    with open(tmp, "w", encoding="utf-8") as fh:
        json.dump(doc, fh, indent=1)
        fh.write("\n")
    os.replace(tmp, out)
    n_dev = sum(m["split"] == "dev" for m in pool)
    print(f"{len(pool)} motors ({len(pool) - n_dev} train, {n_dev} dev); excluded {excluded}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
