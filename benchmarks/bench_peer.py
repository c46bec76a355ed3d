"""sweepedit beside Marching-Primitives (Liu et al., CVPR 2023: superquadrics from a signed
distance field) on the same shapes, in one run, scored by one protocol.

    .venv/bin/python benchmarks/bench_peer.py --shapes ../shared/shapes \\
        --mp-path /path/to/Marching-Primitives-Python --out bench-out/peer/peer.csv \\
        [--methods sweepedit,mp] [--sweepedit-args "--primitives 16"] [--label k16]

Marching-Primitives runs through its MIT-licensed Python port
(github.com/FisherYuuri/Marching-Primitives-Python), which is never copied into this
repository: fetch it anywhere and pass its folder as --mp-path (or SWEEPEDIT_MP_PATH).
Without it the run says how to get it and goes on with sweepedit alone. Only the port's
MPS.py is imported (numpy, scipy, scikit-image); its demo modules (mayavi, plyfile) are
never needed, and are stubbed if MPS.py ever asks for them.

Shapes alternate (sweepedit on shape 1, MP on shape 1, sweepedit on shape 2, ...), each
method in a subprocess of its own, so both pay their imports. Run it on an idle machine:
the 1-minute load average before each run is recorded (`load_avg`).

- sweepedit: `sweepedit fit SHAPE -o OUT.json --quiet ARGS` wall-timed whole
  (`whole_seconds`; it includes the fit command's own 100,000-sample metrics), the fit
  alone read from the JSON's "fit" record (`fit_seconds`); quality from
  `sweepedit eval OUT.json SHAPE --json`.
- mp: a subprocess of this script (--mp-worker) loads the shape with sweepedit's loader
  (normalised: box centre at the origin, longest side 1), computes its signed distance on
  the port's 100^3 grid over [-0.6, 0.6]^3 (laid out as the port's main.py does, values
  clipped at 1.2 grid steps; exact point-to-triangle distance, negative where sweepedit's
  winding-number inside test says inside), calls `mps()` with the port's defaults (only
  its printing off; BLAS held to one thread: with two, its many small SVDs take ~10x as
  long on 2 cores, with the same result) and meshes each superquadric closed.
  `whole_seconds` is that process's wall time, `fit_seconds` the `mps()` call,
  `sdf_seconds` the distance field. Quality: the protocol of
  sweepedit.analysis.metrics applied to the union of superquadrics (IoU on the 64^3 cell
  centres with the exact superquadric inside-outside function; CD-L1, CD-L2, F1@0.05 and
  F1@0.01 between 100,000 area-uniform samples of the union's outer surface and 100,000
  of the shape's, with the same seeds as `sweepedit eval`).

Rows are written as they finish (the CSV is rewritten whole each time), with a Markdown
table of means and medians beside it (OUT.md). A rerun with the same --out and --label
skips the (method, shape) pairs already done; failed ones are run again. Fits and MP
parameters are kept under --workdir (default: OUT's folder, OUT_runs/LABEL/METHOD/).
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import importlib
import importlib.util
import io
import json
import math
import os
import shlex
import statistics
import subprocess
import sys
import time
import types
from collections.abc import Callable, Sequence
from functools import lru_cache, partial
from pathlib import Path
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np

if TYPE_CHECKING:
    from sweepedit.io.shapes import Shape

REPO = Path(__file__).resolve().parents[1]
METHODS = ("sweepedit", "mp")
MP_ENV = "SWEEPEDIT_MP_PATH"
MP_HINT = ("Marching-Primitives skipped: its Python port was not found; fetch "
           "FisherYuuri/Marching-Primitives-Python (git clone "
           "https://github.com/FisherYuuri/Marching-Primitives-Python, outside this "
           f"repository) and pass its folder as --mp-path (or set {MP_ENV}).")
# Modules the port's demos import; MPS.py itself does not, but a stub keeps them harmless.
DEMO_MODULES = ("mayavi", "plyfile")

# The distance field, as the port's main.py lays it out.
GRID_SIZE = 100
GRID_HALF = 0.6
TRUNCATION_STEPS = 1.2
# Superquadric exponents below this are raised to it (as the port's own display does):
# an exponent of 0 (the bound of its fit) would make 2/eps infinite.
EPS_MIN = 0.007
# Cells per edge of the cube grid that each superquadric's mesh is projected from: chords
# of a sphere of radius r sag at most ~2e-4 r, far below the 0.01 of the strictest F1.
MESH_CELLS = 40

N_SAMPLES = 100_000
COLUMNS = ("label", "method", "shape", "status", "n_primitives", "iou", "cd_l1", "cd_l2",
           "f1_0.05", "f1_0.01", "fit_seconds", "whole_seconds", "sdf_seconds",
           "mesh_seconds", "eval_seconds", "load_avg", "args", "finished", "error")
QUALITY = ("iou", "cd_l1", "cd_l2", "f1_0.05", "f1_0.01")


# --------------------------------------------------------------------------- superquadrics


class Superquadric(NamedTuple):
    """One superquadric of the port: exponents (eps1, eps2), half-axes (3,), rotation
    (3, 3) and centre (3,); world = rotation @ local + translation."""

    eps: np.ndarray
    scale: np.ndarray
    rotation: np.ndarray
    translation: np.ndarray

    @classmethod
    def from_params(cls, params: Sequence[float]) -> Superquadric:
        """From the port's 11 numbers: eps1, eps2, a1, a2, a3, ZYX Euler angles, centre."""
        p = np.asarray(params, dtype=np.float64).reshape(11)
        return cls(np.maximum(p[0:2], EPS_MIN), p[2:5].copy(), euler_zyx_matrix(p[5:8]),
                   p[8:11].copy())


def euler_zyx_matrix(euler: Sequence[float]) -> np.ndarray:
    """Rotation Rz(e0) @ Ry(e1) @ Rx(e2), the port's eul2rotm: (3,) -> (3, 3)."""
    z, y, x = (float(v) for v in euler)
    cz, sz, cy, sy, cx, sx = np.cos(z), np.sin(z), np.cos(y), np.sin(y), np.cos(x), np.sin(x)
    rz = np.array([[cz, -sz, 0.0], [sz, cz, 0.0], [0.0, 0.0, 1.0]])
    ry = np.array([[cy, 0.0, sy], [0.0, 1.0, 0.0], [-sy, 0.0, cy]])
    rx = np.array([[1.0, 0.0, 0.0], [0.0, cx, -sx], [0.0, sx, cx]])
    return rz @ ry @ rx


def inside_outside(local: np.ndarray, eps: np.ndarray, scale: np.ndarray) -> np.ndarray:
    """The superquadric function F of (N, 3) points in its own frame: (N,), <= 1 inside.

    F = (|x/a1|^(2/e2) + |y/a2|^(2/e2))^(e2/e1) + |z/a3|^(2/e1); it overflows to inf far
    out, which is outside all the same.
    """
    u = np.abs(local / scale)
    e1, e2 = float(eps[0]), float(eps[1])
    with np.errstate(over="ignore", divide="ignore", invalid="ignore"):
        xy = u[:, 0] ** (2.0 / e2) + u[:, 1] ** (2.0 / e2)
        return xy ** (e2 / e1) + u[:, 2] ** (2.0 / e1)


def inside_superquadric(points: np.ndarray, sq: Superquadric) -> np.ndarray:
    """Exact inside test of one superquadric: (N, 3) world points -> (N,) bool."""
    local = (np.asarray(points, dtype=np.float64) - sq.translation) @ sq.rotation
    return inside_outside(local, sq.eps, sq.scale) <= 1.0


def inside_superquadrics(points: np.ndarray, sqs: Sequence[Superquadric]) -> np.ndarray:
    """Exact inside test of the union: (N, 3) -> (N,) bool."""
    points = np.asarray(points, dtype=np.float64)
    result = np.zeros(len(points), dtype=bool)
    for sq in sqs:
        todo = np.flatnonzero(~result)
        if todo.size == 0:
            break
        result[todo] = inside_superquadric(points[todo], sq)
    return result


@lru_cache(maxsize=4)
def cube_surface(cells: int) -> tuple[np.ndarray, np.ndarray]:
    """Closed, outward triangle grid on the surface of [-1, 1]^3, `cells` per edge:
    (V, 3) vertices (shared along the cube's edges) and (F, 3) faces."""
    g = np.arange(cells + 1)
    u, v = (a.ravel() for a in np.meshgrid(g, g, indexing="ij"))
    i, j = (a.ravel() for a in np.meshgrid(np.arange(cells), np.arange(cells), indexing="ij"))
    k = i * (cells + 1) + j  # the quad's corner (i, j); (i+1, j) is k + cells + 1
    quads = np.stack([k, k + cells + 1, k + cells + 2, k + 1], axis=1)
    tris = np.concatenate([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]])
    keys, faces = [], []
    for axis in range(3):
        a1, a2 = (axis + 1) % 3, (axis + 2) % 3  # e_a1 x e_a2 = e_axis
        for side in (0, cells):
            key = np.empty((len(u), 3), dtype=np.int64)
            key[:, axis], key[:, a1], key[:, a2] = side, u, v
            faces.append((tris if side else tris[:, ::-1]) + len(u) * len(keys))
            keys.append(key)
    unique, inverse = np.unique(np.concatenate(keys), axis=0, return_inverse=True)
    vertices = unique * (2.0 / cells) - 1.0
    return vertices, inverse.reshape(-1)[np.concatenate(faces)]


def superquadric_mesh(sq: Superquadric,
                      cells: int = MESH_CELLS) -> tuple[np.ndarray, np.ndarray]:
    """A closed triangle mesh of a superquadric's surface: (V, 3) world vertices, (F, 3).

    The cube grid, scaled by the half-axes, is projected along rays from the centre onto
    the surface (a superquadric is star-shaped about its centre and F is homogeneous of
    degree 2/eps1 along rays, so the point q lands at q * F(q)^(-eps1/2)); a box-like
    superquadric keeps the cube's grid, a round one gets a cube-sphere.
    """
    cube, faces = cube_surface(cells)
    q = cube * sq.scale
    local = q * inside_outside(q, sq.eps, sq.scale)[:, None] ** (-float(sq.eps[0]) / 2.0)
    return local @ sq.rotation.T + sq.translation, faces


def superquadric_meshes(sqs: Sequence[Superquadric], cells: int = MESH_CELLS
                        ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """All superquadrics meshed in one soup: vertices (V, 3), faces (F, 3), and the
    superquadric each face belongs to (F,)."""
    if not sqs:
        return np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64), np.zeros(0, dtype=np.int64)
    meshes = [superquadric_mesh(sq, cells) for sq in sqs]
    offsets = np.cumsum([0] + [len(v) for v, _ in meshes[:-1]])
    vertices = np.concatenate([v for v, _ in meshes])
    faces = np.concatenate([f + o for (_, f), o in zip(meshes, offsets, strict=True)])
    owner = np.concatenate([np.full(len(f), i) for i, (_, f) in enumerate(meshes)])
    return vertices, faces, owner


def outer_surface_samples(sqs: Sequence[Superquadric], count: int = N_SAMPLES,
                          seed: int = 0, cells: int = MESH_CELLS) -> np.ndarray:
    """Area-uniform samples on the union's outer surface: -> (count, 3).

    As sweepedit.analysis.metrics.outer_surface_samples does for sweeps: every mesh is
    sampled by area, samples inside another superquadric are dropped and the kept ones
    topped up to `count`.
    """
    from sweepedit.analysis.metrics import union_surface_samples

    if not sqs:
        return np.zeros((0, 3))
    vertices, faces, owner = superquadric_meshes(sqs, cells)
    tests = [partial(inside_superquadric, sq=sq) for sq in sqs]
    return union_surface_samples(vertices, faces, owner, tests, count,
                                 np.random.default_rng(seed))


def score_superquadrics(sqs: Sequence[Superquadric], shape: Shape, n_samples: int = N_SAMPLES,
                        seed: int = 0) -> dict[str, float]:
    """sweepedit's quality protocol for a union of superquadrics (normalised frame): iou,
    cd_l1, cd_l2, f1_0.05, f1_0.01 and n_primitives, with `sweepedit eval`'s seeds."""
    from sweepedit.analysis.metrics import (
        F1_TAUS,
        RESOLUTION,
        chamfer_and_f1,
        iou,
        shape_inside_grid,
    )
    from sweepedit.geometry.inside import grid_points

    target_occ = shape_inside_grid(shape, RESOLUTION)
    pred_occ = inside_superquadrics(grid_points(RESOLUTION), sqs)
    result: dict[str, float] = {"iou": iou(pred_occ, target_occ)}
    pred_samples = outer_surface_samples(sqs, n_samples, seed=seed + 1)
    if len(pred_samples):
        result.update(chamfer_and_f1(pred_samples, shape.surface_samples(n_samples, seed=seed)))
    else:
        result.update({"cd_l1": math.inf, "cd_l2": math.inf,
                       **{f"f1_{tau:g}": 0.0 for tau in F1_TAUS}})
    result["n_primitives"] = len(sqs)
    return result


# --------------------------------------------------------------------------- distance field


def port_voxel_grid(size: int = GRID_SIZE, half: float = GRID_HALF) -> dict[str, Any]:
    """The port's voxelGrid dict, built as its main.py does: 'points' is (3, size^3) with
    x varying fastest (MATLAB's column-major order), the order of the SDF values."""
    lin = np.linspace(-half, half, size)
    x, y, z = np.meshgrid(lin, lin, lin, indexing="ij")
    interval = (2 * half) / (size - 1)
    truncation = TRUNCATION_STEPS * interval
    return {"size": np.full(3, size, dtype=int), "range": np.array([-half, half] * 3),
            "x": lin, "y": lin.copy(), "z": lin.copy(),
            "points": np.stack((x, y, z), axis=3).reshape((-1, 3), order="F").T,
            "interval": interval, "truncation": truncation,
            "disp_range": [-np.inf, truncation],
            "visualizeArclength": 0.01 * np.sqrt(2 * half)}


def truncated_sdf(vertices: np.ndarray, faces: np.ndarray,
                  inside: Callable[[np.ndarray], np.ndarray], points: np.ndarray,
                  truncation: float) -> np.ndarray:
    """Signed distance of (N, 3) points to a triangle mesh clipped to [-truncation,
    truncation], negative where `inside` says so: (N,).

    The exact point-to-triangle distance (libigl) is computed only where it can be below
    the truncation: near a centroid of the mesh split into triangles shorter than two
    truncations (a triangle lies within its circumradius of its centroid). Elsewhere the
    clipped value is the truncation whatever the distance.
    """
    import igl
    import trimesh
    from scipy.spatial import cKDTree

    V = np.ascontiguousarray(vertices, dtype=np.float64)
    F = np.ascontiguousarray(faces, dtype=np.int64)
    P = np.ascontiguousarray(points, dtype=np.float64)
    Vs, Fs = trimesh.remesh.subdivide_to_size(V, F, max_edge=2 * truncation, max_iter=16)
    tri = Vs[Fs]
    centroids = tri.mean(axis=1)
    radius = float(np.linalg.norm(tri - centroids[:, None], axis=2).max())
    reach, _ = cKDTree(centroids).query(P, distance_upper_bound=truncation + radius)
    near = np.flatnonzero(np.isfinite(reach))
    distance = np.full(len(P), truncation)
    if near.size:
        d2 = np.asarray(igl.point_mesh_squared_distance(P[near], V, F)[0])
        distance[near] = np.minimum(np.sqrt(d2), truncation)
    return np.where(inside(P), -distance, distance)


# --------------------------------------------------------------------------- mp worker


def import_mps(mp_path: Path) -> Callable[..., list[np.ndarray]]:
    """The port's `mps` function, from MPS.py in mp_path. The demo-only modules (mayavi,
    plyfile) are stubbed first where they are not installed, in this process only."""
    for name in DEMO_MODULES:
        if importlib.util.find_spec(name) is None:
            stub = sys.modules[name] = types.ModuleType(name)
            if name == "mayavi":
                stub.mlab = sys.modules["mayavi.mlab"] = types.ModuleType("mayavi.mlab")
    sys.path.insert(0, str(mp_path))
    try:
        return importlib.import_module("MPS").mps
    finally:  # its utils.py and superquadrics.py must not shadow other modules
        sys.path.remove(str(mp_path))


def mp_worker(shape_path: Path, mp_path: Path, out: Path) -> None:
    """Marching-Primitives on one shape (the timed whole of the mp method): writes out
    (JSON) with the superquadrics' 11 parameters each and the stage seconds."""
    from threadpoolctl import threadpool_limits

    from sweepedit.io.shapes import load_shape

    mps = import_mps(mp_path)
    t0 = time.perf_counter()
    shape = load_shape(shape_path)
    t1 = time.perf_counter()
    grid = port_voxel_grid()
    sdf = truncated_sdf(shape.mesh.vertices, shape.mesh.faces, shape.inside,
                        grid["points"].T, grid["truncation"])
    t2 = time.perf_counter()
    with threadpool_limits(limits=1, user_api="blas"), \
            contextlib.redirect_stdout(io.StringIO()):  # it prints per region regardless
        params = [np.asarray(x, dtype=np.float64).tolist()
                  for x in mps(sdf.copy(), grid, verbose=False)]
    t3 = time.perf_counter()
    superquadric_meshes([Superquadric.from_params(p) for p in params])
    t4 = time.perf_counter()
    record = {"shape": str(shape_path), "superquadrics": params,
              "load_seconds": t1 - t0, "sdf_seconds": t2 - t1, "mps_seconds": t3 - t2,
              "mesh_seconds": t4 - t3}
    out.write_text(json.dumps(record))


# --------------------------------------------------------------------------- runs


def _run(cmd: list[str], timeout: float) -> tuple[float, subprocess.CompletedProcess[str]]:
    """Run cmd, capturing its output: (wall seconds, the finished process)."""
    start = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, check=False)
    return time.perf_counter() - start, proc


def _failure(proc: subprocess.CompletedProcess[str], what: str) -> str:
    lines = [line for line in (proc.stderr or proc.stdout).splitlines() if line.strip()]
    return f"{what} exited {proc.returncode}: {lines[-1] if lines else '(no output)'}"


def run_sweepedit(shape: Path, workdir: Path, sweepedit_bin: str, fit_args: list[str],
                  n_samples: int, seed: int, timeout: float) -> dict[str, Any]:
    """`sweepedit fit` then `sweepedit eval --json` on one shape: a row's figures."""
    out = workdir / f"{shape.stem}.json"
    out.unlink(missing_ok=True)
    cmd = [sweepedit_bin, "fit", str(shape), "-o", str(out), "--quiet", *fit_args]
    whole, proc = _run(cmd, timeout)
    if proc.returncode != 0 or not out.exists():
        raise RuntimeError(_failure(proc, "sweepedit fit"))
    fit_seconds = json.loads(out.read_text())["fit"]["seconds"]
    eval_seconds, proc = _run([sweepedit_bin, "eval", str(out), str(shape), "--json",
                               "--samples", str(n_samples), "--seed", str(seed)], timeout)
    if proc.returncode != 0:
        raise RuntimeError(_failure(proc, "sweepedit eval"))
    metrics = json.loads(proc.stdout.strip().splitlines()[-1])
    return {**{k: metrics[k] for k in (*QUALITY, "n_primitives")},
            "fit_seconds": fit_seconds, "whole_seconds": whole, "eval_seconds": eval_seconds}


def run_mp(shape: Path, workdir: Path, mp_path: Path, n_samples: int, seed: int,
           timeout: float) -> dict[str, Any]:
    """The mp worker on one shape in a subprocess, then the superquadrics scored here."""
    from sweepedit.io.shapes import load_shape

    out = workdir / f"{shape.stem}.json"
    out.unlink(missing_ok=True)
    cmd = [sys.executable, str(Path(__file__).resolve()), "--mp-worker", str(shape),
           "--mp-path", str(mp_path), "--worker-out", str(out)]
    whole, proc = _run(cmd, timeout)
    if proc.returncode != 0 or not out.exists():
        raise RuntimeError(_failure(proc, "Marching-Primitives"))
    record = json.loads(out.read_text())
    start = time.perf_counter()
    sqs = [Superquadric.from_params(p) for p in record["superquadrics"]]
    metrics = score_superquadrics(sqs, load_shape(shape), n_samples, seed)
    return {**metrics, "fit_seconds": record["mps_seconds"], "whole_seconds": whole,
            "sdf_seconds": record["sdf_seconds"], "mesh_seconds": record["mesh_seconds"],
            "eval_seconds": time.perf_counter() - start}


# --------------------------------------------------------------------------- tables


def read_rows(path: Path) -> list[dict[str, str]]:
    """Rows of an earlier run's CSV (none if it does not exist)."""
    if not path.exists():
        return []
    with path.open(newline="", encoding="utf-8") as f:
        return list(csv.DictReader(f))


def write_rows(path: Path, rows: Sequence[dict[str, Any]]) -> None:
    """The CSV, rewritten whole and atomically."""
    from sweepedit.io.params import atomic_write_text

    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, fieldnames=COLUMNS, extrasaction="ignore",
                            lineterminator="\n")
    writer.writeheader()
    for row in rows:
        writer.writerow({k: _cell(row.get(k)) for k in COLUMNS})
    atomic_write_text(path, buffer.getvalue())


def _cell(value: object) -> str:
    if value is None:
        return ""
    if isinstance(value, float):
        return f"{value:.6g}" if math.isfinite(value) else str(value)
    return str(value)


def _number(text: object) -> float | None:
    try:
        value = float(str(text))
    except ValueError:
        return None
    return value if math.isfinite(value) else None


def markdown(rows: Sequence[dict[str, Any]]) -> str:
    """Means and medians per label and method over the shapes that every method of the
    label finished, then the per-shape figures."""
    figures = (*QUALITY, "n_primitives", "fit_seconds", "whole_seconds", "sdf_seconds")
    heads = ("IoU", "CD-L1", "CD-L2", "F1@0.05", "F1@0.01", "prims", "fit s", "whole s",
             "SDF s")
    ok = [r for r in rows if r.get("status") == "ok"]
    lines = ["# sweepedit beside Marching-Primitives", ""]
    for label in sorted({str(r["label"]) for r in ok}):
        mine = [r for r in ok if r["label"] == label]
        methods = [m for m in METHODS if any(r["method"] == m for r in mine)]
        common = set.intersection(*({r["shape"] for r in mine if r["method"] == m}
                                    for m in methods))
        args = sorted({str(r.get("args", "")) for r in mine if r["method"] == "sweepedit"})
        lines += [f"## {label}", "",
                  f"{len(common)} shapes done by {', '.join(methods)}"
                  + (f"; sweepedit fit args: `{' '.join(args)}`" if any(args) else ""), "",
                  "| method | stat | " + " | ".join(heads) + " |",
                  "|---|---|" + "---:|" * len(heads)]
        for method in methods:
            sel = [r for r in mine if r["method"] == method and r["shape"] in common]
            for stat, fn in (("mean", statistics.fmean), ("median", statistics.median)):
                cells = []
                for key in figures:
                    values = [v for r in sel if (v := _number(r.get(key))) is not None]
                    cells.append(_fmt(key, fn(values)) if values else "")
                lines.append(f"| {method} | {stat} | " + " | ".join(cells) + " |")
        lines += ["", "| shape | method | " + " | ".join(heads) + " |",
                  "|---|---|" + "---:|" * len(heads)]
        for shape in sorted({r["shape"] for r in mine}):
            for r in (r for m in methods for r in mine if r["shape"] == shape
                      and r["method"] == m):
                cells = [_fmt(k, v) if (v := _number(r.get(k))) is not None else ""
                         for k in figures]
                lines.append(f"| {shape} | {r['method']} | " + " | ".join(cells) + " |")
        lines.append("")
    return "\n".join(lines)


def _fmt(key: str, value: float) -> str:
    if key == "n_primitives":
        return f"{value:.1f}" if value != int(value) else f"{value:.0f}"
    if key.startswith("cd_"):
        return f"{value:.5f}"
    if key.endswith("seconds"):
        return f"{value:.1f}"
    return f"{value:.4f}"


# --------------------------------------------------------------------------- main


def find_shapes(inputs: Sequence[str]) -> list[Path]:
    """Shape files of the given files and folders (a folder: its supported files, sorted)."""
    from sweepedit.io.shapes import SUPPORTED_EXTENSIONS

    shapes: list[Path] = []
    for item in inputs:
        path = Path(item)
        if path.is_dir():
            shapes += sorted(p for p in path.iterdir()
                             if p.is_file() and p.suffix.lower() in SUPPORTED_EXTENSIONS)
        elif path.is_file():
            shapes.append(path)
        else:
            raise SystemExit(f"bench_peer: {path}: no such file or folder")
    return shapes


def find_port(option: str | None) -> Path | None:
    """The port's folder (holding MPS.py) from --mp-path or SWEEPEDIT_MP_PATH, or None."""
    text = option or os.environ.get(MP_ENV)
    if not text:
        return None
    path = Path(text).expanduser().resolve()
    if not (path / "MPS.py").is_file():
        print(f"bench_peer: no MPS.py in {path}", file=sys.stderr)
        return None
    if path.is_relative_to(REPO):
        print(f"bench_peer: warning: the port at {path} lies inside this repository; keep it "
              "outside (it must not be committed here)", file=sys.stderr)
    return path


def build_parser() -> argparse.ArgumentParser:
    """The command line (see the module docstring)."""
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--shapes", nargs="+", default=[str(REPO.parent / "shared" / "shapes")],
                   help="shape files and/or folders (default: ../shared/shapes)")
    p.add_argument("--out", default="bench-out/peer/peer.csv",
                   help="CSV to write (a Markdown summary goes beside it, .md)")
    p.add_argument("--mp-path", default=None,
                   help=f"folder of the Marching-Primitives Python port (or ${MP_ENV})")
    p.add_argument("--methods", default="sweepedit,mp",
                   help="comma-separated: sweepedit, mp (default both)")
    p.add_argument("--sweepedit-args", default="",
                   help='options passed to `sweepedit fit`, e.g. "--primitives 16"')
    p.add_argument("--label", default="default", help="names this run's rows (resume key)")
    p.add_argument("--workdir", default=None, help="fits and MP parameters (default: OUT_runs)")
    p.add_argument("--sweepedit-bin", default=None,
                   help="the sweepedit command (default: the one beside this Python)")
    p.add_argument("--samples", type=int, default=N_SAMPLES,
                   help="surface samples per side (100,000: the protocol's)")
    p.add_argument("--seed", type=int, default=0, help="metric sampling seed (0)")
    p.add_argument("--timeout", type=float, default=3600.0, help="seconds per command")
    p.add_argument("--mp-worker", default=None, help=argparse.SUPPRESS)
    p.add_argument("--worker-out", default=None, help=argparse.SUPPRESS)
    return p


def main(argv: Sequence[str] | None = None) -> int:
    """Run the benchmark; 0 when it ran (failed shapes are rows with status 'error')."""
    args = build_parser().parse_args(argv)
    if args.mp_worker:
        mp_worker(Path(args.mp_worker), Path(args.mp_path), Path(args.worker_out))
        return 0
    methods = [m.strip() for m in args.methods.split(",") if m.strip()]
    if not methods or set(methods) - set(METHODS):
        raise SystemExit(f"bench_peer: --methods takes {', '.join(METHODS)}; got "
                         f"{args.methods!r}")
    port = find_port(args.mp_path) if "mp" in methods else None
    if "mp" in methods and port is None:
        print(MP_HINT)
        methods.remove("mp")
    if not methods:
        return 0
    shapes = find_shapes(args.shapes)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    workdir = Path(args.workdir) if args.workdir else out.parent / f"{out.stem}_runs"
    sweepedit_bin = args.sweepedit_bin or str(Path(sys.executable).parent / "sweepedit")
    if not args.sweepedit_bin and not Path(sweepedit_bin).exists():
        sweepedit_bin = "sweepedit"
    fit_args = shlex.split(args.sweepedit_args)

    rows = read_rows(out)
    done = {(r["label"], r["method"], r["shape"]) for r in rows if r.get("status") == "ok"}
    load = os.getloadavg()[0]
    cores = os.cpu_count() or 1
    print(f"bench_peer: {len(shapes)} shapes x {', '.join(methods)}, label {args.label!r}, "
          f"load {load:.2f} on {cores} cores"
          + (" (not idle: timings will suffer)" if load > 0.25 * cores else ""))
    for shape in shapes:
        for method in methods:
            key = (args.label, method, shape.stem)
            if key in done:
                continue
            folder = workdir / args.label / method
            folder.mkdir(parents=True, exist_ok=True)
            row: dict[str, Any] = {"label": args.label, "method": method, "shape": shape.stem,
                                   "load_avg": round(os.getloadavg()[0], 2),
                                   "args": args.sweepedit_args if method == "sweepedit" else ""}
            try:
                if method == "sweepedit":
                    row.update(run_sweepedit(shape, folder, sweepedit_bin, fit_args,
                                             args.samples, args.seed, args.timeout))
                else:
                    assert port is not None
                    row.update(run_mp(shape, folder, port, args.samples, args.seed,
                                      args.timeout))
                row["status"] = "ok"
            except Exception as exc:  # a row says what failed; the run goes on
                row.update(status="error", error=" ".join(str(exc).split())[:300])
            row["finished"] = time.strftime("%Y-%m-%dT%H:%M:%S")
            rows = [r for r in rows if (r["label"], r["method"], r["shape"]) != key] + [row]
            write_rows(out, rows)
            out.with_suffix(".md").write_text(markdown(rows), encoding="utf-8")
            print(_progress_line(row), flush=True)
    print(f"bench_peer: {out} and {out.with_suffix('.md')}")
    return 0


def _progress_line(row: dict[str, Any]) -> str:
    if row["status"] != "ok":
        return f"{row['shape']:<14} {row['method']:<9} ERROR {row['error']}"
    sdf = f", SDF {row['sdf_seconds']:.1f} s" if row.get("sdf_seconds") is not None else ""
    return (f"{row['shape']:<14} {row['method']:<9} {row['n_primitives']:>3} prims  "
            f"IoU {row['iou']:.4f}  CD-L1 {row['cd_l1']:.5f}  F1@0.05 {row['f1_0.05']:.4f}  "
            f"F1@0.01 {row['f1_0.01']:.4f}  fit {row['fit_seconds']:.1f} s, whole "
            f"{row['whole_seconds']:.1f} s{sdf}")


if __name__ == "__main__":
    sys.exit(main())
