"""Edits of a primitive's axis that keep its shape: insert or delete a control point,
mirror through a coordinate plane of the shape's frame.

The axis is a clamped quadratic B-spline with uniform interior knots (sweep.py): with n
control points it is m = n - 2 quadratic segments, segment j covering t in [j/m, (j+1)/m].

- 3 -> 4 points is exact: inserting the knot 1/2 into a quadratic Bezier gives the two
  halves of de Casteljau's subdivision, which is the uniform 4-point spline; the curve
  and its parameter stay, so the scaling f(t) stays as it is.
- Otherwise a uniform spline with one point more (or less) cannot hold the old curve in
  general. First the least-squares fit at the same parameter t is tried (exact when the
  old axis lies in the new space, e.g. one quadratic: every 3-point fit after 3 -> 4;
  then the scaling stays as it is). Beyond KEEP_PARAMETER the new control points are
  the geometric least-squares approximation of the old axis sampled densely, with the
  end points kept and the sample parameters corrected by
  projection onto the new curve and tangent distance minimisation. The scaling polynomial is then
  refitted, by least squares, so that f follows the same part of the axis: each new
  parameter is matched to the old parameter at the same fraction of arclength.
- Mirroring negates one coordinate. The frames' initial-frame rule (docs/primitive.md)
  and parallel transport commute with a reflection through a coordinate plane up to the
  sign of U or V, and the superellipse is symmetric in both, so the mirrored control
  points with the same profile and scaling sweep exactly the mirrored solid.

Plain numpy; no Qt, no torch.
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
from scipy.spatial import cKDTree

from sweepedit.geometry.arrays import as_array
from sweepedit.geometry.model import MIN_CONTROL_POINTS, SCALING_RANGE, SweepPrimitive
from sweepedit.geometry.sweep import axis_points, scaling_factor

# Dense samples of the old axis that the new one is fitted to, and parameter corrections.
FIT_SAMPLES = 401
FIT_ITERATIONS = 20
TANGENT_WEIGHT = 0.1  # of the squared error along the tangent
# How densely deviations are measured (per axis), and the bound an insertion must keep.
MEASURE_SAMPLES = 2049
INSERT_MEASURE_SAMPLES = 513  # choosing among the fit's rounds
MAX_DEVIATION = 0.01  # of the old axis length
# A fit at the old parameter this close (of the axis length) is taken as it is: the
# scaling then follows the same part of the axis exactly, without refitting.
KEEP_PARAMETER = 0.005
AXES = {"x": 0, "y": 1, "z": 2}


# -- the B-spline basis -------------------------------------------------------------------

def bspline_basis(n: int, t: np.ndarray, derivative: int = 0) -> np.ndarray:
    """Basis functions (or their derivatives in t, derivative 0, 1 or 2) of the clamped
    uniform quadratic B-spline with n control points: t (M,) -> (M, n), so that
    axis = basis @ control_points. Matches sweep.axis_points."""
    if n < MIN_CONTROL_POINTS:
        raise ValueError(f"a quadratic B-spline needs at least 3 control points, got {n}")
    t = as_array(t, "T", "t")
    m = n - 2
    tm = np.clip(t, 0.0, 1.0) * m
    j = np.clip(np.floor(tm), 0, m - 1).astype(np.int64)
    u = tm - j
    # Segment j's Bezier points: p0 = a0 c_j + (1 - a0) c_{j+1} (a0 = 1 on the first
    # segment, else 1/2), p1 = c_{j+1}, p2 = (1 - a2) c_{j+1} + a2 c_{j+2} (a2 = 1 last).
    a0 = np.where(j == 0, 1.0, 0.5)
    a2 = np.where(j == m - 1, 1.0, 0.5)
    if derivative == 0:
        b0, b1, b2 = (1.0 - u) ** 2, 2.0 * u * (1.0 - u), u**2
    elif derivative == 1:
        b0, b1, b2 = -2.0 * (1.0 - u) * m, (2.0 - 4.0 * u) * m, 2.0 * u * m
    elif derivative == 2:
        b0, b1, b2 = (np.full_like(u, 2.0 * m * m), np.full_like(u, -4.0 * m * m),
                      np.full_like(u, 2.0 * m * m))
    else:
        raise ValueError(f"derivative must be 0, 1 or 2, got {derivative}")
    out = np.zeros((len(t), n))
    rows = np.arange(len(t))
    out[rows, j] = b0 * a0
    out[rows, j + 1] = b0 * (1.0 - a0) + b1 + b2 * (1.0 - a2)
    out[rows, j + 2] = b2 * a2
    return out


def _check_points(control_points: np.ndarray) -> np.ndarray:
    cp = as_array(control_points, "n, 3", "control points")
    if cp.shape[0] < MIN_CONTROL_POINTS:
        raise ValueError(f"a quadratic B-spline needs at least 3 control points, got "
                         f"{cp.shape[0]}")
    return cp


# -- measuring ----------------------------------------------------------------------------

def axis_length(control_points: np.ndarray, samples: int = MEASURE_SAMPLES) -> float:
    """Arclength of the axis (n, 3), from `samples` points."""
    pts = axis_points(_check_points(control_points)[None], np.linspace(0.0, 1.0, samples))[0]
    return float(np.sum(np.linalg.norm(np.diff(pts, axis=0), axis=1)))


def axis_deviation(old: np.ndarray, new: np.ndarray, samples: int = MEASURE_SAMPLES) -> float:
    """The symmetric Hausdorff distance between two axes (n, 3) and (n', 3), measured from
    `samples` points on each to the other's dense polyline points."""
    t = np.linspace(0.0, 1.0, samples)
    a = axis_points(_check_points(old)[None], t)[0]
    b = axis_points(_check_points(new)[None], t)[0]
    d_ab, _ = cKDTree(b).query(a)
    d_ba, _ = cKDTree(a).query(b)
    return float(max(d_ab.max(), d_ba.max()))


def closest_axis_parameter(control_points: np.ndarray, point: np.ndarray,
                           samples: int = MEASURE_SAMPLES) -> float:
    """The parameter t in [0, 1] of the axis point nearest to `point` (3,)."""
    t = np.linspace(0.0, 1.0, samples)
    pts = axis_points(_check_points(control_points)[None], t)[0]
    p = np.asarray(point, dtype=np.float64).reshape(3)
    return float(t[np.argmin(np.sum((pts - p) ** 2, axis=1))])


def _arclength_fraction(points: np.ndarray) -> np.ndarray:
    """(M, 3) polyline -> (M,) cumulative arclength / total, from 0 to 1."""
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(points, axis=0), axis=1))])
    return s / s[-1] if s[-1] > 0 else np.linspace(0.0, 1.0, len(points))


# -- fitting a uniform spline to an axis ----------------------------------------------------

def fit_control_points(target: np.ndarray, params: np.ndarray, n: int,
                tangents: np.ndarray | None = None, tangent_weight: float = 1.0) -> np.ndarray:
    """Least-squares control points (n, 3) of a spline through target (M, 3) at params
    (M,), the first and last control point fixed to the target's ends.

    With the new curve's unit tangents (M, 3) at the params, the error along the
    tangent is weighted down to tangent_weight (tangent distance minimisation, Wang,
    Pottmann and Liu 2006): the squared distance to the tangent line approximates the
    squared distance to the curve far better than the distance to a fixed foot point,
    so the alternation converges in tens of steps instead of thousands."""
    basis = bspline_basis(n, params)
    ends = basis[:, [0]] * target[0] + basis[:, [-1]] * target[-1]  # (M, 3)
    if tangents is None:
        q = np.broadcast_to(np.eye(3), (len(target), 3, 3))
    else:
        shrink = 1.0 - np.sqrt(tangent_weight)
        q = np.eye(3) - shrink * tangents[:, :, None] * tangents[:, None, :]
    # Rows: the 3 weighted error components of each sample; columns: inner points' xyz.
    lhs = np.einsum("ik,iab->iakb", basis[:, 1:-1], q).reshape(3 * len(target), 3 * (n - 2))
    rhs = np.einsum("iab,ib->ia", q, target - ends).reshape(-1)
    solution = np.linalg.lstsq(lhs, rhs, rcond=None)[0].reshape(n - 2, 3)
    return np.vstack([target[0], solution, target[-1]])


def _project(cp: np.ndarray, target: np.ndarray, params: np.ndarray) -> np.ndarray:
    """Parameters (M,) of the points of target (M, 3) on the spline cp (n, 3), by Newton
    steps on (s(u) - p).s'(u) = 0 from `params` (M,): a local search, which keeps each
    sample on its branch of the curve where it comes close to itself; the ends stay 0
    and 1 and the order of the samples is kept."""
    n = len(cp)
    u = np.array(params, dtype=np.float64)
    for _ in range(4):
        r = bspline_basis(n, u) @ cp - target
        d1 = bspline_basis(n, u, 1) @ cp
        d2 = bspline_basis(n, u, 2) @ cp
        g = np.einsum("ij,ij->i", r, d1)
        h = np.einsum("ij,ij->i", d1, d1) + np.einsum("ij,ij->i", r, d2)
        step = np.where(h > 1e-12, -g / np.where(h > 1e-12, h, 1.0), 0.0)
        u = np.clip(u + np.clip(step, -0.05, 0.05), 0.0, 1.0)
    u[0], u[-1] = 0.0, 1.0
    return np.maximum.accumulate(u)


def fit_iterates(target: np.ndarray, n: int, params: np.ndarray,
                 iterations: int = FIT_ITERATIONS,
                 tangent_weight: float = TANGENT_WEIGHT) -> Iterator[np.ndarray]:
    """Successive control points (n, 3) of the uniform quadratic spline fitted to the
    polyline target (M, 3): first the least-squares fit at params (M,), then each
    round of projection and refit; the ends of the target are kept exactly."""
    target = as_array(target, "M, 3", "target")
    u = as_array(params, "M", "params")
    if len(u) != len(target):
        raise ValueError(f"params must hold one parameter per target point: {len(u)} for "
                         f"{len(target)}")
    cp = fit_control_points(target, u, n)
    yield cp
    for _ in range(iterations):
        u = _project(cp, target, u)
        d1 = bspline_basis(n, u, 1) @ cp
        tangents = d1 / np.maximum(np.linalg.norm(d1, axis=1, keepdims=True), 1e-12)
        cp = fit_control_points(target, u, n, tangents, tangent_weight)
        yield cp


def fit_uniform_axis(target: np.ndarray, n: int, params: np.ndarray,
                     iterations: int = FIT_ITERATIONS,
                     tangent_weight: float = TANGENT_WEIGHT) -> np.ndarray:
    """Control points (n, 3) of the uniform quadratic spline closest in the least-squares
    sense to the polyline target (M, 3), from sample parameters params (M,); ends kept."""
    *_, last = fit_iterates(target, n, params, iterations, tangent_weight)
    return last


def refit_scaling(old_cp: np.ndarray, old_scaling: tuple[float, ...], new_cp: np.ndarray,
                  samples: int = MEASURE_SAMPLES) -> tuple[float, ...]:
    """Scaling coefficients (same count) for the axis new_cp such that f follows the
    same part of the axis as f did on old_cp: f_new(t') ~ f_old(t) where t is the old
    parameter at the same fraction of arclength as t'; least squares on dense samples,
    each coefficient kept in SCALING_RANGE (a coefficient that would leave it is held
    at the bound and the others refitted)."""
    k = len(old_scaling)
    if k == 0 or not any(old_scaling):
        return tuple(float(s) for s in old_scaling)  # f = 1 follows any axis exactly
    t = np.linspace(0.0, 1.0, samples)
    frac_old = _arclength_fraction(axis_points(_check_points(old_cp)[None], t)[0])
    frac_new = _arclength_fraction(axis_points(_check_points(new_cp)[None], t)[0])
    t_old = np.interp(frac_new, frac_old, t)
    f_old = scaling_factor(np.asarray(old_scaling, dtype=np.float64)[None], t_old)[0]
    return fit_scaling(f_old, t, k)


def fit_scaling(f: np.ndarray, t: np.ndarray, k: int) -> tuple[float, ...]:
    """Least-squares s1..sk of f(t) = 1 + s1 t + ... + sk t^k through the values f (M,)
    at t (M,), each coefficient kept in SCALING_RANGE (a coefficient that would leave it
    is held at the bound and the others refitted)."""
    if k == 0:
        return ()
    powers = np.stack([t ** (i + 1) for i in range(k)], axis=1)  # (M, k)
    coef = np.zeros(k)
    free = np.ones(k, dtype=bool)
    lo, hi = SCALING_RANGE
    for _ in range(k):  # a small active set: at most k coefficients go to a bound
        rhs = f - 1.0 - powers[:, ~free] @ coef[~free]
        coef[free] = np.linalg.lstsq(powers[:, free], rhs, rcond=None)[0]
        out = free & ((coef < lo) | (coef > hi))
        if not out.any():
            break
        coef[out] = np.clip(coef[out], lo, hi)
        free &= ~out
    return tuple(float(c) for c in np.clip(coef, lo, hi))


# -- the edits ----------------------------------------------------------------------------

def insert_control_point(primitive: SweepPrimitive, t: float | None = None) -> SweepPrimitive:
    """A copy of `primitive` with one control point more, inserted where the axis has
    parameter t (the clicked point; default: the middle of the longest control-polygon
    leg's segment). 3 -> 4 points is exact (knot insertion at 1/2, whatever t). Other
    counts: the least-squares fit at the same parameter when it stays within
    KEEP_PARAMETER (exact for an axis that is one quadratic, as every 3-point fit is;
    the scaling stays), else the geometric fit started from the click's knot, within
    MAX_DEVIATION of the axis length (ValueError otherwise), with the scaling refitted
    to follow the same part of the axis. With uniform knots the click can only steer
    the latter."""
    cp = _check_points(primitive.control_points)
    n = len(cp)
    out = primitive.copy()
    if n == 3:
        c0, c1, c2 = cp
        out.control_points = np.stack([c0, (c0 + c1) / 2.0, (c1 + c2) / 2.0, c2])
        return out
    s = np.linspace(0.0, 1.0, FIT_SAMPLES)
    target = axis_points(cp[None], s)[0]
    length = axis_length(cp)
    kept = _keep_parameter(cp, target, s, n + 1, length)
    if kept is not None:
        out.control_points = kept
        return out
    m = n - 2
    if t is None:
        legs = np.linalg.norm(np.diff(cp, axis=0), axis=1)
        # Leg i (c_i -> c_{i+1}) lies along segments i - 1 and i: split where it is longest.
        i = int(np.argmax(legs))
        t = (min(max(i, 1), m) - 0.5) / m
    t = float(np.clip(t, 0.0, 1.0))
    # Start from the exact knot insertion's parameters: old knots and the new one map
    # piecewise-linearly onto the uniform knots of m + 1 segments. A knot too close to
    # an old one would squeeze a whole new segment into a sliver: keep it central.
    j = min(int(t * m), m - 1)
    t = float(np.clip(t, (j + 0.25) / m, (j + 0.75) / m))
    old_knots = np.concatenate([np.arange(j + 1) / m, [t], np.arange(j + 1, m + 1) / m])
    new_knots = np.linspace(0.0, 1.0, m + 2)
    # The least-squares rounds approach the old axis on average; the bound is on the
    # largest gap, which is not monotone over the rounds: keep the round that is best.
    deviation, new_cp = min(
        ((axis_deviation(cp, c, INSERT_MEASURE_SAMPLES), c)
         for c in fit_iterates(target, n + 1, np.interp(s, old_knots, new_knots))),
        key=lambda pair: pair[0])
    deviation = axis_deviation(cp, new_cp)
    if deviation > MAX_DEVIATION * length:
        raise ValueError(f"inserting a control point would move the axis by "
                         f"{deviation / length:.1%} of its length")
    out.control_points = new_cp
    out.scaling = refit_scaling(cp, primitive.scaling, new_cp)
    return out


def _keep_parameter(cp: np.ndarray, target: np.ndarray, s: np.ndarray, n: int,
                    length: float) -> np.ndarray | None:
    """Control points (n, 3) of the least-squares fit of the axis at its own parameter
    (samples target (M, 3) at s (M,)), when that stays within KEEP_PARAMETER of the axis
    length: then f(t) needs no change. Exact whenever the old axis lies in the new
    spline space, e.g. an axis that is one quadratic (every 3-point fit, after 3 -> 4)."""
    new_cp = fit_control_points(target, s, n)
    return new_cp if axis_deviation(cp, new_cp) <= KEEP_PARAMETER * length else None


def delete_control_point(primitive: SweepPrimitive, index: int) -> SweepPrimitive:
    """A copy of `primitive` with control point `index` removed (at least 3 remain).

    An end point is dropped (the axis now ends at its neighbour; the scaling is kept);
    an interior one gives the least-squares approximation of the old axis by a spline
    with one point less, ends kept: at the same parameter when that stays within
    KEEP_PARAMETER of the axis length (exact when the old axis fits, and the scaling
    stays), else the geometric best fit with the scaling refitted to follow the same
    part of the axis. Which interior point is named does not change the result."""
    cp = _check_points(primitive.control_points)
    n = len(cp)
    if n <= MIN_CONTROL_POINTS:
        raise ValueError(f"an axis needs at least {MIN_CONTROL_POINTS} control points")
    if not -n <= index < n:
        raise IndexError(f"control point {index} does not exist (the axis has {n})")
    index %= n
    out = primitive.copy()
    if index in (0, n - 1):
        out.control_points = np.delete(cp, index, axis=0)
        return out
    s = np.linspace(0.0, 1.0, FIT_SAMPLES)
    target = axis_points(cp[None], s)[0]
    kept = _keep_parameter(cp, target, s, n - 1, axis_length(cp))
    if kept is not None:
        out.control_points = kept
        return out
    new_cp = fit_uniform_axis(target, n - 1, s)
    out.control_points = new_cp
    out.scaling = refit_scaling(cp, primitive.scaling, new_cp)
    return out


def axis_index(axis: int | str) -> int:
    """0, 1, 2 for 'x', 'y', 'z' (or the int itself)."""
    if isinstance(axis, str):
        if axis.lower() not in AXES:
            raise ValueError(f"axis must be x, y or z, got {axis!r}")
        return AXES[axis.lower()]
    if axis not in (0, 1, 2):
        raise ValueError(f"axis must be 0, 1 or 2, got {axis}")
    return int(axis)


def mirror_points(points: np.ndarray, axis: int | str) -> np.ndarray:
    """(..., 3) points reflected through the plane where coordinate `axis` is 0 (the
    shape's box centre in the normalised frame): that coordinate negated, exactly."""
    out = as_array(points, "..., 3", "points").copy()
    out[..., axis_index(axis)] *= -1.0
    return out


def mirror_primitive(primitive: SweepPrimitive, axis: int | str) -> SweepPrimitive:
    """A copy of `primitive` that is its exact mirror image through a coordinate plane.

    Why the profile needs no change: with T' = M T (M the reflection), the initial frame
    rule gives V0' = +-M V0 and U0' = -+M U0 (V0 is the projection of world z onto the
    normal plane, which M keeps or negates with T0's z), parallel transport commutes with
    M, and the superellipse is symmetric under x -> -x and y -> -y."""
    out = primitive.copy()
    out.control_points = mirror_points(primitive.control_points, axis)
    return out


def is_mirror_pair(p: SweepPrimitive, q: SweepPrimitive, axis: int | str,
                   tol: float = 1e-9) -> bool:
    """True when q is p mirrored through the plane of `axis` (geometry only, to tol)."""
    if p.control_points.shape != q.control_points.shape or len(p.scaling) != len(q.scaling):
        return False
    return bool(np.allclose(mirror_points(p.control_points, axis), q.control_points,
                            rtol=0.0, atol=tol)
                and np.allclose(p.profile, q.profile, rtol=0.0, atol=tol)
                and np.allclose(p.scaling, q.scaling, rtol=0.0, atol=tol))
