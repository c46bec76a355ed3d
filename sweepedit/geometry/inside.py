"""The exact inside test of docs/primitive.md: the ground truth for sweeps.

A point p is inside a primitive when, for some t in [0, 1], p lies in the profile plane
at t (h(t) = (p - s(t)).T(t) = 0) and its in-plane coordinates, divided by f(t), fall
inside the superellipse. h is sampled densely, its sign changes are bracketed and
refined by regula falsi on the exact curve, and every root is tested. All of it is one
compiled loop per point (inside_kernel.py), with sweep.py's math written out for one
point and held to it by tests; what it needs of a primitive is made once, by sweep.py
(_make_axis_table).
"""

from __future__ import annotations

from collections.abc import Sequence
from functools import lru_cache
from typing import NamedTuple

import numpy as np

from sweepedit.geometry.arrays import as_array
from sweepedit.geometry.inside_kernel import mark_inside
from sweepedit.geometry.model import SweepPrimitive
from sweepedit.geometry.sweep import (
    axis_points_tangents,
    bezier_segments,
    scaling_factor,
    segment_frames,
)

T_SAMPLES = 256
REFINE_STEPS = 2
# Every how many axis samples the tube filter tests against (see _make_axis_table).
_COARSE = 8


def _bounding_box(cps: np.ndarray, profile: np.ndarray, scaling: np.ndarray,
                  t: np.ndarray, centres: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A box that holds the whole solid: axis samples padded by the largest profile radius."""
    f = scaling_factor(scaling, t)[0]
    radius = float(np.max(f)) * float(np.hypot(profile[0, 0], profile[0, 1]))
    # The polyline through samples can cut inside the curve by at most the sagitta;
    # pad by the largest gap between samples to stay conservative.
    gap = float(np.max(np.linalg.norm(np.diff(centres, axis=0), axis=1)))
    pad = radius + gap + 1e-9
    return centres.min(axis=0) - pad, centres.max(axis=0) + pad


def _as_points(points: np.ndarray) -> np.ndarray:
    """points (N, 3) as contiguous float64; a ValueError for any other shape."""
    return as_array(points, "N, 3", "points", contiguous=True)


def inside_primitive(points: np.ndarray, primitive: SweepPrimitive,
                     t_samples: int = T_SAMPLES) -> np.ndarray:
    """Exact occupancy of one primitive: points (N, 3) -> bool (N,)."""
    return _inside_primitive(_as_points(points), primitive, t_samples)


class _AxisTable(NamedTuple):
    """What the inside test needs of one primitive at its axis samples, made once per
    primitive (_axis_table): the slicer of STEP export asks about a few thousand points
    at a time, thousands of times, and making these took a third of each call."""

    cps: np.ndarray  # (1, n, 3)
    profile: np.ndarray  # (1, 3)
    scaling: np.ndarray  # (1, k)
    t: np.ndarray  # (T,) the axis samples
    centres: np.ndarray  # (T, 3)
    tangent_columns: np.ndarray  # (3, T) the tangents, a row per coordinate
    offsets: np.ndarray  # (T,) s(t).T(t)
    lo: np.ndarray  # (3,) a box that holds the solid
    hi: np.ndarray  # (3,)
    coarse: np.ndarray  # (C, 3) every _COARSE-th axis sample
    bound: float  # how far from a coarse sample a point inside can be
    reach2: np.ndarray  # (T-1,) squared reach of each interval of samples
    segments: tuple[np.ndarray, np.ndarray, np.ndarray]  # the Bezier segments, each (m, 3)
    radii2: tuple[float, float]  # squared in-plane radii surely inside, surely outside
    # (m, 13) per segment: start tangent, U, V, plane normal, planar (inside_kernel._frame_at)
    start: np.ndarray


def profile_radii2(a: float, b: float, d: float) -> tuple[float, float]:
    """Squared radii (over f) within which every point of a profile plane is inside the
    superellipse |x/a|^d + |y/b|^d <= 1 as superellipse_level computes it (its clip
    included), and beyond which every point is outside, each with 1e-9 of the level to
    spare: the inscribed and circumscribed circles, m min(1, e) and M max(1, e) with
    m, M = min, max(a, b) and e = 2^(1/2 - 1/d) (|cos|^d + |sin|^d lies between 1 and
    2^(1 - d/2)). (-1, inf), which decide nothing, unless a, b and d are finite and
    positive."""
    if not (0.0 < a < np.inf and 0.0 < b < np.inf and 0.0 < d < np.inf):
        return -1.0, np.inf
    e = 2.0 ** (0.5 - 1.0 / d)
    spare = 1.0 - 1e-9 - 2.0 * 1e-12 ** d  # superellipse_level clips each term at 1e-12^d
    inside = (min(a, b) * min(1.0, e)) ** 2 * spare ** (2.0 / d) if spare > 0.0 else -1.0
    return inside, (max(a, b) * max(1.0, e)) ** 2 * (1.0 + 1e-9) ** (2.0 / d)


class _Arrays:
    """A primitive's arrays (copies) as a cache key: equal when its geometry is."""

    __slots__ = ("_hash", "_key", "arrays")

    def __init__(self, primitive: SweepPrimitive) -> None:
        self.arrays = tuple(np.array(a, dtype=np.float64) for a in primitive.batch_arrays())
        self._key = primitive.geometry_key()
        self._hash = hash(self._key)

    def __hash__(self) -> int:
        return self._hash

    def __eq__(self, other: object) -> bool:
        return isinstance(other, _Arrays) and self._key == other._key


def _axis_table(primitive: SweepPrimitive, t_samples: int) -> _AxisTable:
    return _make_axis_table(_Arrays(primitive), t_samples)


@lru_cache(maxsize=64)
def _make_axis_table(arrays: _Arrays, t_samples: int) -> _AxisTable:
    cps, profile, scaling = arrays.arrays
    t = np.linspace(0.0, 1.0, t_samples)
    centres, tangents = (np.ascontiguousarray(a[0]) for a in axis_points_tangents(cps, t))
    lo, hi = _bounding_box(cps, profile, scaling, t, centres)
    # Only points within the largest profile radius (plus the sample gap) of the axis
    # can be inside: this cuts the box down to a tube before the dense work. The tube is
    # tested against every COARSE-th axis sample, widened by the most any sample lies
    # from its nearest coarse one (half the polyline between two coarse samples).
    gap = np.linalg.norm(np.diff(centres, axis=0), axis=1)  # (T-1,)
    reach = scaling_factor(scaling, t)[0] * np.hypot(profile[0, 0], profile[0, 1])
    coarse_at = np.unique(np.append(np.arange(0, t_samples, _COARSE), t_samples - 1))
    arc = np.concatenate([[0.0], np.cumsum(gap)])
    widen = float(np.max(np.diff(arc[coarse_at]))) / 2.0
    # A plane crossing at t can only be inside if p is within reach of s(t): the
    # largest profile radius there plus the gap to the next sample.
    return _AxisTable(
        cps, profile, scaling, t, centres, np.ascontiguousarray(tangents.T),
        np.einsum("ij,ij->i", centres, tangents), lo, hi, np.ascontiguousarray(centres[coarse_at]),
        float(reach.max() + gap.max()) + widen + 1e-9,
        (np.maximum(reach[:-1], reach[1:]) + gap) ** 2,
        tuple(np.ascontiguousarray(a[0]) for a in bezier_segments(cps)),
        profile_radii2(*(float(v) for v in profile[0])),
        np.ascontiguousarray(np.concatenate([np.asarray(a[0], dtype=np.float64)
                                             for a in segment_frames(cps)], axis=1)))


def _inside_primitive(points: np.ndarray, primitive: SweepPrimitive, t_samples: int,
                      todo: np.ndarray | None = None) -> np.ndarray:
    """inside_primitive of points (N, 3), contiguous float64; only where todo (N,) bool
    is True, if given (False elsewhere)."""
    table = _axis_table(primitive, t_samples)
    result = np.zeros(len(points), dtype=bool)
    todo = np.ones(len(points), dtype=bool) if todo is None else todo
    mark_inside(points, todo, table.lo, table.hi, table.coarse, table.bound, table.centres,
                table.tangent_columns, table.offsets, table.reach2, table.t,
                *table.segments, REFINE_STEPS, table.scaling[0], *table.radii2,
                table.start, table.profile[0], result)
    return result


def inside_primitives(points: np.ndarray, primitives: Sequence[SweepPrimitive],
                      t_samples: int = T_SAMPLES) -> np.ndarray:
    """Exact occupancy of each primitive: points (N, 3) -> bool (K, N)."""
    points = _as_points(points)
    out = np.zeros((len(primitives), len(points)), dtype=bool)
    for k, prim in enumerate(primitives):
        out[k] = _inside_primitive(points, prim, t_samples)
    return out


def inside_union(points: np.ndarray, primitives: Sequence[SweepPrimitive],
                 t_samples: int = T_SAMPLES) -> np.ndarray:
    """Exact occupancy of the union: points (N, 3) -> bool (N,)."""
    points = _as_points(points)
    result = np.zeros(len(points), dtype=bool)
    for prim in primitives:
        if result.all():
            break
        result |= _inside_primitive(points, prim, t_samples, todo=~result)
    return result


def grid_points(resolution: int = 64) -> np.ndarray:
    """Cell centres of a resolution^3 grid over [-0.5, 0.5]^3, (R^3, 3), x-major ([ix, iy, iz])."""
    c = (np.arange(resolution) + 0.5) / resolution - 0.5
    return np.stack(np.meshgrid(c, c, c, indexing="ij"), axis=-1).reshape(-1, 3)
