"""Scans made from meshes, abstracted and scored against the complete mesh: how much of
a shape sweepedit recovers from points as a scanner gives them.

    .venv/bin/python benchmarks/bench_scans.py --shapes ../shared/shapes \\
        --out bench-out/scans.json [--kinds clean,noisy,view1,views3] [-k 8]

Per shape, from its normalised mesh (seeded, so every run makes the same scans):

- clean: 20,000 points spread evenly over the whole surface;
- noisy: the same with Gaussian noise of 0.5 % of the bounding box's diagonal on every
  point and 5 % of the points replaced by outliers uniform in the box grown by 10 %;
- view1: single-view scans, three per shape: 20,000 rays from a random viewpoint 2.5
  away (a pinhole aimed at the centre, its field of view just covering the unit box),
  the first hit of each ray kept;
- views3: the three views of view1 together.

Each scan is written as an .xyz file and fitted with `sweepedit.fit` (K primitives, the
default settings), then scored with the quality protocol against the complete mesh
(`sweepedit.evaluate`), and by the scan's own score: the share of scan points within 0.01
of the abstraction's surface. A scan that cannot be fitted is a row with its error (a
refusal). Beside each shape's scans, the mesh itself is fitted for the reference. Rows are
printed as they finish and the JSON is rewritten whole each time (a rerun with the same
--out fits only the shapes not in it yet); a Markdown summary (means per kind beside the
mesh fits of the same shapes, refusals) ends the run. Run it alone.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
import zlib
from pathlib import Path

import numpy as np
import trimesh
from scipy.spatial import cKDTree

import sweepedit
from sweepedit.analysis.metrics import outer_surface_samples
from sweepedit.io.shapes import SUPPORTED_EXTENSIONS

POINTS = 20_000
NOISE = 0.005  # of the box's diagonal
OUTLIERS = 0.05
VIEWS = 3
SCAN_TOLERANCE = 0.01


def clean_scan(mesh: trimesh.Trimesh, rng: np.random.Generator) -> np.ndarray:
    points, _ = trimesh.sample.sample_surface_even(mesh, POINTS, seed=int(rng.integers(2**31)))
    if len(points) < POINTS:  # even sampling may fall short: top up uniformly
        extra, _ = trimesh.sample.sample_surface(mesh, POINTS - len(points),
                                                 seed=int(rng.integers(2**31)))
        points = np.concatenate([points, extra])
    return np.asarray(points)


def noisy_scan(clean: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    lower, upper = clean.min(axis=0), clean.max(axis=0)
    diagonal = float(np.linalg.norm(upper - lower))
    points = clean + rng.normal(scale=NOISE * diagonal, size=clean.shape)
    n_out = round(OUTLIERS * len(points))
    grow = 0.1 * (upper - lower)
    points[rng.choice(len(points), n_out, replace=False)] = rng.uniform(
        lower - grow, upper + grow, size=(n_out, 3))
    return points


def view_scan(mesh: trimesh.Trimesh, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """20,000 first hits of rays from a random viewpoint 2.5 from the centre, through a
    square pinhole image covering the unit box: (hits (H, 3), the viewpoint (3,))."""
    direction = rng.normal(size=3)
    eye = 2.5 * direction / np.linalg.norm(direction)
    forward = -eye / np.linalg.norm(eye)
    up = np.array([0.0, 0.0, 1.0]) if abs(forward[2]) < 0.9 else np.array([0.0, 1.0, 0.0])
    right = np.cross(forward, up)
    right /= np.linalg.norm(right)
    up = np.cross(right, forward)
    half = np.tan(np.arcsin(0.87 / 2.5))  # the unit box's circumsphere fills the view
    side = int(np.ceil(np.sqrt(POINTS * 4)))  # more rays than hits: many miss
    u, v = np.meshgrid(np.linspace(-half, half, side), np.linspace(-half, half, side))
    rays = forward + u.reshape(-1, 1) * right + v.reshape(-1, 1) * up
    rays /= np.linalg.norm(rays, axis=1, keepdims=True)
    # In chunks: trimesh tests each ray against every triangle of the boxes it crosses,
    # and 80,000 rays at once through a 100k-face mesh asked for more than 24 GiB.
    found = [mesh.ray.intersects_location(np.repeat(eye[None], len(chunk), axis=0), chunk,
                                          multiple_hits=False)[0]
             for chunk in np.array_split(rays, max(1, len(rays) // 2000))]
    hits = np.concatenate([f.reshape(-1, 3) for f in found])
    if len(hits) > POINTS:
        hits = hits[rng.choice(len(hits), POINTS, replace=False)]
    return np.asarray(hits), eye


def scan_score(abstraction: sweepedit.Abstraction, points: np.ndarray) -> float:
    """Share of the scan's points within SCAN_TOLERANCE of the union's outer surface."""
    surface = outer_surface_samples(abstraction.primitives, 100_000, seed=3)
    if not len(surface):
        return 0.0
    distance, _ = cKDTree(surface).query(points)
    return float(np.mean(distance <= SCAN_TOLERANCE))


def fit_row(name: str, kind: str, points: np.ndarray | None, mesh_shape: object, k: int,
            workdir: Path) -> dict:
    """Fit a scan (points in the mesh's normalised frame; None: the mesh itself)."""
    row: dict = {"shape": name, "kind": kind}
    started = time.perf_counter()
    try:
        if points is None:
            source = mesh_shape
        else:
            path = workdir / f"{name}_{kind}.xyz"
            np.savetxt(path, points, fmt="%.6f")
            source = sweepedit.load_shape(path)
        abstraction = sweepedit.fit(source, k, progress=False)
        seconds = time.perf_counter() - started
        # The scan's points are in the mesh's normalised frame, which the scan's own
        # normalisation maps to: score its primitives in the mesh's frame.
        if points is not None:
            own = source.normalization
            for p in abstraction.primitives:
                p.control_points = own.to_original(p.control_points)
                p.a, p.b = p.a * own.scale, p.b * own.scale
            abstraction.normalization = mesh_shape.normalization
        metrics = sweepedit.evaluate(abstraction, mesh_shape).to_dict()
        row.update(metrics, seconds=seconds)
        if points is not None:
            row["scan_score"] = scan_score(abstraction, points)
    except sweepedit.SweepeditError as exc:
        row["error"] = str(exc)
        row["seconds"] = time.perf_counter() - started
    return row


def summary(rows: list[dict]) -> str:
    mesh = {r["shape"]: r for r in rows if r["kind"] == "mesh" and "error" not in r}
    lines = ["| kind | scans | refused | IoU | CD-L1 | F1@0.05 | F1@0.01 | scan score | "
             "mesh IoU | mesh CD-L1 | time / mesh time (median) |",
             "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for kind in ("clean", "noisy", "view1", "views3"):
        mine = [r for r in rows if r["kind"] == kind]
        if not mine:
            continue
        done = [r for r in mine if "error" not in r and r["shape"] in mesh]

        def mean(key: str, source: list[dict]) -> str:
            values = [r[key] for r in source if key in r]
            return f"{statistics.mean(values):.4f}" if values else "-"

        reference = [mesh[r["shape"]] for r in done]
        ratio = [r["seconds"] / mesh[r["shape"]]["seconds"] for r in done]
        lines.append(f"| {kind} | {len(mine)} | {len(mine) - len(done)} | {mean('iou', done)} | "
                     f"{mean('cd_l1', done)} | {mean('f1_0.05', done)} | "
                     f"{mean('f1_0.01', done)} | {mean('scan_score', done)} | "
                     f"{mean('iou', reference)} | {mean('cd_l1', reference)} | "
                     f"{statistics.median(ratio):.2f} |" if ratio else
                     f"| {kind} | {len(mine)} | {len(mine) - len(done)} | - | - | - | - | - | "
                     "- | - | - |")
    return "\n".join(lines)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--shapes", type=Path, required=True)
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--kinds", default="clean,noisy,view1,views3")
    parser.add_argument("-k", type=int, default=8)
    args = parser.parse_args()
    kinds = args.kinds.split(",")
    workdir = args.out.with_suffix("")
    workdir.mkdir(parents=True, exist_ok=True)
    # A rerun with the same --out goes on where the last one stopped.
    rows: list[dict] = json.loads(args.out.read_text())["rows"] if args.out.is_file() else []
    done = {r["shape"] for r in rows}
    for path in sorted(p for p in args.shapes.iterdir()
                       if p.suffix.lower() in SUPPORTED_EXTENSIONS and p.stem not in done):
        rng = np.random.default_rng(zlib.crc32(path.stem.encode()))  # the same scans each run
        shape = sweepedit.load_shape(path)
        mesh = shape.surface
        name = path.stem
        rows.append(fit_row(name, "mesh", None, shape, args.k, workdir))
        clean = clean_scan(mesh, rng)
        views = [view_scan(mesh, rng)[0] for _ in range(VIEWS)] if {"view1", "views3"} & set(
            kinds) else []
        scans = {"clean": [clean], "noisy": [noisy_scan(clean, rng)], "view1": views,
                 "views3": [np.concatenate(views)] if views else []}
        for kind in kinds:
            for i, points in enumerate(scans[kind]):
                label = kind if len(scans[kind]) == 1 else f"{kind}_{i}"
                row = fit_row(name, label, points, shape, args.k, workdir)
                row["kind"] = kind
                rows.append(row)
        for row in rows[-(1 + sum(len(scans[k]) for k in kinds)):]:
            brief = row.get("error") or (f"IoU {row['iou']:.3f} CD-L1 {row['cd_l1']:.4f} "
                                         f"F1@0.01 {row['f1_0.01']:.3f}"
                                         + (f" scan {row['scan_score']:.3f}"
                                            if "scan_score" in row else ""))
            print(f"{name:14s} {row['kind']:7s} {row['seconds']:5.1f} s  {brief}", flush=True)
        args.out.write_text(json.dumps({"rows": rows}, indent=1))
    print()
    print(summary(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
