"""A primitive's side surface as B-spline patches, to a tolerance of the exact sweep (for
STEP export's solids).

The side surface is S(t, θ) = s(t) + f(t) (x(θ) U(t) + y(θ) V(t)) (docs/primitive.md),
linear in the profile point (x, y). So if one quadrant of the profile is a planar
B-spline with control points (x_k, y_k), the side surface over that quadrant is the
tensor-product B-spline whose row k is the space curve C_k(t) = s(t) + f(t) (x_k U(t)
+ y_k V(t)), and only these curves need approximating along t.

Along t each Bezier segment of the axis is interpolated on its own (s, f and the
rotation-minimising frames are analytic inside a segment, but only C1 across joints)
and the pieces are joined with knots of full multiplicity; stations are added until the
control curves are within a tolerance of the exact ones at every midpoint.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from scipy.interpolate import make_interp_spline

from sweepedit.geometry.loft import SideSurface
from sweepedit.geometry.model import SweepPrimitive
from sweepedit.geometry.solid import profile_angles
from sweepedit.geometry.sweep import axis_frames, scaling_factor
from sweepedit.geometry.volumes import superellipse_area

# Largest distance of the profile's B-spline from the superellipse, as a share of the
# profile's area over its perimeter (its "thickness"), and the relative area error allowed.
PROFILE_TOLERANCE = 5e-3
PROFILE_AREA_TOLERANCE = 2.5e-4
# Interpolation nodes per quadrant tried, fewest first.
PROFILE_NODES = (8, 10, 12, 16, 20, 24, 32, 40, 48, 64)
# Largest distance of the side surface's control curves from the exact ones at the
# midpoints between stations, as a share of the profile's reach max(a, b) (times f there).
# 1.5e-3 keeps 200 random primitives' volumes within 5.2e-4 of the closed form (target
# 1e-3) and the largest file at 217 kB (target 250; 257 kB at 1e-3).
AXIS_TOLERANCE = 1.5e-3
MIN_SEGMENT_STATIONS = 5
MAX_SEGMENT_STATIONS = 257


@dataclass(frozen=True)
class ProfileSpline:
    """One quadrant of the unit superellipse (a = b = 1) as a cubic B-spline, from (1, 0)
    to (0, 1): knots (N + 4,) clamped, control points (N, 2)."""

    knots: np.ndarray
    control: np.ndarray


def _quadrant_tangents(degree: float) -> tuple[np.ndarray, np.ndarray]:
    """Unit tangents of the quadrant at (1, 0) and at (0, 1), in the direction of travel:
    along the other axis for d > 1 (smooth tips), along the axis itself for a star (cusps),
    along the straight edge for d = 1."""
    if degree > 1.0:
        return np.array([0.0, 1.0]), np.array([-1.0, 0.0])
    if degree < 1.0:
        return np.array([-1.0, 0.0]), np.array([0.0, 1.0])
    edge = np.array([-1.0, 1.0]) / math.sqrt(2.0)
    return edge, edge


@lru_cache(maxsize=64)
def profile_spline(degree: float) -> ProfileSpline:
    """The quadrant of the unit superellipse of exponent `degree` as a cubic B-spline that
    interpolates it at points placed by curvature (solid.profile_angles), the fewest that
    keep it within PROFILE_TOLERANCE of its thickness and its area within
    PROFILE_AREA_TOLERANCE. The exact tangents at the tips are imposed where that does
    not cost points; for d just above 1 (curvature unbounded at the tips) and just below
    (a tiny cusp) the spline's own ends are kept (a tangent off by well under a degree)."""
    dense = _quadrant_points(degree, np.linspace(0.0, 0.5 * np.pi, 8193))
    exact_area = superellipse_area(1.0, 1.0, degree) / 4.0
    perimeter = 4.0 * float(np.sum(np.linalg.norm(np.diff(dense, axis=0), axis=1)))
    tolerance = PROFILE_TOLERANCE * 4.0 * exact_area / perimeter
    start, end = _quadrant_tangents(degree)
    check = np.linspace(0.0, 1.0, 8 * 1024 + 1)
    for nodes in PROFILE_NODES:
        points = _quadrant_points(degree, profile_angles(degree, 4 * nodes)[:nodes + 1])
        u = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(points, axis=0), axis=1))])
        u /= u[-1]
        # End derivatives in the chord-length parameter: unit direction times the speed.
        tangents = ([(1, start * np.linalg.norm(points[1] - points[0]) / u[1])],
                    [(1, end * np.linalg.norm(points[-1] - points[-2]) / (1.0 - u[-2]))])
        for bc in (tangents, None):
            spl = make_interp_spline(u, points, k=3, bc_type=bc)
            # Control points kept in the quadrant keep the curve in it (convex hull
            # property): by overshooting the axis near a star's cusp, a quadrant would
            # cross its mirror image and the cap's outline would intersect itself.
            spl.c = np.maximum(spl.c, 0.0)
            fine = spl(check)
            area = 0.5 * float(np.sum(fine[:-1, 0] * fine[1:, 1] - fine[1:, 0] * fine[:-1, 1]))
            if (_curve_distance(fine, degree) <= tolerance
                    and abs(area / exact_area - 1.0) <= PROFILE_AREA_TOLERANCE) \
                    or nodes == PROFILE_NODES[-1]:
                return ProfileSpline(np.asarray(spl.t), np.asarray(spl.c))
    raise AssertionError("unreachable: the last node count always returns")


def _curve_distance(points: np.ndarray, degree: float) -> float:
    """Largest distance of points (M, 2) from the unit superellipse, to first order:
    |level - 1| / |grad level| with level = |x|^d + |y|^d (1 on the curve)."""
    ax = np.maximum(np.abs(points), 1e-12)
    level = np.sum(ax**degree, axis=1)
    grad = degree * np.linalg.norm(ax ** (degree - 1.0), axis=1)
    return float(np.max(np.abs(level - 1.0) / grad))


def _quadrant_points(degree: float, theta: np.ndarray) -> np.ndarray:
    """(M,) angles in [0, π/2] -> (M, 2) points of the unit superellipse (exact at the ends)."""
    c = np.clip(np.cos(theta), 0.0, 1.0)
    s = np.clip(np.sin(theta), 0.0, 1.0)
    return np.stack([c ** (2.0 / degree), s ** (2.0 / degree)], axis=1)


def quadrant_controls(primitive: SweepPrimitive) -> list[tuple[np.ndarray, np.ndarray]]:
    """The four quadrants of a primitive's profile, counter-clockwise from the tip on U:
    [(knots (N + 4,), control points (N, 2))] in the profile's (x, y) coordinates."""
    q = profile_spline(primitive.degree)
    k, c = q.knots, q.control * np.array([primitive.a, primitive.b])
    flipped = 1.0 - k[::-1]  # the same spline run backwards
    return [(k, c), (flipped, c[::-1] * [-1.0, 1.0]), (k, c * [-1.0, -1.0]),
            (flipped, c[::-1] * [1.0, -1.0])]


# --------------------------------------------------------------------------- side surface


def _control_curves(primitive: SweepPrimitive, t: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """C_k(t) for profile control points xy (K, 2) at t (M,) -> (M, K, 3)."""
    cps, _, scaling = primitive.batch_arrays()
    fr = axis_frames(cps, t)
    f = scaling_factor(scaling, t)[0]  # (M,)
    offset = xy[None, :, :1] * fr.U[0][:, None, :] + xy[None, :, 1:] * fr.V[0][:, None, :]
    return fr.points[0][:, None, :] + f[:, None, None] * offset


def _segment_spline(primitive: SweepPrimitive, t0: float, t1: float, xy: np.ndarray,
                    tolerance: float) -> tuple[np.ndarray, np.ndarray]:
    """Cubic interpolation of the control curves over one Bezier segment [t0, t1], with
    more stations until every midpoint is within `tolerance` (times f there); the error
    falls as the fourth power of the spacing, which sets the next count.
    -> knots (Nt + 4,), poles (Nt, K, 3)."""
    stations = MIN_SEGMENT_STATIONS
    while True:
        t = np.linspace(t0, t1, stations)
        spl = make_interp_spline(t, _control_curves(primitive, t, xy), k=3)
        mid = 0.5 * (t[:-1] + t[1:])
        err = np.linalg.norm(spl(mid) - _control_curves(primitive, mid, xy), axis=-1).max(axis=1)
        f = scaling_factor(primitive.scaling_array, mid)[0]
        worst = float(np.max(err / (tolerance * f)))
        if worst <= 1.0 or stations >= MAX_SEGMENT_STATIONS:
            return np.asarray(spl.t), np.asarray(spl.c)
        grow = math.ceil((stations - 1) * 1.02 * worst**0.25) + 1
        stations = min(MAX_SEGMENT_STATIONS, max(stations + 2, grow))


def side_surface(primitive: SweepPrimitive, share: float = AXIS_TOLERANCE) -> SideSurface:
    """The side surface of a primitive (see the module's docstring); along t its control
    curves are within `share` of the profile's reach (times f) of the exact ones."""
    quads = quadrant_controls(primitive)
    xy = np.concatenate([c for _, c in quads])  # all quadrants' controls, (4 Nk, 2)
    tolerance = share * max(primitive.a, primitive.b)
    m = primitive.n_control_points - 2
    knots: list[np.ndarray] = []
    poles: list[np.ndarray] = []
    for j in range(m):
        k, c = _segment_spline(primitive, j / m, (j + 1) / m, xy, tolerance)
        # Joined with knots of multiplicity 3 (C0 in parameter; the exact surface is C1):
        # each segment's clamped spline ends on a pole that the next begins on.
        knots.append(k[:-4] if j < m - 1 else k)
        if j > 0:
            knots[-1] = knots[-1][1:]
        poles.append(c if j == 0 else c[1:])
    all_poles = np.concatenate(poles)  # (Nt, 4 Nk, 3)
    split = np.cumsum([len(c) for _, c in quads])[:-1]
    return SideSurface(np.concatenate(knots),
                       [(k, p) for (k, _), p in zip(quads, np.split(all_poles, split, axis=1),
                                                      strict=True)])
