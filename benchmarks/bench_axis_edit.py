"""Control-point insertion and deletion on real fitted primitives (issue 16, item 1):

    .venv/bin/python benchmarks/bench_axis_edit.py [--params DIR ...] [--limit N] [--json OUT]

Every primitive of the fitted parameter files (default: bench-out/k8/params and
bench-out/k16/params, 30 shapes each; all fits have 3 control points) gets a control
point inserted three times (3 -> 4 -> 5 -> 6, each at a random click on the axis) and
then deleted back (6 -> 5 -> 4 -> 3, an interior point at random). Before each step a
random control point is moved by 10% of the axis length (a drag: a fitted 3-point axis
is one quadratic, for which every step is exact and would show nothing). For each step: the
axis deviation (symmetric Hausdorff distance of 2049 samples per axis) as a share of
the axis length before the step (insertion target: <= 1%, 3 -> 4 exact), the largest
gap between the new scaling f and the old one at the nearest old axis point, whether
the result is valid, and seconds per step. Medians, p95 and maxima per step.

About 4 minutes for the 60 default files on one core; --limit 3 is a smoke run.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from sweepedit.errors import InvalidPrimitiveError
from sweepedit.geometry.axis_edit import (
    axis_deviation,
    axis_length,
    delete_control_point,
    insert_control_point,
)
from sweepedit.geometry.model import SweepPrimitive
from sweepedit.geometry.sweep import axis_points, scaling_factor
from sweepedit.io.params import read_abstraction

ROOT = Path(__file__).resolve().parent.parent
T = np.linspace(0.0, 1.0, 1025)


def scaling_gap(old: SweepPrimitive, new: SweepPrimitive) -> float:
    """Largest |f_new(t') - f_old(t)| with t the old parameter nearest to the new point."""
    a = axis_points(old.control_points[None], T)[0]
    b = axis_points(new.control_points[None], T)[0]
    _, nearest = cKDTree(a).query(b)
    f_new = scaling_factor(new.scaling_array, T)[0]
    f_old = scaling_factor(old.scaling_array, T[nearest])[0]
    return float(np.max(np.abs(f_new - f_old)))


def dragged(p: SweepPrimitive, rng: np.random.Generator) -> SweepPrimitive:
    """p with one random control point moved by 10% of its axis length (a valid result)."""
    for _ in range(20):
        q = p.copy()
        i = int(rng.integers(q.n_control_points))
        direction = rng.normal(size=3)
        q.control_points[i] += 0.1 * axis_length(p.control_points) * direction / np.linalg.norm(
            direction)
        try:
            q.validate()
            return q
        except InvalidPrimitiveError:
            continue
    return p


def step(record: dict, label: str, old: SweepPrimitive, edit) -> SweepPrimitive:
    t0 = time.perf_counter()
    new = edit(old)
    seconds = time.perf_counter() - t0
    try:
        new.validate()
        valid = True
    except InvalidPrimitiveError:
        valid = False
    entry = record.setdefault(label, {"deviation": [], "scaling_gap": [], "seconds": [],
                                      "invalid": 0})
    entry["deviation"].append(axis_deviation(old.control_points, new.control_points)
                              / axis_length(old.control_points))
    entry["scaling_gap"].append(scaling_gap(old, new))
    entry["seconds"].append(seconds)
    entry["invalid"] += int(not valid)
    return new


def summary(values: list[float]) -> dict[str, float]:
    v = np.asarray(values, dtype=np.float64)
    return {"median": float(np.median(v)), "p95": float(np.percentile(v, 95)),
            "max": float(v.max())}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--params", nargs="*", type=Path,
                        default=[ROOT / "bench-out/k8/params", ROOT / "bench-out/k16/params"])
    parser.add_argument("--limit", type=int, default=0, help="files per folder (0: all)")
    parser.add_argument("--seed", type=int, default=16)
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args(argv)
    rng = np.random.default_rng(args.seed)
    record: dict[str, dict] = {}
    files = []
    for folder in args.params:
        found = sorted(folder.glob("*.json")) + sorted(folder.glob("*.txt"))
        files += found[: args.limit] if args.limit else found
    if not files:
        print("no parameter files found", file=sys.stderr)
        return 2
    n_prims = 0
    for path in files:
        for prim in read_abstraction(path).primitives:
            n_prims += 1
            p = prim
            for _ in range(3):
                p = dragged(p, rng)
                n = p.n_control_points
                click = float(rng.uniform())
                p = step(record, f"insert {n} -> {n + 1}", p,
                         lambda q, c=click: insert_control_point(q, c))
            while p.n_control_points > 3:
                p = dragged(p, rng)
                n = p.n_control_points
                index = int(rng.integers(1, n - 1))
                p = step(record, f"delete {n} -> {n - 1}", p,
                         lambda q, i=index: delete_control_point(q, i))
    print(f"{len(files)} files, {n_prims} primitives\n")
    print("| step | axis deviation / length: median, p95, max | scaling gap: median, max "
          "| invalid | ms per step: median, p95 |")
    print("|---|---|---|---|---|")
    out = {}
    for label, entry in record.items():
        d, g, s = (summary(entry[k]) for k in ("deviation", "scaling_gap", "seconds"))
        out[label] = {"deviation": d, "scaling_gap": g, "seconds": s,
                      "invalid": entry["invalid"], "count": len(entry["seconds"])}
        print(f"| {label} | {d['median']:.2e}, {d['p95']:.2e}, {d['max']:.2e} "
              f"| {g['median']:.4f}, {g['max']:.4f} | {entry['invalid']} "
              f"| {1e3 * s['median']:.0f}, {1e3 * s['p95']:.0f} |")
    if args.json is not None:
        args.json.write_text(json.dumps({"files": len(files), "primitives": n_prims,
                                         "steps": out}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
