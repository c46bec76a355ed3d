"""How faithfully a .blend export draws the primitives (docs/blender.md).

For each parameter file in a folder: export it to .blend (sweepedit.io.blend_export, at
resolution scale 4 by default), let Blender turn each curve object into a mesh (its
evaluated surface, caps included) and compare it, primitive by primitive, with the exact
inside test:

* IoU64: on the cell centres of the 64^3 grid over [-0.5, 0.5]^3 (grid_points(64)),
  inside the Blender mesh by its generalised winding number. Coarse for thin primitives
  (a leg a few cells wide loses or gains whole cells at its rim).
* IoUbox: on a grid of 128 cells along the longest side of the primitive's bounding box
  (cubic cells, the box padded by two cells): the same test at a resolution relative to
  the primitive, which says more about thin ones.
* volume error: |V_blender / V - 1| against the closed form (geometry/volumes.py), only
  for primitives that do not fold.
* round trip: the largest difference of any parameter after export_blend -> read_blend.
* seconds: export_blend's wall time for the shape (one Blender subprocess).

    python benchmarks/bench_blender.py bench-out/k8_ax20s/params [--scale 4] [--limit N]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from sweepedit.geometry.inside import grid_points, inside_primitive
from sweepedit.geometry.model import folds_onto_itself
from sweepedit.geometry.volumes import closed_form_volume
from sweepedit.io.blend_export import blend_meshes, export_blend, read_blend
from sweepedit.io.occupancy import winding_numbers
from sweepedit.io.params import read_abstraction

BOX_CELLS = 128


def iou(a: np.ndarray, b: np.ndarray) -> float:
    union = int(np.count_nonzero(a | b))
    return 1.0 if union == 0 else int(np.count_nonzero(a & b)) / union


def box_grid(vertices: np.ndarray) -> np.ndarray:
    lo, hi = vertices.min(axis=0), vertices.max(axis=0)
    h = float(np.max(hi - lo)) / BOX_CELLS
    lo, hi = lo - 2 * h, hi + 2 * h
    axes = [np.arange(lo[i] + h / 2, hi[i], h) for i in range(3)]
    return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)


def max_param_error(a: object, b: object) -> float:
    err = 0.0
    for p, q in zip(a.primitives, b.primitives, strict=True):
        err = max(err, float(np.max(np.abs(p.control_points - q.control_points))),
                  abs(p.a - q.a), abs(p.b - q.b), abs(p.degree - q.degree),
                  max((abs(x - y) for x, y in zip(p.scaling, q.scaling, strict=True)),
                      default=0.0))
    return err


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("folder", type=Path)
    parser.add_argument("--scale", type=float, default=4.0, help="resolution scale")
    parser.add_argument("--limit", type=int, default=None)
    args = parser.parse_args(argv)
    files = sorted(args.folder.glob("*.json"))[:args.limit]
    grid = grid_points(64)
    rows, seconds, trips = [], [], []
    print("| shape | primitive | d | profile | folds | IoU64 | IoUbox | volume error |")
    print("|---|---|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as work:
        for path in files:
            abstraction = read_abstraction(path)
            out = Path(work) / f"{path.stem}.blend"
            t0 = time.perf_counter()
            report = export_blend(abstraction, out, resolution_scale=args.scale)
            seconds.append(time.perf_counter() - t0)
            meshes = blend_meshes(out)
            trips.append(max_param_error(abstraction, read_blend(out)))
            for prim, note, (_, vertices, faces) in zip(abstraction.primitives,
                                                        report.primitives, meshes, strict=True):
                folds = folds_onto_itself(prim)
                inside = np.abs(winding_numbers(vertices, faces, grid)) > 0.5
                iou64 = iou(inside, inside_primitive(grid, prim))
                box = box_grid(vertices)
                ioubox = iou(np.abs(winding_numbers(vertices, faces, box)) > 0.5,
                             inside_primitive(box, prim))
                tri = vertices[faces]
                volume = float(np.einsum("ij,ij->", tri[:, 0],
                                         np.cross(tri[:, 1], tri[:, 2]))) / 6.0
                verr = None if folds else abs(volume / closed_form_volume(prim) - 1.0)
                kind = note.profile + (f" ({note.profile_error:.1e})" if note.approximated
                                       else "")
                rows.append((iou64, ioubox, verr, folds, note))
                print(f"| {path.stem} | {prim.name} | {prim.degree:.2f} | {kind} | "
                      f"{'yes' if folds else ''} | {iou64:.4f} | {ioubox:.4f} | "
                      + (f"{verr:.2e}" if verr is not None else "-") + " |", flush=True)
    plain = [r for r in rows if not r[3]]
    print()
    print(f"{len(files)} shapes, {len(rows)} primitives ({len(rows) - len(plain)} fold), "
          f"resolution scale {args.scale:g}")
    for label, sel in (("all", rows), ("not folding", plain)):
        if not sel:
            continue
        i64 = [r[0] for r in sel]
        ibox = [r[1] for r in sel]
        print(f"- {label} ({len(sel)}): IoU64 min {min(i64):.4f}, median "
              f"{statistics.median(i64):.4f}, >= 0.98: {np.mean(np.array(i64) >= 0.98):.1%}; "
              f"IoUbox min {min(ibox):.4f}, median {statistics.median(ibox):.4f}, >= 0.98: "
              f"{np.mean(np.array(ibox) >= 0.98):.1%}")
    verrs = [r[2] for r in plain]
    if verrs:
        print(f"- volume error (not folding): max {max(verrs):.2e}, median "
              f"{statistics.median(verrs):.2e}")
    approx = [r[4].profile_error for r in rows if r[4].approximated]
    print(f"- approximated profiles: {len(approx)} of {len(rows)}"
          + (f", distance from the superellipse max {max(approx):.1e} of the profile's size"
             if approx else ""))
    print(f"- round trip: max parameter error {max(trips):.1e}")
    print(f"- export_blend: {statistics.median(seconds):.2f} s per shape (median), "
          f"max {max(seconds):.2f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
