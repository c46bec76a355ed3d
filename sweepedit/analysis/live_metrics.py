"""The metrics of DESIGN.md section 3 for an abstraction being edited, recomputing only
what an edit changed.

`evaluate` in metrics.py starts from nothing each time: the union's occupancy on the
64^3 grid, area-uniform samples of its outer surface, then Chamfer and F1 against the
shape's samples (about 2 s for 8 primitives). While editing, one primitive changes at a
time, so `LiveMetrics` keeps, per primitive (keyed by its geometry): its occupancy on the
grid, its surface samples, and which of them lie inside each other primitive; the shape's
grid occupancy, surface samples and their KD-tree are made once.

The protocol is evaluate's with one difference in the sampling: each primitive's surface
is sampled on its own, at a density fixed by the shape (n_samples over the shape's
surface area) and from a seed derived from the primitive's parameters, so that a
primitive's samples do not depend on the others and survive their edits. IoU is
evaluate's exactly; Chamfer and F1 agree with it within sampling noise. The result of
a given abstraction does not depend on the edits that led to it.
"""

from __future__ import annotations

import hashlib
from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np
from scipy.spatial import ConvexHull, QhullError, cKDTree

from sweepedit.analysis.metrics import (
    _SAMPLE_PROFILE_POINTS,
    _SAMPLE_STATIONS,
    F1_TAUS,
    RESOLUTION,
    iou,
    sample_triangles,
    shape_inside_grid,
)
from sweepedit.geometry.inside import grid_points, inside_primitive
from sweepedit.geometry.mesher import sweep_mesh
from sweepedit.geometry.model import GeometryKey, SweepPrimitive, folds_onto_itself
from sweepedit.geometry.solid import solid_pieces

if TYPE_CHECKING:
    from sweepedit.io.shapes import Shape

_Key = GeometryKey


# How far a folding primitive's piece samples are moved outward to tell the solid's
# boundary from the pieces' insides, as a share of the profile's largest radius: the
# pieces' flat facets lie inside the curved surface by up to ~0.2 % of it at the
# sampling resolution, so a smaller nudge left true boundary samples inside (on the 72
# folding primitives of the K = 8 benchmark fits: 0.5 % and 2 % both match samples of
# the boolean solid within sampling noise, median symmetric Chamfer 0.004).
_NUDGE_SHARE = 0.01


def _solid_pieces_mesh(prim: SweepPrimitive) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A folding primitive's solid pieces (geometry.solid.solid_pieces: tubes and convex
    hulls whose union is the solid) as one triangle soup: vertices (V, 3), faces (F, 3)
    and outward unit face normals (F, 3). Not the boolean union, which manifold3d
    computes holding the GIL: 50-190 ms stalls of the app's window after a fit."""
    tubes, hulls = solid_pieces(prim, _SAMPLE_STATIONS, _SAMPLE_PROFILE_POINTS)
    parts: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
    for vertices, faces in tubes:  # closed and outward
        tri = vertices[faces]
        normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        length = np.linalg.norm(normal, axis=1, keepdims=True)
        parts.append((vertices, faces, normal / np.where(length > 0, length, 1.0)))
    for points in hulls:
        try:
            hull = ConvexHull(points)
        except QhullError:  # flat: no volume of its own
            continue
        parts.append((hull.points, hull.simplices, hull.equations[:, :3]))
    offsets = np.cumsum([0] + [len(v) for v, _, _ in parts[:-1]])
    return (np.concatenate([v for v, _, _ in parts]),
            np.concatenate([f + o for (_, f, _), o in zip(parts, offsets, strict=True)]),
            np.concatenate([n for _, _, n in parts]))


def _seed(key: _Key, seed: int) -> int:
    digest = hashlib.blake2b(repr((key, seed)).encode(), digest_size=8).digest()
    return int.from_bytes(digest, "little")


class LiveMetrics:
    """iou, cd_l1, cd_l2, f1_0.05, f1_0.01 and n_primitives of changing primitives against
    one shape (the normalised frame); `n_samples` surface samples on the shape and about
    as many on an abstraction of the same area. Not thread-safe: one per thread."""

    def __init__(self, shape: Shape, n_samples: int = 20_000,
                 resolution: int = RESOLUTION, seed: int = 0) -> None:
        self.shape = shape
        self.seed = seed
        self.grid = grid_points(resolution)
        self.target_occupancy = shape_inside_grid(shape, resolution)
        self.target_samples = shape.surface_samples(n_samples, seed=seed)
        self.target_tree = cKDTree(self.target_samples)
        area = float(getattr(shape.surface, "area", 0.0) or 0.0)
        self.density = n_samples / area if area > 0 else None
        self.n_samples = n_samples
        self._occupancy: dict[_Key, np.ndarray] = {}  # key -> (R^3,) bool
        self._samples: dict[_Key, np.ndarray] = {}  # key -> (M, 3)
        self._to_target: dict[_Key, np.ndarray] = {}  # key -> (M,) distance to the shape
        self._pairs: dict[tuple[_Key, _Key], np.ndarray] = {}  # i's samples inside j

    def evaluate(self, primitives: Sequence[SweepPrimitive]) -> dict[str, float]:
        """The metrics of `primitives` (hidden ones count: the metric is of the
        abstraction, not of the view)."""
        keys = [p.geometry_key() for p in primitives]
        prims = dict(zip(keys, primitives, strict=True))
        covered = np.zeros(len(self.grid), dtype=bool)
        for key, prim in prims.items():
            if key not in self._occupancy:
                self._occupancy[key] = inside_primitive(self.grid, prim)
                self._samples[key] = self._sample(key, prim)
                self._to_target[key] = self.target_tree.query(self._samples[key], k=1,
                                                              workers=-1)[0]
            covered |= self._occupancy[key]
        result: dict[str, float] = {"iou": iou(covered, self.target_occupancy)}
        outer, d_pred = self._outer_samples(prims)
        self._forget(set(prims))
        if len(outer):
            # Full boxes per node (compact_nodes=False): surface samples leave shrunk
            # boxes thin, which slows the search several times.
            tree = cKDTree(outer, balanced_tree=False, compact_nodes=False)
            d_target = tree.query(self.target_samples, k=1, workers=-1)[0]
            result["cd_l1"] = float((d_pred.mean() + d_target.mean()) / 2.0)
            result["cd_l2"] = float(((d_pred**2).mean() + (d_target**2).mean()) / 2.0)
            for tau in F1_TAUS:
                precision = float(np.mean(d_pred < tau))
                recall = float(np.mean(d_target < tau))
                total = precision + recall
                result[f"f1_{tau:g}"] = 2 * precision * recall / total if total else 0.0
        else:
            result.update({"cd_l1": float("inf"), "cd_l2": float("inf"),
                           **{f"f1_{tau:g}": 0.0 for tau in F1_TAUS}})
        result["n_primitives"] = len(primitives)
        return result

    def _sample(self, key: _Key, prim: SweepPrimitive) -> np.ndarray:
        """Area-uniform samples (M, 3) of one primitive's surface, at the shape's density;
        a folding primitive on its solid's boundary (its display tube turns inside-out)."""
        rng = np.random.default_rng(_seed(key, self.seed))
        if folds_onto_itself(prim):
            vertices, faces, normals = _solid_pieces_mesh(prim)
        else:
            mesh = sweep_mesh(prim, _SAMPLE_STATIONS, _SAMPLE_PROFILE_POINTS)
            vertices, faces, normals = mesh.vertices, mesh.faces, None
        tri = vertices[faces]
        area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]),
                                    axis=1).sum()
        count = (max(16, round(self.density * area)) if self.density is not None
                 else self.n_samples // 8)
        points, face = sample_triangles(vertices, faces, count, rng)
        if normals is None:
            return points
        # The pieces overlap: a sample is on the solid's boundary when a nudge outward
        # takes it out of the solid (the exact inside test, the solid's own definition).
        nudge = _NUDGE_SHARE * float(np.hypot(prim.a, prim.b))
        return points[~inside_primitive(points + nudge * normals[face], prim)]

    def _outer_samples(self, prims: dict[_Key, SweepPrimitive]
                       ) -> tuple[np.ndarray, np.ndarray]:
        """Every primitive's samples that lie in no other primitive (M, 3), and their
        distances to the shape's samples (M,)."""
        parts, distances = [], []
        for ki in prims:
            samples = self._samples[ki]
            keep = np.ones(len(samples), dtype=bool)
            for kj, pj in prims.items():
                if kj == ki:
                    continue
                if (ki, kj) not in self._pairs:
                    self._pairs[(ki, kj)] = inside_primitive(samples, pj)
                keep &= ~self._pairs[(ki, kj)]
            parts.append(samples[keep])
            distances.append(self._to_target[ki][keep])
        if not parts:
            return np.zeros((0, 3)), np.zeros(0)
        return np.concatenate(parts), np.concatenate(distances)

    def _forget(self, keep: set[_Key]) -> None:
        for cache in (self._occupancy, self._samples, self._to_target):
            for key in [k for k in cache if k not in keep]:
                del cache[key]
        for pair in [p for p in self._pairs if p[0] not in keep or p[1] not in keep]:
            del self._pairs[pair]
