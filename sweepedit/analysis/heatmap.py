"""A heat map of an abstraction's error, on the target's surface.

Definition. For each vertex v of the target's surface, `distance[v]` is the distance
from v to the boundary of the union of the primitives (the abstraction's outer surface),
signed by the exact inside test (sweepedit.geometry.inside):

- positive: v lies outside every primitive, so the target's surface there is *missed*
  (the value is how far the abstraction would have to grow to reach it);
- negative: v lies inside the union, so the abstraction reaches past the target's surface
  there: *excess* (the value is how deep the target's surface is buried in it).

Excess that stands away from the target (a primitive poking into empty space) shows on the
target only where the target's surface is buried near its base; the heat map does not colour
the abstraction itself.

How. The union's boundary is sampled densely and regularly: each primitive's ring grid
(its display mesh at a finer resolution) plus rings on its two end caps, with the
samples that fall inside another primitive dropped (they are not on the boundary). For
each vertex the nearest boundary sample q (a KD-tree) gives the distance; where v's foot
on q's tangent plane lies within one sample spacing of q (v is over the smooth surface
there, not beyond a rim) the distance to that tangent plane is taken instead, which
removes the sampling error to second order. The error is then about
curvature * spacing^2 / 2 (1e-4 on the test cylinder; up to one sample spacing, ~0.01,
right at a crease where two primitives cross), below what the colour bar resolves. Tests
bound it against an analytic cylinder and the exact union mesh.

Speed. `HeatMapper` keeps, per primitive, its samples, its exact occupancy at the
target's vertices and which of its samples lie inside each other primitive: after an edit
of one primitive only that primitive's share is recomputed (the app's case).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from sweepedit.geometry.arrays import as_array
from sweepedit.geometry.inside import T_SAMPLES, inside_primitive
from sweepedit.geometry.mesher import sweep_meshes_batch
from sweepedit.geometry.model import GeometryKey, SweepPrimitive, folds_onto_itself
from sweepedit.geometry.solid import solid_mesh

# Sampling of each primitive's surface: rings along the axis, points per ring, and rings
# on each end cap (besides its centre).
SAMPLE_STATIONS = 96
SAMPLE_PROFILE_POINTS = 64
CAP_RINGS = 8
# Samples examined per vertex (inside a convex edge the nearest can be on the far face).
NEAREST = 4

_Key = GeometryKey


@dataclass(frozen=True)
class BoundarySamples:
    """Samples of one primitive's surface: points (M, 3); two unit outward normals each
    (M, 2, 3), the same twice inside a smooth patch, the tube's and the cap's on a rim;
    `edges` (M, 2, 3) and `limits` (M, 2): the patch of that normal ends where
    foot . edge exceeds the limit (at the nearer rim: the tube along the cap's normal,
    a cap radially outwards; 0 on the rim itself); `rims` (M, 3),
    the rim's unit tangent at rim samples, else zero (past both patches the rim itself is
    nearest); `spacing`, the largest distance between neighbouring samples (negative: no
    tangent planes, plain distances to the samples); `blocks`, the (rows, columns) of the
    ring grids the samples come in, one after the other (tube, cap at t = 0, cap at 1),
    empty when they form no grid."""

    points: np.ndarray
    normals: np.ndarray
    edges: np.ndarray
    limits: np.ndarray
    rims: np.ndarray
    spacing: float
    blocks: tuple[tuple[int, int], ...] = ()

    def near(self, mask: np.ndarray) -> np.ndarray:
        """(M,) bool: the samples in `mask` (M,) bool and their grid neighbours (rings
        wrap around); `mask` itself without grids."""
        out, start = mask.copy(), 0
        for rows, cols in self.blocks:
            block = mask[start:start + rows * cols].reshape(rows, cols)
            grown = block | np.roll(block, 1, axis=1) | np.roll(block, -1, axis=1)
            grown[1:] |= block[:-1]
            grown[:-1] |= block[1:]
            out[start:start + rows * cols] = grown.reshape(-1)
            start += rows * cols
        return out


@dataclass(frozen=True)
class HeatMap:
    """distance (N,) signed distances of the target's vertices to the abstraction's outer
    surface: > 0 missed (outside the union), < 0 excess (inside it); inside (N,) bool."""

    distance: np.ndarray
    inside: np.ndarray

    @property
    def missed(self) -> float:
        """The largest distance of a missed vertex (0 if none)."""
        out = self.distance[~self.inside]
        return float(out.max()) if out.size else 0.0

    @property
    def excess(self) -> float:
        """The largest depth of a buried vertex (0 if none)."""
        buried = self.distance[self.inside]
        return float(-buried.min()) if buried.size else 0.0


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.maximum(np.linalg.norm(v, axis=-1, keepdims=True), 1e-300)


def boundary_samples(primitive: SweepPrimitive, stations: int = SAMPLE_STATIONS,
                     profile_points: int = SAMPLE_PROFILE_POINTS,
                     cap_rings: int = CAP_RINGS) -> BoundarySamples:
    """Regular samples of a primitive's surface (see BoundarySamples)."""
    if folds_onto_itself(primitive):
        # The display tube turns inside-out where the sweep folds: sample the solid's
        # mesh instead, and take plain distances to its vertices.
        mesh = solid_mesh(primitive, stations, profile_points)
        normals = np.repeat(mesh.normals[:, None], 2, axis=1)
        return BoundarySamples(mesh.vertices, normals, np.zeros_like(normals),
                               np.zeros(normals.shape[:2]), np.zeros_like(mesh.vertices), -1.0)
    verts, _, normals = sweep_meshes_batch(*primitive.batch_arrays(), stations=stations,
                                           profile_points=profile_points, split_caps=True)
    S, P = stations, profile_points
    grid = verts[0, : S * P].reshape(S, P, 3)
    side_n = np.repeat(normals[0, : S * P, None], 2, axis=1).reshape(S, P, 2, 3)
    centres = verts[0, -2:]  # the caps' centres, at t = 0 and 1
    cap_n = normals[0, [S * P, S * P + P]]  # -T(0), +T(1)
    # The tube's patch ends at the nearer rim: past the rim's plane along its cap normal.
    to_rim = np.stack([np.einsum("spk,k->sp", grid[:1] - grid, cap_n[0]),
                       np.einsum("spk,k->sp", grid[-1:] - grid, cap_n[1])])  # (2, S, P)
    end = np.argmin(np.abs(to_rim), axis=0)  # (S, P)
    side_e = np.zeros_like(side_n)
    side_e[:, :, 0] = cap_n[end]
    side_e[:, :, 1] = side_e[:, :, 0]
    side_l = np.repeat(np.take_along_axis(to_rim, end[None], 0)[0][..., None], 2, axis=2)
    side_t = np.zeros_like(grid)
    fractions = np.arange(cap_rings + 1) / (cap_rings + 1)  # 0 (the centre) .. < 1
    caps, caps_n, caps_e, caps_l = [], [], [], []
    for c, ring in enumerate((grid[0], grid[-1])):
        out = ring - centres[c]  # (P, 3)
        radius = np.linalg.norm(out, axis=1)
        caps.append(centres[c] + fractions[:, None, None] * out)
        caps_n.append(np.broadcast_to(cap_n[c], (cap_rings + 1, P, 2, 3)))
        # The cap's patch ends at the rim, radially outwards.
        caps_e.append(np.broadcast_to(_unit(out)[None, :, None], (cap_rings + 1, P, 2, 3)))
        caps_l.append(np.broadcast_to(((1 - fractions)[:, None] * radius)[..., None],
                                      (cap_rings + 1, P, 2)))
        # The rim ring holds both patches: the tube's (normal 0) and the cap's (normal 1).
        rim = 0 if c == 0 else S - 1
        side_n[rim, :, 1] = cap_n[c]
        side_e[rim, :, 0] = cap_n[c]
        side_e[rim, :, 1] = _unit(out)
        side_l[rim] = 0.0
        side_t[rim] = _unit(np.roll(ring, -1, axis=0) - np.roll(ring, 1, axis=0))
    along = np.linalg.norm(np.diff(grid, axis=0), axis=2).max()
    around = np.linalg.norm(grid - np.roll(grid, 1, axis=1), axis=2).max()
    radial = max(np.linalg.norm(grid[[0, -1]] - centres[:, None], axis=2).max()
                 / (cap_rings + 1), 0.0)
    n_caps = 2 * (cap_rings + 1) * P
    return BoundarySamples(
        np.concatenate([grid.reshape(-1, 3), *(c.reshape(-1, 3) for c in caps)]),
        np.concatenate([side_n.reshape(-1, 2, 3), *(c.reshape(-1, 2, 3) for c in caps_n)]),
        np.concatenate([side_e.reshape(-1, 2, 3), *(c.reshape(-1, 2, 3) for c in caps_e)]),
        np.concatenate([side_l.reshape(-1, 2), *(c.reshape(-1, 2) for c in caps_l)]),
        np.concatenate([side_t.reshape(-1, 3), np.zeros((n_caps, 3))]),
        float(max(along, around, radial)), ((S, P), (cap_rings + 1, P), (cap_rings + 1, P)))


@dataclass
class _Nearest:
    """What a computation leaves for the next one: per primitive (in order) its sample
    status (M_i,) int8 (0 buried, 1 on the boundary, 2 on it but next to a buried one: no
    tangent planes), the k candidate samples of each vertex (N, k) as indices into that
    computation's concatenated boundary samples, the distance (N,) to the farthest
    candidate, and the unsigned distances (N,)."""

    status: dict[_Key, np.ndarray]
    order: list[_Key]
    candidates: np.ndarray
    radius: np.ndarray
    distance: np.ndarray


class HeatMapper:
    """Signed distances of fixed target vertices (N, 3) to the outer surface of changing
    primitives, reusing everything that did not change since the last call (see the
    module's docstring). Not thread-safe: use one per thread.

    After an edit only the vertices that can see it are searched again: those whose
    candidate samples changed (moved, buried, exposed), and those within their
    candidates' reach of the box around the samples that appeared. The search is exact
    (the k nearest samples), so the result is what a computation from nothing gives."""

    def __init__(self, vertices: np.ndarray, t_samples: int = T_SAMPLES) -> None:
        self.vertices = as_array(vertices, "N, 3", "vertices")
        self.t_samples = t_samples
        self._samples: dict[_Key, BoundarySamples] = {}
        self._inside: dict[_Key, np.ndarray] = {}  # key -> (N,) bool at the vertices
        self._pairs: dict[tuple[_Key, _Key], np.ndarray] = {}  # (i, j) -> i's samples in j
        self._last: _Nearest | None = None
        self.searched = 0  # vertices searched by the last call (for benchmarks)

    def compute(self, primitives: Sequence[SweepPrimitive]) -> HeatMap:
        """The heat map of `primitives` (all of them, hidden ones too: the map is of the
        abstraction, as the metrics are). Without primitives every vertex is missed by
        an infinite distance."""
        n = len(self.vertices)
        keys = list(dict.fromkeys(p.geometry_key() for p in primitives))
        prims = {p.geometry_key(): p for p in primitives}
        for key, prim in prims.items():
            if key not in self._samples:
                self._samples[key] = boundary_samples(prim)
                self._inside[key] = inside_primitive(self.vertices, prim, self.t_samples)
        inside = np.zeros(n, dtype=bool)
        for key in keys:
            inside |= self._inside[key]
        status = {key: self._status(key, prims) for key in keys}
        self._forget(set(keys))
        order = [k for k in keys if np.any(status[k])]
        arrays = self._gather(order, status)
        if not len(arrays[0]):  # nothing, or every sample buried (identical copies)
            self._last = None
            self.searched = 0
            return HeatMap(np.where(inside, -0.0, np.inf), inside)
        last = self._update(order, status, arrays)
        self._last = last
        return HeatMap(np.where(inside, -last.distance, last.distance), inside)

    def _status(self, key: _Key, prims: dict[_Key, SweepPrimitive]) -> np.ndarray:
        """(M,) int8 of a primitive's samples: 0 inside another primitive, 1 on the
        boundary, 2 on it but next to a buried sample (no tangent planes: they would reach
        over surface that is not the boundary, where another primitive crosses)."""
        s = self._samples[key]
        buried = np.zeros(len(s.points), dtype=bool)
        for other, prim in prims.items():
            if other == key:  # also an exact duplicate: its surface is the same boundary
                continue
            if (key, other) not in self._pairs:
                self._pairs[(key, other)] = inside_primitive(s.points, prim, self.t_samples)
            buried |= self._pairs[(key, other)]
        return np.where(buried, 0, np.where(s.near(buried), 2, 1)).astype(np.int8)

    def _gather(self, order: list[_Key], status: dict[_Key, np.ndarray]
                ) -> tuple[np.ndarray, ...]:
        """The boundary samples of `order`'s primitives, concatenated: points (M, 3),
        normals (M, 2, 3), edges (M, 2, 3), limits (M, 2), rims (M, 3), spacing (M,)."""
        parts = []
        for key in order:
            s, st = self._samples[key], status[key]
            keep = st > 0
            limits = np.where((st == 2)[:, None], -np.inf, s.limits)
            parts.append((s.points[keep], s.normals[keep], s.edges[keep], limits[keep],
                          s.rims[keep], np.full(int(keep.sum()), s.spacing)))
        if not parts:
            return (np.zeros((0, 3)),)
        return tuple(np.concatenate(c) for c in zip(*parts, strict=True))

    def _update(self, order: list[_Key], status: dict[_Key, np.ndarray],
                arrays: tuple[np.ndarray, ...]) -> _Nearest:
        """Search the vertices that an edit can have changed (all of them the first time)
        and carry the others' candidates over."""
        points = arrays[0]
        k = min(NEAREST, len(points))
        last = self._last
        n = len(self.vertices)
        if last is None or last.candidates.shape[1] != k:
            todo = np.arange(n)
            candidates = np.zeros((n, k), dtype=np.int64)
            radius, distance = np.zeros(n), np.zeros(n)
        else:
            moved, appeared, where = self._changes(last, order, status)
            gone = moved[last.candidates].any(axis=1)
            if len(appeared):
                lo, hi = points[appeared].min(axis=0), points[appeared].max(axis=0)
                to_box = np.linalg.norm(np.maximum(np.maximum(lo - self.vertices,
                                                              self.vertices - hi), 0.0),
                                        axis=1)
                gone |= to_box <= last.radius
            todo = np.flatnonzero(gone)
            candidates = where[last.candidates]
            radius, distance = last.radius.copy(), last.distance.copy()
        self.searched = len(todo)
        if len(todo):
            tree = cKDTree(points, leafsize=32, balanced_tree=False, compact_nodes=False)
            found, nearest = tree.query(self.vertices[todo], k=k, workers=-1)
            nearest = nearest.reshape(len(todo), k)
            candidates[todo] = nearest
            radius[todo] = np.asarray(found).reshape(len(todo), k)[:, -1]
            distance[todo] = _estimate(self.vertices[todo], nearest, *arrays)
        return _Nearest(status, order, candidates, radius, distance)

    def _changes(self, last: _Nearest, order: list[_Key], status: dict[_Key, np.ndarray]
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Between the last computation and this one: `moved` (M_last,) bool, the last
        boundary samples that are gone or changed; `appeared`, indices of this one's
        samples that are new or changed; `where` (M_last,), each last sample's index now
        (-1 if moved)."""
        now: dict[_Key, np.ndarray] = {}  # key -> index now of each of its samples, or -1
        appeared, offset = [], 0
        for key in order:
            st = status[key]
            index = np.full(len(st), -1, dtype=np.int64)
            kept = np.flatnonzero(st > 0)
            index[kept] = offset + np.arange(len(kept))
            before = last.status.get(key)
            fresh = st > 0 if before is None else (st > 0) & (st != before)
            appeared.append(index[fresh])
            now[key] = index
            offset += len(kept)
        moved, where = [], []
        for key in last.order:
            st = last.status[key]
            kept = np.flatnonzero(st > 0)
            if key in now and key in status:
                same = status[key][kept] == st[kept]
                index = np.where(same, now[key][kept], -1)
            else:
                index = np.full(len(kept), -1, dtype=np.int64)
            moved.append(index < 0)
            where.append(index)
        return (np.concatenate(moved), np.concatenate(appeared),
                np.concatenate(where))

    def _forget(self, keep: set[_Key]) -> None:
        """Drop what belongs to primitives that are gone (a drag makes one per move)."""
        for cache in (self._samples, self._inside):
            for key in [k for k in cache if k not in keep]:
                del cache[key]
        for pair in [p for p in self._pairs if p[0] not in keep or p[1] not in keep]:
            del self._pairs[pair]


def _estimate(vertices: np.ndarray, nearest: np.ndarray, points: np.ndarray,
              normals: np.ndarray, edges: np.ndarray, limits: np.ndarray, rims: np.ndarray,
              spacing: np.ndarray) -> np.ndarray:
    """Unsigned distance (N,) of vertices (N, 3) to the surface sampled by points (M, 3)
    with normals and edges (M, 2, 3), limits (M, 2), rims (M, 3) and spacing (M,) (see
    BoundarySamples), over each vertex's candidate samples nearest (N, k): the least
    distance to a candidate's tangent plane where the foot lies on its patch, else to the
    rim's tangent line at a rim sample, else to the sample itself (inside a convex edge
    the nearest sample can be on the farther face, hence several candidates)."""
    offset = vertices[:, None, :] - points[nearest]  # (N, k, 3)
    reach = spacing[nearest]  # (N, k)
    square = np.einsum("ijk,ijk->ij", offset, offset)
    along_rim = np.einsum("ijk,ijk->ij", offset, rims[nearest])  # 0 off the rims
    best = square - np.where(np.abs(along_rim) <= reach, along_rim, 0.0) ** 2
    for side in range(2):
        n = normals[nearest, side]
        along = np.einsum("ijk,ijk->ij", offset, n)
        foot = offset - along[..., None] * n
        on_patch = ((np.einsum("ijk,ijk->ij", foot, foot) <= reach**2)
                    & (np.einsum("ijk,ijk->ij", foot, edges[nearest, side])
                       <= limits[nearest, side]))
        best = np.where(on_patch, np.minimum(best, along**2), best)
    # Each estimate is the distance to a piece of the surface: the least one is nearest.
    return np.sqrt(np.maximum(best.min(axis=1), 0.0))


def signed_distances(vertices: np.ndarray, primitives: Sequence[SweepPrimitive]) -> np.ndarray:
    """Signed distances (N,) of vertices (N, 3) to the primitives' outer surface (> 0
    outside: missed; < 0 inside: excess); one-off, without HeatMapper's reuse."""
    return HeatMapper(vertices).compute(primitives).distance
