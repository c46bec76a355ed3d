"""Fits of damaged copies of closed shapes (issue 19: "the 30 shapes are not the whole
world"): what an open mesh or one with mixed face orientations does to a K = 8 fit.

    .venv/bin/python benchmarks/bench_open_meshes.py --shapes DIR [--names spot.obj ...]
        [--out open_meshes.json]

For each shape, four meshes are written to a temporary folder and fitted with the
default settings (K = 8), each scored with `sweepedit eval`'s protocol against the mesh
it was fitted to (and the capped fit against the open mesh):

- closed: the shape as it is;
- open: the faces on one side of a plane dropped (a bust, a bowl, a cut scan);
- open, capped: the open mesh with a fan over each boundary loop, fitted, scored against
  the open mesh (what a solid abstraction of an open surface can reach there);
- mixed: the faces of one half (x above the median) turned over, as scans and exports
  can come (the winding number of mixed faces cancels inside).
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import networkx as nx
import numpy as np
import trimesh

from sweepedit.analysis.metrics import evaluate
from sweepedit.fitting.fit import FitSettings, fit_abstraction
from sweepedit.io.shapes import load_shape

# (file, axis, share of the extent where the plane cuts, keep the side above it)
CUTS = {"spot.obj": (1, 0.6, False), "man.off": (1, 0.7, True), "bull.off": (2, 0.5, False),
        "hand.obj": (1, 0.3, True)}


def cut_open(mesh: trimesh.Trimesh, axis: int, share: float, above: bool) -> trimesh.Trimesh:
    """The faces of mesh on one side of the plane at `share` of its extent along axis."""
    lo, hi = mesh.bounds
    level = lo[axis] + share * (hi[axis] - lo[axis])
    centre = mesh.triangles_center[:, axis]
    return mesh.submesh([np.flatnonzero(centre > level if above else centre < level)],
                        append=True)


def capped(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    """mesh with a fan around its centroid over each boundary loop."""
    sorted_edges = np.sort(mesh.edges, axis=1)
    unique, counts = np.unique(sorted_edges, axis=0, return_counts=True)
    boundary = {tuple(e) for e in unique[counts == 1]}
    graph = nx.DiGraph([tuple(e) for e in mesh.edges if tuple(sorted(e)) in boundary])
    vertices, faces = [mesh.vertices], [mesh.faces]
    for loop in nx.weakly_connected_components(graph):
        centre = len(np.concatenate(vertices))
        vertices.append(mesh.vertices[list(loop)].mean(axis=0)[None])
        # The cap's faces run against the boundary edges' direction in their faces.
        faces.append(np.array([[b, a, centre] for a, b in graph.subgraph(loop).edges()]))
    return trimesh.Trimesh(np.concatenate(vertices), np.concatenate(faces), process=False)


def mixed(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    """mesh with the faces of one half turned over."""
    faces = mesh.faces.copy()
    half = mesh.triangles_center[:, 0] > np.median(mesh.triangles_center[:, 0])
    faces[half] = faces[half][:, ::-1]
    return trimesh.Trimesh(mesh.vertices, faces, process=False)


def fit_and_score(fit_path: Path, score_path: Path) -> dict[str, float]:
    shape = load_shape(fit_path)
    started = time.perf_counter()
    result = fit_abstraction(shape, FitSettings(primitives=8))
    seconds = time.perf_counter() - started
    metrics = evaluate(result.abstraction, load_shape(score_path))
    return {"iou": metrics["iou"], "cd_l1": metrics["cd_l1"], "f1_0.05": metrics["f1_0.05"],
            "f1_0.01": metrics["f1_0.01"], "seconds": seconds,
            "inside_cells": int(shape.winding_occupancy.sum())}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--shapes", type=Path, required=True, help="folder of the shapes")
    parser.add_argument("--names", nargs="*", default=sorted(CUTS))
    parser.add_argument("--out", type=Path, default=None, help="JSON of every row")
    args = parser.parse_args(argv)
    rows = []
    print(f"{'shape':12} {'variant':14} {'cells':>6} {'IoU':>6} {'CD-L1':>7} {'F1@.05':>6} "
          f"{'F1@.01':>6} {'s':>5}")
    with tempfile.TemporaryDirectory() as tmp:
        for name in args.names:
            mesh = trimesh.load(args.shapes / name, force="mesh")
            mesh.merge_vertices(merge_tex=True, merge_norm=True)  # no seams: real holes only
            opened = cut_open(mesh, *CUTS[name])
            stem = Path(name).stem
            paths = {}
            for variant, made in (("closed", mesh), ("open", opened), ("mixed", mixed(mesh)),
                                  ("open, capped", capped(opened))):
                paths[variant] = Path(tmp) / f"{stem}_{variant.replace(', ', '_')}.ply"
                made.export(paths[variant])
            for variant, path in paths.items():
                score = paths["open"] if variant == "open, capped" else path
                row = {"shape": name, "variant": variant, **fit_and_score(path, score)}
                rows.append(row)
                print(f"{name:12} {variant:14} {row['inside_cells']:6d} {row['iou']:6.3f} "
                      f"{row['cd_l1']:7.4f} {row['f1_0.05']:6.3f} {row['f1_0.01']:6.3f} "
                      f"{row['seconds']:5.1f}", flush=True)
    if args.out:
        args.out.write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
