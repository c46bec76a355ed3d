"""The exact (non-differentiable) sweeper: primitives -> triangle meshes.

Each primitive becomes a closed, outward-oriented mesh: a grid of `stations` profile
rings along the axis, closed by flat fan caps at both ends. The topology depends only on
the resolution, so it is built once per resolution and cached; sweeping a primitive is
then a handful of vectorised numpy operations (fast enough for live dragging).

This tube is for display: where a sweep folds onto itself its rings cross and the tube
turns inside-out locally. The mesh of the true solid, for export and booleans, is
solid.py's.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from functools import lru_cache
from typing import TYPE_CHECKING

import numpy as np

from sweepedit.geometry.model import SweepPrimitive
from sweepedit.geometry.sweep import _cross, axis_frames, scaling_factor, superellipse

if TYPE_CHECKING:
    import trimesh

DISPLAY_STATIONS = 64
DISPLAY_PROFILE_POINTS = 48


@dataclass
class TriangleMesh:
    """vertices (V, 3) float64, faces (F, 3) int64 (counter-clockwise seen from outside),
    normals (V, 3) unit vertex normals for smooth shading."""

    vertices: np.ndarray
    faces: np.ndarray
    normals: np.ndarray

    def to_trimesh(self) -> trimesh.Trimesh:  # imported lazily: trimesh is slow to import
        import trimesh

        return trimesh.Trimesh(self.vertices, self.faces, vertex_normals=self.normals,
                               process=False)


@lru_cache(maxsize=32)
def _side_and_cap_faces(stations: int, profile_points: int, split_caps: bool) -> np.ndarray:
    """Faces (F, 3) of the ring grid plus the two fans.

    Vertex layout: side ring vertices i*P + j (i station, j profile point); then, when
    split_caps, a copy of the first and last ring (flat-shaded caps); then the two
    cap centres.
    """
    S, P = stations, profile_points
    i, j = np.meshgrid(np.arange(S - 1), np.arange(P), indexing="ij")
    a = i * P + j
    b = i * P + (j + 1) % P
    c = (i + 1) * P + j
    d = (i + 1) * P + (j + 1) % P
    # (dθ) x (dt) points outwards for a profile that turns counter-clockwise about T.
    side = np.concatenate([np.stack([a, b, c], -1).reshape(-1, 3),
                           np.stack([b, d, c], -1).reshape(-1, 3)])
    jj = np.arange(P)
    if split_caps:
        ring0, ring1 = S * P + jj, S * P + P + jj
        centre0, centre1 = S * P + 2 * P, S * P + 2 * P + 1
    else:
        ring0, ring1 = jj, (S - 1) * P + jj
        centre0, centre1 = S * P, S * P + 1
    nxt = np.roll(jj, -1)
    cap0 = np.stack([np.full(P, centre0), ring0[nxt], ring0], -1)  # faces -T
    cap1 = np.stack([np.full(P, centre1), ring1, ring1[nxt]], -1)  # faces +T
    return np.concatenate([side, cap0, cap1]).astype(np.int64)


def _side_normals(grid: np.ndarray) -> np.ndarray:
    """Smooth normals of a (K, S, P, 3) ring grid from central differences."""
    d_theta = np.roll(grid, -1, axis=2) - np.roll(grid, 1, axis=2)
    d_t = np.gradient(grid, axis=1)
    n = _cross(np, d_theta, d_t)
    return n / np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-12)


def sweep_meshes_batch(control_points: np.ndarray, profile: np.ndarray, scaling: np.ndarray,
                       stations: int = DISPLAY_STATIONS,
                       profile_points: int = DISPLAY_PROFILE_POINTS,
                       split_caps: bool = False) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Mesh K primitives that share n and k at once.

    control_points (K, n, 3), profile (K, 3), scaling (K, k) -> vertices (K, V, 3),
    faces (F, 3) (shared topology), normals (K, V, 3). split_caps duplicates the rim
    vertices so that caps shade flat (for display); otherwise the mesh is watertight.
    """
    if profile_points % 4:
        raise ValueError("profile_points must be a multiple of 4 (keeps the profile's tips)")
    if stations < 2:
        raise ValueError("stations must be at least 2")
    t = np.linspace(0.0, 1.0, stations)
    theta = np.linspace(0.0, 2.0 * np.pi, profile_points, endpoint=False)
    fr = axis_frames(control_points, t)
    x, y = superellipse(theta, profile)  # (K, P)
    f = scaling_factor(scaling, t)[:, :, None, None]
    grid = fr.points[:, :, None, :] + f * (x[:, None, :, None] * fr.U[:, :, None, :]
                                           + y[:, None, :, None] * fr.V[:, :, None, :])
    K, S, P = grid.shape[:3]
    normals = _side_normals(grid).reshape(K, S * P, 3)
    verts = [grid.reshape(K, S * P, 3)]
    norms = [normals]
    start_n = -fr.T[:, :1, :]
    end_n = fr.T[:, -1:, :]
    if split_caps:
        verts += [grid[:, 0], grid[:, -1]]
        norms += [np.broadcast_to(start_n, (K, P, 3)), np.broadcast_to(end_n, (K, P, 3))]
    verts += [fr.points[:, :1], fr.points[:, -1:]]
    norms += [start_n, end_n]
    vertices = np.concatenate(verts, axis=1)
    vertex_normals = np.concatenate(norms, axis=1)
    return vertices, _side_and_cap_faces(S, P, split_caps), vertex_normals


def sweep_mesh(primitive: SweepPrimitive, stations: int = DISPLAY_STATIONS,
               profile_points: int = DISPLAY_PROFILE_POINTS,
               split_caps: bool = False) -> TriangleMesh:
    """One primitive -> a closed, outward-oriented TriangleMesh (watertight unless split_caps)."""
    v, f, n = sweep_meshes_batch(*primitive.batch_arrays(), stations=stations,
                                 profile_points=profile_points, split_caps=split_caps)
    return TriangleMesh(v[0], f, n[0])


def sweep_meshes(primitives: Sequence[SweepPrimitive], stations: int = DISPLAY_STATIONS,
                 profile_points: int = DISPLAY_PROFILE_POINTS,
                 split_caps: bool = False) -> list[TriangleMesh]:
    """Mesh several primitives, batching those with the same number of control points
    and scaling coefficients; the result is in the input's order."""
    out: list[TriangleMesh | None] = [None] * len(primitives)
    groups: dict[tuple[int, int], list[int]] = {}
    for i, p in enumerate(primitives):
        groups.setdefault((p.n_control_points, len(p.scaling)), []).append(i)
    for (_, k), idx in groups.items():
        cps = np.stack([primitives[i].control_points for i in idx])
        prof = np.stack([primitives[i].profile for i in idx])
        scal = np.array([primitives[i].scaling for i in idx], dtype=np.float64).reshape(len(idx), k)
        v, f, n = sweep_meshes_batch(cps, prof, scal, stations, profile_points, split_caps)
        for row, i in enumerate(idx):
            out[i] = TriangleMesh(v[row], f, n[row])
    return out  # type: ignore[return-value]


def union_mesh(meshes: Sequence[TriangleMesh]) -> TriangleMesh:
    """The boolean union of closed meshes as one watertight mesh (manifold3d).

    Each mesh must bound its solid: manifold3d does not resolve a mesh that overlaps
    itself, and a sweep that folds onto itself (its profile reaching past the axis'
    centre of curvature) turns inside-out locally. For the solids of primitives use
    solid.solid_union, which cuts such sweeps into pieces that each bound their solid.
    """
    import manifold3d as m3d

    if not meshes:
        return TriangleMesh(np.zeros((0, 3)), np.zeros((0, 3), np.int64), np.zeros((0, 3)))
    solids = [m3d.Manifold(m3d.Mesh(vert_properties=np.asarray(m.vertices, np.float32),
                                    tri_verts=np.asarray(m.faces, np.uint32)))
              for m in meshes]
    result = m3d.Manifold.batch_boolean(solids, m3d.OpType.Add).to_mesh()
    vertices = np.asarray(result.vert_properties, dtype=np.float64)[:, :3]
    faces = np.asarray(result.tri_verts, dtype=np.int64)
    return TriangleMesh(vertices, faces, _vertex_normals(vertices, faces))


def _vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Area-weighted vertex normals: vertices (V, 3), faces (F, 3) -> (V, 3)."""
    fn = np.cross(vertices[faces[:, 1]] - vertices[faces[:, 0]],
                  vertices[faces[:, 2]] - vertices[faces[:, 0]])
    vn = np.zeros_like(vertices)
    for c in range(3):
        np.add.at(vn, faces[:, c], fn)
    return vn / np.maximum(np.linalg.norm(vn, axis=1, keepdims=True), 1e-12)
