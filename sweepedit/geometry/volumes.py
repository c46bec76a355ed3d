"""Volumes of primitives and of their unions: the independent truths that exported
solids are checked against (STEP export, its benchmark and tests).

A primitive that does not fold has its volume in closed form: the profile's area times
the integral of f(t)^2 |s'(t)| dt (docs/primitive.md). A folding one, and any union, is
estimated with the exact inside test (geometry/inside.py) at randomised quasi-Monte Carlo
points (scrambled Sobol sets), whose replicates also give the estimate's standard error.
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Sequence

import numpy as np

from sweepedit.geometry.inside import inside_union
from sweepedit.geometry.model import SweepPrimitive
from sweepedit.geometry.sweep import axis_points, bezier_segments, scaling_factor

# A union's estimate (UnionVolumes, union_volume): 8 scrambled Sobol sets of 2^15 points.
UNION_REPLICATES = 8
UNION_LOG2_POINTS = 15
# Plain Monte Carlo points (monte_carlo_volume, a check independent of the above).
UNION_SAMPLES = 300_000
# A folding primitive's estimate (fold_volume): 8 scrambled Sobol sets of 2^14 points.
FOLD_REPLICATES = 8
FOLD_LOG2_POINTS = 14
_GAUSS = np.polynomial.legendre.leggauss(48)


def superellipse_area(a: float, b: float, degree: float) -> float:
    """Area of |x/a|^d + |y/b|^d <= 1: 4 a b Γ(1 + 1/d)^2 / Γ(1 + 2/d)."""
    return 4.0 * a * b * math.gamma(1.0 + 1.0 / degree) ** 2 / math.gamma(1.0 + 2.0 / degree)


def closed_form_volume(primitive: SweepPrimitive) -> float:
    """The volume of a primitive that does not fold: area * ∫ f(t)^2 |s'(t)| dt.

    The Jacobian of the sweep is f^2 |s'| (1 - o . q(t)) at profile point o; the profile is
    centrally symmetric, so o . q integrates to zero over it. Gauss-Legendre per Bezier
    segment (each smooth inside: a polynomial times the root of a quadratic), 48 nodes.
    """
    p0, p1, p2 = (x[0] for x in bezier_segments(primitive.control_points[None]))
    m = len(p0)
    nodes, weights = _GAUSS
    u = 0.5 * (nodes + 1.0)  # (G,) on [0, 1]
    total = 0.0
    for j in range(m):
        speed = np.linalg.norm(2.0 * ((1.0 - u)[:, None] * (p1[j] - p0[j])
                                      + u[:, None] * (p2[j] - p1[j])), axis=1)  # |ds/du|
        f = scaling_factor(primitive.scaling_array, (j + u) / m)[0]
        total += 0.5 * float(np.sum(weights * f**2 * speed))
    return superellipse_area(primitive.a, primitive.b, primitive.degree) * total


def fold_volume(primitive: SweepPrimitive, replicates: int = FOLD_REPLICATES,
                log2_points: int = FOLD_LOG2_POINTS, seed: int = 0) -> tuple[float, float]:
    """Volume of one primitive by the exact inside test at randomised quasi-Monte Carlo
    points -> (estimate, standard error), in the normalised frame. Remembered by the
    primitive's geometry: a union's check asks again for the primitives it built.

    In a box aligned with the axis' principal directions (sobol_volume): a thin diagonal
    primitive fills its own box several times better than the coordinate box. On the
    122 folding primitives of the official files and the K = 8 fits the standard error is
    0.05-0.28 % (median 0.13 %) from 131k points in 0.08 s (median), where plain Monte
    Carlo needed 0.4-2M points and 1-1.8 s for 0.21-0.26 % (BENCHMARKS.md, STEP export)."""
    key = (primitive.geometry_key(), replicates, log2_points, seed)
    if key in _FOLD_VOLUMES:
        return _FOLD_VOLUMES[key]
    t = np.linspace(0.0, 1.0, 513)
    centres = axis_points(primitive.control_points[None], t)[0]
    reach = scaling_factor(primitive.scaling_array, t)[0] * math.hypot(primitive.a,
                                                                       primitive.b)
    gap = float(np.linalg.norm(np.diff(centres, axis=0), axis=1).max())  # between samples
    middle = centres.mean(axis=0)
    _, _, directions = np.linalg.svd(centres - middle, full_matrices=False)  # rows
    along = (centres - middle) @ directions.T
    lo = (along - reach[:, None]).min(axis=0) - gap
    hi = (along + reach[:, None]).max(axis=0) + gap
    volume = sobol_volume([primitive], middle, directions, lo, hi, replicates, log2_points,
                          seed)
    while len(_FOLD_VOLUMES) >= _FOLD_VOLUMES_KEPT:
        del _FOLD_VOLUMES[next(iter(_FOLD_VOLUMES))]
    _FOLD_VOLUMES[key] = volume
    return volume


_FOLD_VOLUMES: dict[tuple, tuple[float, float]] = {}
_FOLD_VOLUMES_KEPT = 64


def _sobol_sets(middle: np.ndarray, directions: np.ndarray, lo: np.ndarray, hi: np.ndarray,
                replicates: int, log2_points: int, seed: int) -> Iterator[np.ndarray]:
    """`replicates` independently scrambled Sobol sets of 2**log2_points points (each
    (2**log2_points, 3)) in the box middle (3,) + [lo, hi] (3,) along the rows of
    directions (3, 3), orthonormal."""
    from scipy.stats import qmc

    for k in range(replicates):
        unit = qmc.Sobol(3, scramble=True, seed=seed + k).random_base2(log2_points)
        yield middle + (lo + unit * (hi - lo)) @ directions


def _replicated(shares: np.ndarray, box: float) -> tuple[float, float]:
    """The volume from the shares (R,) of independent replicates' points inside, in a box
    of volume `box` -> (estimate, standard error from their spread)."""
    return (float(shares.mean()) * box,
            float(shares.std(ddof=1)) / math.sqrt(len(shares)) * box)


def sobol_volume(primitives: Sequence[SweepPrimitive], middle: np.ndarray,
                 directions: np.ndarray, lo: np.ndarray, hi: np.ndarray,
                 replicates: int, log2_points: int, seed: int = 0) -> tuple[float, float]:
    """Volume of the union of primitives within the box middle (3,) + [lo, hi] (3,) along
    the rows of directions (3, 3), orthonormal, by the exact inside test at `replicates`
    independently scrambled Sobol sets of 2**log2_points points -> (estimate, standard
    error from the spread of the replicates). The occupancy's boundary is smooth, so such
    points converge faster than random ones."""
    shares = [inside_union(points, primitives).mean()
              for points in _sobol_sets(middle, directions, lo, hi, replicates, log2_points,
                                        seed)]
    return _replicated(np.array(shares), float(np.prod(hi - lo)))


class UnionVolumes:
    """The volume of the union of any of `primitives`, as sobol_volume estimates it in
    the bounding box of all (UNION_REPLICATES sets of 2**UNION_LOG2_POINTS points), in
    the normalised frame: each primitive's occupancy at the points is kept, so that a
    union fused one solid at a time is checked at every step for one inside test a
    primitive (0.1-0.3 s for 6-10 primitives). glyph_8.json's K = 8 fit: 0.095 % from
    262k points in 0.2 s, where plain Monte Carlo (monte_carlo_volume) gave 0.52 % from
    300k in 0.26 s (BENCHMARKS.md, STEP export)."""

    def __init__(self, primitives: Sequence[SweepPrimitive]) -> None:
        lo, hi = union_bounds(primitives)
        self._box = float(np.prod(hi - lo))
        self.count = len(primitives)
        sets = list(_sobol_sets(np.zeros(3), np.eye(3), lo, hi, UNION_REPLICATES,
                                UNION_LOG2_POINTS, 0))
        self._points = sets[0]  # (P, 3), for only_inside
        # one (points, primitives) bool table per replicate
        self._inside = [np.stack([inside_union(points, [p]) for p in primitives], axis=1)
                        for points in sets]

    def volume(self, members: Sequence[int]) -> tuple[float, float]:
        """The union of the primitives at indices `members` -> (estimate, standard error)."""
        columns = list(members)
        return _replicated(np.array([inside[:, columns].any(axis=1).mean()
                                     for inside in self._inside]), self._box)

    def only_inside(self, k: int, count: int) -> np.ndarray:
        """Up to `count` points (n, 3) inside the k-th primitive and no other, spread over
        that part of it (the first in the Sobol set's order), in the normalised frame."""
        inside = self._inside[0]
        alone = inside[:, k] & (inside.sum(axis=1) == 1)
        return self._points[np.flatnonzero(alone)[:count]]


def union_volume(primitives: Sequence[SweepPrimitive]) -> tuple[float, float]:
    """Volume of the union of primitives -> (estimate, standard error), in the
    normalised frame (UnionVolumes)."""
    return UnionVolumes(primitives).volume(range(len(primitives)))


def monte_carlo_volume(primitives: Sequence[SweepPrimitive], samples: int = UNION_SAMPLES,
                       seed: int = 0) -> tuple[float, float]:
    """Volume of the union by the exact inside test at `samples` uniform points of its
    bounding box -> (estimate, standard error), in the normalised frame."""
    lo, hi = union_bounds(primitives)
    rng = np.random.default_rng(seed)
    inside = 0
    for start in range(0, samples, 1 << 18):
        n = min(1 << 18, samples - start)
        inside += int(inside_union(rng.uniform(lo, hi, size=(n, 3)), primitives).sum())
    box = float(np.prod(hi - lo))
    p = inside / samples
    return p * box, box * math.sqrt(max(p * (1.0 - p), 1.0 / samples) / samples)


def union_bounds(primitives: Sequence[SweepPrimitive]) -> tuple[np.ndarray, np.ndarray]:
    """A box (lo, hi (3,)) around the primitives: their control polygons (which hold the
    axes) padded by the largest profile reach."""
    lo = np.full(3, np.inf)
    hi = np.full(3, -np.inf)
    t = np.linspace(0.0, 1.0, 257)
    for p in primitives:
        reach = float(scaling_factor(p.scaling_array, t).max()) * max(p.a, p.b)
        lo = np.minimum(lo, p.control_points.min(axis=0) - reach)
        hi = np.maximum(hi, p.control_points.max(axis=0) + reach)
    return lo, hi
