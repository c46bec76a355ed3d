"""The sweep primitive's math that the Blender side needs, in plain Python and numpy (no bpy).

The definitions are those of sweepedit's docs/primitive.md: a clamped quadratic B-spline
axis with uniform interior knots, a superellipse profile |x/a|^d + |y/b|^d <= 1, a
scaling f(t) = 1 + s1 t + ... + sk t^k and the SweepNet initial frame. This module runs
inside Blender's own Python, so it imports nothing of sweepedit.
"""

from __future__ import annotations

import itertools
import math

# Profiles Blender draws exactly: an ellipse as a rational NURBS, a rhombus as a polygon.
EXACT_DEGREE_TOLERANCE = 1e-9
# How closely a polygon follows a superellipse that Blender cannot draw exactly, relative
# to the profile's larger half-axis, at resolution scale 1 (divided by the scale squared:
# the sag of a chord falls with the square of its length).
POLYGON_TOLERANCE = 2e-3
# The app's 64 stations along an axis (docs/primitive.md, "Display and export resolution").
STATIONS = 64
# Points around an ellipse at resolution scale 1: the app's 48.
ELLIPSE_POINTS = 48
BLENDER_MAX_RESOLUTION = 1024
_EPS = 1e-12


def profile_kind(degree: float) -> str:
    """'ellipse' (d = 2), 'rhombus' (d = 1) or 'polygon' (anything else)."""
    if abs(degree - 2.0) <= EXACT_DEGREE_TOLERANCE:
        return "ellipse"
    if abs(degree - 1.0) <= EXACT_DEGREE_TOLERANCE:
        return "rhombus"
    return "polygon"


def superellipse_point(theta: float, a: float, b: float, d: float) -> tuple[float, float]:
    """x(θ) = a sgn(cos θ)|cos θ|^(2/d), y(θ) = b sgn(sin θ)|sin θ|^(2/d)."""
    c, s = math.cos(theta), math.sin(theta)
    e = 2.0 / d
    return (math.copysign(a * abs(c) ** e, c), math.copysign(b * abs(s) ** e, s))


def _segment_distance(p: tuple[float, float], q0: tuple[float, float],
                      q1: tuple[float, float]) -> float:
    dx, dy = q1[0] - q0[0], q1[1] - q0[1]
    length2 = dx * dx + dy * dy
    u = 0.0 if length2 == 0.0 else max(0.0, min(1.0, ((p[0] - q0[0]) * dx
                                                      + (p[1] - q0[1]) * dy) / length2))
    return math.hypot(p[0] - q0[0] - u * dx, p[1] - q0[1] - u * dy)


def _sag(a: float, b: float, d: float, t0: float, t1: float, samples: int = 16) -> float:
    """Largest distance of the superellipse arc θ in [t0, t1] from its chord."""
    p0, p1 = superellipse_point(t0, a, b, d), superellipse_point(t1, a, b, d)
    return max(_segment_distance(superellipse_point(t0 + (t1 - t0) * i / samples, a, b, d),
                                 p0, p1) for i in range(1, samples))


def quadrant_angles(a: float, b: float, d: float, tolerance: float) -> list[float]:
    """Angles θ in [0, π/2] whose superellipse points make a polygon within `tolerance`
    (absolute) of the arc: chords are halved until their sag is small enough, so points
    crowd where the curve turns (the tips of a star, the corners of a box)."""
    angles = [0.0]
    stack = [(0.0, math.pi / 2.0)]
    while stack:
        t0, t1 = stack.pop()
        if t1 - t0 > 1e-9 and (_sag(a, b, d, t0, t1) > tolerance or t1 - t0 > math.pi / 8):
            mid = 0.5 * (t0 + t1)
            stack.append((mid, t1))
            stack.append((t0, mid))
        else:
            angles.append(t1)
    return angles


def profile_polygon(a: float, b: float, d: float,
                    resolution_scale: float = 1.0) -> tuple[list[tuple[float, float]], float]:
    """A closed polygon (counter-clockwise, first point on +x, no repeat) on the
    superellipse and its largest distance from the true curve, relative to max(a, b).

    d = 1 gives the four corners of the rhombus (exact, error 0). Otherwise the first
    quadrant is refined adaptively (quadrant_angles) and mirrored, so the four tips are
    vertices and the polygon has the profile's symmetries.
    """
    if profile_kind(d) == "rhombus":
        return [(a, 0.0), (0.0, b), (-a, 0.0), (0.0, -b)], 0.0
    size = max(a, b)
    tolerance = POLYGON_TOLERANCE / max(resolution_scale, 1e-3) ** 2 * size
    quad = quadrant_angles(a, b, d, tolerance)
    back = list(reversed(quad))
    angles = (quad[:-1] + [math.pi - t for t in back][:-1] + [math.pi + t for t in quad[:-1]]
              + [2.0 * math.pi - t for t in back][:-1])
    points = [superellipse_point(t, a, b, d) for t in angles]
    error = max(_sag(a, b, d, t0, t1, samples=32) for t0, t1 in itertools.pairwise(quad))
    return points, error / size


def ellipse_nurbs(a: float, b: float) -> list[tuple[float, float, float]]:
    """The 8 weighted control points (x, y, w) of an exact ellipse as a cyclic rational
    quadratic NURBS with Bezier knots (four 90-degree arcs): corner points weigh √2/2."""
    w = math.sqrt(0.5)
    pts = [(1, 0, 1), (1, 1, w), (0, 1, 1), (-1, 1, w), (-1, 0, 1), (-1, -1, w), (0, -1, 1),
           (1, -1, w)]
    return [(a * x, b * y, wt) for x, y, wt in pts]


# --------------------------------------------------------------------------- the axis


def _sub(u: list[float], v: list[float]) -> list[float]:
    return [u[0] - v[0], u[1] - v[1], u[2] - v[2]]


def _dot(u: list[float], v: list[float]) -> float:
    return u[0] * v[0] + u[1] * v[1] + u[2] * v[2]


def _cross(u: list[float], v: list[float]) -> list[float]:
    return [u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0]]


def _unit(v: list[float]) -> list[float]:
    n = math.sqrt(_dot(v, v))
    return [c / max(n, _EPS) for c in v]


def start_tangent(control_points: list[list[float]]) -> list[float]:
    """The unit tangent at t = 0: along c2 - c1, or the chord of the first Bezier segment,
    or its last leg where those vanish (sweep.py's _segment_tangent)."""
    p0 = control_points[0]
    p1 = control_points[1]
    p2 = control_points[2] if len(control_points) == 3 else [
        0.5 * (control_points[1][i] + control_points[2][i]) for i in range(3)]
    for cand in (_sub(p1, p0), _sub(p2, p0), _sub(p2, p1)):
        if _dot(cand, cand) >= 1e-18:
            return _unit(cand)
    return [1.0, 0.0, 0.0]


def initial_frame(T0: list[float]) -> tuple[list[float], list[float]]:
    """U0, V0 of docs/primitive.md: W = (-T0.y, T0.x, 0), or (0, 1, 0) when that
    vanishes; V0 = normalise(T0 x W); U0 = V0 x T0."""
    W = [-T0[1], T0[0], 0.0]
    if _dot(W, W) < 1e-12:
        W = [0.0, 1.0, 0.0]
    V0 = _unit(_cross(T0, W))
    return _cross(V0, T0), V0


def scaling_value(scaling: list[float], t: float) -> float:
    """f(t) = 1 + s1 t + ... + sk t^k."""
    f, power = 1.0, 1.0
    for s in scaling:
        power *= t
        f += s * power
    return f


def axis_resolution(n_control_points: int, resolution_scale: float = 1.0) -> int:
    """Blender's resolution_u (evaluated points per knot span) for an axis of n control
    points: the app's 64 stations over the whole axis, times the scale."""
    spans = max(n_control_points - 2, 1)
    return max(2, min(BLENDER_MAX_RESOLUTION, math.ceil(STATIONS * resolution_scale / spans)))


def fit_scaling_free(ts: list[float], fs: list[float], k: int) -> list[float]:
    """Least squares c0..ck of g(t) = c0 + c1 t + ... + ck t^k through (t, f) points
    (numpy, which Blender bundles)."""
    from numpy.polynomial import polynomial

    return [float(c) for c in polynomial.polyfit(ts, fs, k)]


def fit_degree(points: list[tuple[float, float]], a: float, b: float) -> float:
    """The exponent d in [0.3, 5] whose superellipse best passes through the points
    (least squares of |x/a|^d + |y/b|^d - 1, golden-section search on log d)."""
    def cost(log_d: float) -> float:
        d = math.exp(log_d)
        return sum((abs(x / a) ** d + abs(y / b) ** d - 1.0) ** 2 for x, y in points)
    lo, hi = math.log(0.3), math.log(5.0)
    g = (math.sqrt(5.0) - 1.0) / 2.0
    for _ in range(60):
        m1, m2 = hi - g * (hi - lo), lo + g * (hi - lo)
        if cost(m1) < cost(m2):
            hi = m2
        else:
            lo = m1
    return math.exp(0.5 * (lo + hi))


def srgb_to_linear(c: float) -> float:
    return c / 12.92 if c <= 0.04045 else ((c + 0.055) / 1.055) ** 2.4


def linear_to_srgb(c: float) -> float:
    c = max(0.0, min(1.0, c))
    return c * 12.92 if c <= 0.0031308 else 1.055 * c ** (1.0 / 2.4) - 0.055


def hex_to_linear(color: str) -> tuple[float, float, float]:
    return tuple(srgb_to_linear(int(color[i:i + 2], 16) / 255.0) for i in (1, 3, 5))


def linear_to_hex(rgb: tuple[float, ...]) -> str:
    return "#" + "".join(f"{round(linear_to_srgb(c) * 255):02x}" for c in rgb[:3])
