"""The sweep math of docs/primitive.md, written once for numpy and torch.

Every function takes arrays of either library (through array_api_compat) and returns
arrays of the same library, so the mesher and the exact inside test (numpy, float64)
and the differentiable fitting code (torch, with autograd) share one definition.

Shapes: K primitives, n control points, M parameter values t, P profile points.
  control_points (K, n, 3); t (M,); profile [a, b, d] (K, 3); scaling (K, k).

Frames are rotation-minimising. A clamped quadratic B-spline is a chain of quadratic
Bezier segments, each of which lies in a plane; along a planar curve the rotation-
minimising frame is the initial frame turned by the minimal rotation that takes the
initial tangent to the current one. So the frames are exact and closed form within a
segment, and a loop runs only over the n - 2 segments, not over the stations.
"""

from __future__ import annotations

from typing import Any, NamedTuple

from array_api_compat import array_namespace, is_numpy_namespace

# Keeps divisions and powers finite (and their gradients) at degenerate points.
_EPS = 1e-9
_POW_EPS = 1e-6


class SegmentFrames(NamedTuple):
    """What each Bezier segment of the axes starts with, each (K, m, 3): its unit
    tangent there, its frame U, V (carried over from the segments before), and the unit
    normal of its plane; planar (K, m, 1) bool (_segment_binormal)."""

    tangent: Any
    U: Any
    V: Any
    normal: Any
    planar: Any


class AxisFrames(NamedTuple):
    """Axis points and rotation-minimising frames, each (K, M, 3); U x V = T."""

    points: Any
    U: Any
    V: Any
    T: Any


def _dot(xp: Any, u: Any, v: Any) -> Any:
    if is_numpy_namespace(xp):
        # Written out for numpy, whose reduction over a last axis of 3 is 4x slower (the
        # exact inside test's root search and frames); torch's sum is the faster there.
        return u[..., 0:1] * v[..., 0:1] + u[..., 1:2] * v[..., 1:2] + u[..., 2:3] * v[..., 2:3]
    return xp.sum(u * v, axis=-1, keepdims=True)


def _cross(xp: Any, u: Any, v: Any) -> Any:
    # Written out: for the small arrays of live editing this is several times faster
    # than numpy's general cross (which moves axes around), and the same in torch.
    u0, u1, u2 = u[..., 0:1], u[..., 1:2], u[..., 2:3]
    v0, v1, v2 = v[..., 0:1], v[..., 1:2], v[..., 2:3]
    return xp.concat([u1 * v2 - u2 * v1, u2 * v0 - u0 * v2, u0 * v1 - u1 * v0], axis=-1)


def _normalize(xp: Any, v: Any, eps: float = _EPS) -> Any:
    # Exactly unit for |v| >= eps (a tangent near a cusp is short but must stay unit);
    # shorter vectors are divided by eps instead, which keeps gradients finite.
    return v / xp.sqrt(xp.maximum(_dot(xp, v, v), xp.full_like(v[..., :1], eps * eps)))


def bezier_segments(control_points: Any) -> tuple[Any, Any, Any]:
    """Bezier control points of the clamped uniform quadratic B-spline's segments.

    control_points: (K, n, 3) -> P0, P1, P2 each (K, n - 2, 3).
    With uniform interior knots, segment j runs from the midpoint of c_j, c_{j+1}
    (c_0 for the first) over c_{j+1} to the midpoint of c_{j+1}, c_{j+2} (c_{n-1} last).
    """
    xp = array_namespace(control_points)
    c = control_points
    mids = (c[:, 1:-2, :] + c[:, 2:-1, :]) / 2.0  # (K, n-3, 3): joints between segments
    p0 = xp.concat([c[:, :1, :], mids], axis=1)
    p1 = c[:, 1:-1, :]
    p2 = xp.concat([mids, c[:, -1:, :]], axis=1)
    return p0, p1, p2


def _segment_index(xp: Any, t: Any, m: int) -> tuple[Any, Any]:
    """Segment j (M,) int and local parameter u (M,) in [0, 1] of global t (M,)."""
    tm = xp.clip(t, 0.0, 1.0) * m
    j = xp.clip(xp.floor(tm), 0, m - 1)
    u = tm - j
    return xp.astype(j, xp.int64), u


def _segment_binormal(xp: Any, d0: Any, d1: Any, chord: Any) -> tuple[Any, Any]:
    """Unit normal of a quadratic segment's plane, from its legs d0, d1 and its chord
    d0 + d1 = p2 - p0 (..., 3).

    -> n (..., 3) and planar (..., 1) bool, False where the legs are collinear to rounding
    (then n is arbitrary). Taken from the control points, not from sampled tangents, so
    it is the same exact axis at every sample of the segment. n = d0 x chord (= d0 x d1):
    where the axis folds back, d1 ~ -d0 and d0 x d1 cancels to rounding noise of the
    legs' size, while the short chord, a difference of nearby points, is exact.
    """
    n = _cross(xp, d0, chord)
    nn = _dot(xp, n, n)
    planar = nn > (64.0 * xp.finfo(n.dtype).eps) ** 2 * _dot(xp, d0, d0) * _dot(xp, d1, d1)
    # Relative, not _normalize's absolute eps: a normal of length 1e-13 is still exact.
    return n / xp.sqrt(xp.where(planar, nn, xp.ones_like(nn))), planar


def _minimal_rotation(xp: Any, a: Any, b: Any, u: Any, v: Any,
                      n: Any, planar: Any) -> tuple[Any, Any]:
    """Rotate the frame (u, v) at unit tangent a by the smallest rotation taking a to b.

    a, b: unit tangents of one quadratic segment, which is planar, so the turn is about
    the segment's unit normal n (from _segment_binormal). For a turn below pi/2,
    R x = c x + w x x + w (w.x) / (1 + c), w = a x b, c = a.b (Rodrigues without
    normalising the axis, smooth as a -> b). Beyond, near a fold back, w is tiny and its
    direction rounding noise, so the rotation is about n by the angle of (c, w.n). Where
    the segment is collinear (not planar) and folds back exactly, every rotation by pi
    about an axis normal to a is minimal: the one about u is taken (u stays, v flips).
    All (..., 3); planar (..., 1).
    """
    w = _cross(xp, a, b)
    c = _dot(xp, a, b)
    forward = c >= 0.0
    one = xp.ones_like(c)
    k = 1.0 / xp.where(forward, 1.0 + c, one)  # both branches are evaluated: keep finite
    s = _dot(xp, w, n)

    def rotate(x: Any) -> Any:
        near = c * x + _cross(xp, w, x) + w * _dot(xp, w, x) * k
        about_n = c * x + s * _cross(xp, n, x) + (1.0 - c) * _dot(xp, n, x) * n
        return xp.where(forward, near, about_n)

    # The exact fold: u, made normal to b, and v = b x u (= -v when b = -a exactly),
    # so the frame stays orthonormal and right-handed.
    folded = (~forward) & (~planar)
    u_fold = _normalize(xp, u - b * _dot(xp, u, b))
    return (xp.where(folded, u_fold, rotate(u)),
            xp.where(folded, _cross(xp, b, u_fold), rotate(v)))


def initial_frame(T0: Any) -> tuple[Any, Any]:
    """The frame at t = 0 as in docs/primitive.md and the official SweepNet code.

    T0: (..., 3) unit tangent -> U0, V0 (..., 3). W = (-T0.y, T0.x, 0), or (0, 1, 0)
    when that vanishes (tangent along z); V0 = normalize(T0 x W); U0 = V0 x T0.
    """
    xp = array_namespace(T0)
    zero = xp.zeros_like(T0[..., :1])
    W = xp.concat([-T0[..., 1:2], T0[..., 0:1], zero], axis=-1)
    degenerate = _dot(xp, W, W) < 1e-12
    W = xp.where(degenerate, xp.concat([zero, zero + 1.0, zero], axis=-1), W)
    V0 = _normalize(xp, _cross(xp, T0, W))
    U0 = _cross(xp, V0, T0)
    return U0, V0


def _segment_tangent(xp: Any, *candidates: Any) -> Any:
    """Unit tangent from the first candidate direction that does not vanish (a derivative
    that is zero at a cusp falls back on the chord, a closed chord on the first leg)."""
    direction = candidates[-1]
    for cand in reversed(candidates[:-1]):
        direction = xp.where(_dot(xp, cand, cand) < 1e-18, direction, cand)
    return _normalize(xp, direction)


def segment_frames(control_points: Any) -> SegmentFrames:
    """The frames the axes' Bezier segments start with: control_points (K, n, 3) ->
    SegmentFrames, each (K, n - 2, ...). Within segment j the frame at t is its start
    frame turned by the minimal rotation from its start tangent to the tangent at t
    (axis_frames)."""
    return _segment_frames(array_namespace(control_points), *bezier_segments(control_points))


def _segment_frames(xp: Any, p0: Any, p1: Any, p2: Any) -> SegmentFrames:
    """segment_frames of the axes' Bezier segments p0, p1, p2 (K, m, 3)."""
    m = p0.shape[1]
    d0 = p1 - p0  # derivative / 2 at u = 0 of each segment, (K, m, 3)
    d1 = p2 - p1  # derivative / 2 at u = 1
    chord = p2 - p0
    t_start = _segment_tangent(xp, d0, chord, d1)
    t_end = _segment_tangent(xp, d1, chord, -d0)

    normal, planar = _segment_binormal(xp, d0, d1, chord)  # (K, m, 3), (K, m, 1)

    # Carry the frame across segments: the B-spline is C1, so each segment starts
    # with the tangent the previous one ended with.
    U, V = initial_frame(t_start[:, 0, :])
    starts_u, starts_v = [U], [V]
    for j in range(1, m):
        U, V = _minimal_rotation(xp, t_start[:, j - 1, :], t_end[:, j - 1, :], U, V,
                                 normal[:, j - 1, :], planar[:, j - 1, :])
        starts_u.append(U)
        starts_v.append(V)
    return SegmentFrames(t_start, xp.stack(starts_u, axis=1), xp.stack(starts_v, axis=1),
                         normal, planar)


def axis_frames(control_points: Any, t: Any) -> AxisFrames:
    """Points and rotation-minimising frames of the axes at parameters t.

    control_points: (K, n, 3); t: (M,) in [0, 1] -> AxisFrames, each (K, M, 3).
    """
    xp = array_namespace(control_points, t)
    p0, p1, p2 = bezier_segments(control_points)
    # The same segments for the frames: a second copy in torch's graph changes the order
    # in which gradients add up, and the fits with it (the bundled cactus: 6 primitives,
    # not 5).
    start = _segment_frames(xp, p0, p1, p2)
    j, u = _segment_index(xp, t, p0.shape[1])
    take = lambda arr: xp.take(arr, j, axis=1)  # noqa: E731  (K, m, 3) -> (K, M, 3)
    points, T = _points_and_tangents(xp, take(p0), take(p1), take(p2), u)
    U, V = _minimal_rotation(xp, take(start.tangent), T, take(start.U), take(start.V),
                             take(start.normal), take(start.planar))
    return AxisFrames(points, U, V, T)


def _bezier_points(a0: Any, a1: Any, a2: Any, u: Any) -> Any:
    """Points of quadratic Bezier segments a0, a1, a2 (K, M, 3) at local parameters
    u (M,) -> (K, M, 3)."""
    u3 = u[None, :, None]
    return (1.0 - u3) ** 2 * a0 + 2.0 * u3 * (1.0 - u3) * a1 + u3**2 * a2


def _points_and_tangents(xp: Any, a0: Any, a1: Any, a2: Any, u: Any) -> tuple[Any, Any]:
    """Points and unit tangents of quadratic Bezier segments a0, a1, a2 (K, M, 3) at local
    parameters u (M,) -> each (K, M, 3)."""
    u3 = u[None, :, None]
    deriv = (1.0 - u3) * (a1 - a0) + u3 * (a2 - a1)
    return _bezier_points(a0, a1, a2, u), _segment_tangent(xp, deriv, a2 - a0, a1 - a0)


def _segments_at(control_points: Any, t: Any) -> tuple[Any, Any, Any, Any, Any]:
    """The Bezier segment holding each t and the local parameter there:
    control_points (K, n, 3), t (M,) -> xp, a0, a1, a2 (K, M, 3), u (M,)."""
    xp = array_namespace(control_points, t)
    p0, p1, p2 = bezier_segments(control_points)
    j, u = _segment_index(xp, t, p0.shape[1])
    a0, a1, a2 = (xp.take(p, j, axis=1) for p in (p0, p1, p2))
    return xp, a0, a1, a2, u


def axis_points_tangents(control_points: Any, t: Any) -> tuple[Any, Any]:
    """Points and unit tangents of the axes, the same as axis_frames' but without the
    frames (the exact inside test's root search needs only the planes):
    control_points (K, n, 3), t (M,) -> each (K, M, 3)."""
    xp, a0, a1, a2, u = _segments_at(control_points, t)
    return _points_and_tangents(xp, a0, a1, a2, u)


def axis_points(control_points: Any, t: Any) -> Any:
    """Points of the axes: control_points (K, n, 3), t (M,) -> (K, M, 3)."""
    _, a0, a1, a2, u = _segments_at(control_points, t)
    return _bezier_points(a0, a1, a2, u)


def scaling_factor(scaling: Any, t: Any) -> Any:
    """f(t) = 1 + s1 t + ... + sk t^k: scaling (K, k), t (M,) -> (K, M)."""
    xp = array_namespace(scaling, t)
    f = xp.ones((scaling.shape[0], t.shape[0]), dtype=t.dtype, device=getattr(t, "device", None))
    power = xp.ones_like(t)
    for i in range(scaling.shape[1]):
        power = power * t
        f = f + scaling[:, i : i + 1] * power[None, :]
    return f


def superellipse(theta: Any, profile: Any) -> tuple[Any, Any]:
    """Profile points x(θ) = a sgn(cos θ)|cos θ|^(2/d), y likewise with b and sin.

    theta (P,), profile (K, 3) = [a, b, d] -> x, y each (K, P).
    """
    xp = array_namespace(theta, profile)
    a, b, d = profile[:, 0:1], profile[:, 1:2], profile[:, 2:3]
    c, s = xp.cos(theta)[None, :], xp.sin(theta)[None, :]
    e = 2.0 / d
    x = a * xp.sign(c) * xp.clip(xp.abs(c), min=_POW_EPS) ** e
    y = b * xp.sign(s) * xp.clip(xp.abs(s), min=_POW_EPS) ** e
    return x, y


def superellipse_level(x: Any, y: Any, profile: Any) -> Any:
    """|x/a|^d + |y/b|^d (<= 1 inside): x, y (K, ...) and profile (K, 3) -> (K, ...)."""
    xp = array_namespace(x, y, profile)
    extra = (1,) * (x.ndim - 1)
    a = xp.reshape(profile[:, 0], (-1, *extra))
    b = xp.reshape(profile[:, 1], (-1, *extra))
    d = xp.reshape(profile[:, 2], (-1, *extra))
    return (xp.clip(xp.abs(x / a), min=1e-12) ** d) + (xp.clip(xp.abs(y / b), min=1e-12) ** d)


def sweep_surface(control_points: Any, profile: Any, scaling: Any, t: Any, theta: Any) -> Any:
    """Points on the side surface: stations t (M,), profile angles theta (P,) -> (K, M, P, 3)."""
    fr = axis_frames(control_points, t)
    x, y = superellipse(theta, profile)  # (K, P)
    f = scaling_factor(scaling, t)[:, :, None, None]  # (K, M, 1, 1)
    offset = x[:, None, :, None] * fr.U[:, :, None, :] + y[:, None, :, None] * fr.V[:, :, None, :]
    return fr.points[:, :, None, :] + f * offset


def _axis_derivatives(xp: Any, control_points: Any, t: Any) -> tuple[Any, Any]:
    """First and second derivatives s'(t), s''(t) of the axes: (K, n, 3), t (M,) -> each
    (K, M, 3) (s'' is constant over each segment)."""
    p0, p1, p2 = bezier_segments(control_points)
    m = p0.shape[1]
    j, u = _segment_index(xp, t, m)
    a0, a1, a2 = (xp.take(p, j, axis=1) for p in (p0, p1, p2))
    u3 = u[None, :, None]
    # Global t runs m times faster than a segment's u: d/dt = m d/du.
    d1 = 2.0 * m * ((1.0 - u3) * (a1 - a0) + u3 * (a2 - a1))
    d2 = 2.0 * m * m * (a2 - 2.0 * a1 + a0)
    return d1, d2


def axis_speed(control_points: Any, t: Any) -> Any:
    """|s'(t)| of the axes: control_points (K, n, 3), t (M,) -> (K, M)."""
    xp = array_namespace(control_points, t)
    d1, _ = _axis_derivatives(xp, control_points, t)
    return xp.sqrt(_dot(xp, d1, d1))[..., 0]


def axis_curvature(control_points: Any, t: Any) -> Any:
    """Curvature |s' x s''| / |s'|^3 of the axes: control_points (K, n, 3), t (M,) -> (K, M).

    A sweep whose profile reaches farther from the axis than 1 / curvature folds
    onto itself on the inner side of the bend.
    """
    xp = array_namespace(control_points, t)
    d1, d2 = _axis_derivatives(xp, control_points, t)
    num = xp.sqrt(_dot(xp, _cross(xp, d1, d2), _cross(xp, d1, d2)))[..., 0]
    speed = xp.sqrt(_dot(xp, d1, d1))[..., 0]
    return num / xp.clip(speed, min=_EPS) ** 3


def axis_curvature_vectors(control_points: Any, t: Any) -> Any:
    """Curvature vectors κN = (s'' - (s''.T) T) / |s'|^2: (K, n, 3), t (M,) -> (K, M, 3).

    Along rotation-minimising frames a profile offset o = x U + y V moves along T at
    the rate |s'| (1 - f o.κN): where that turns negative the sweep folds onto itself.
    """
    xp = array_namespace(control_points, t)
    d1, d2 = _axis_derivatives(xp, control_points, t)
    speed2 = xp.clip(_dot(xp, d1, d1), min=_EPS)
    return (d2 - d1 * _dot(xp, d2, d1) / speed2) / speed2


def fold_vectors(control_points: Any, scaling: Any, t: Any) -> Any:
    """q(t) = f (κN . U, κN . V): (K, n, 3), scaling (K, k), t (M,) -> (K, M, 2).

    A profile point o = (x, y) moves along the axis at the rate 1 - o . q(t) relative to
    the axis itself; where that is negative the sweep runs backwards and folds onto itself.
    """
    xp = array_namespace(control_points, t)
    fr = axis_frames(control_points, t)
    k = axis_curvature_vectors(control_points, t)
    f = scaling_factor(scaling, t)[..., None]
    return f * xp.concat([_dot(xp, fr.U, k), _dot(xp, fr.V, k)], axis=-1)
