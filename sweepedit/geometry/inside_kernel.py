"""The exact inside test (inside.py) as one compiled loop per point.

For each point it does what inside.py's docstring says: the box and tube filters,
h(t) = (p - s(t)).T(t) at the axis samples, its sign changes where the point is within
reach of the sample, REFINE_STEPS of regula falsi on the exact curve, and the profile
test at each root. As numpy array operations over all points this took 1.7 ms a call
whatever its size and about 2 µs a point, and STEP export's slicer calls the test ~125
times per folding primitive (BENCHMARKS.md, STEP export). numba; compiled on first use
and cached on disk.

A root is settled by the point's radius in its plane where that is within the profile's
inscribed circle or beyond its circumscribed one (inside.profile_radii2), else by the
profile test in the root's frame. Written out here for one point, each held to sweep.py
by tests/test_geometry.py: the axis point and unit tangent at t (_axis_at: sweep.py's
_points_and_tangents), f(t) (_scaling_at: its scaling_factor), the frame at t
(_frame_at: its _minimal_rotation of the segment's start frame, which sweep.py's
segment_frames makes once per primitive) and the profile's level (its
superellipse_level). Numpy's frames at the roots took 40 % of the slicer's inside tests.
"""

from __future__ import annotations

import math

import numba
import numpy as np


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _axis_at(p0: np.ndarray, p1: np.ndarray, p2: np.ndarray, t: float
             ) -> tuple[float, float, float, float, float, float]:
    """The axis point s(t) and unit tangent T(t) of the axis whose Bezier segments are
    p0, p1, p2 (m, 3) (sweep.bezier_segments): the tangent is the derivative's
    direction, else the chord's, else the first leg's (sweep._segment_tangent)."""
    m = p0.shape[0]
    tm = min(max(t, 0.0), 1.0) * m
    j = min(max(math.floor(tm), 0.0), m - 1.0)
    u = tm - j
    k = int(j)
    w0, w1, w2 = (1.0 - u) ** 2, 2.0 * u * (1.0 - u), u * u
    a0x, a0y, a0z = p0[k, 0], p0[k, 1], p0[k, 2]
    a1x, a1y, a1z = p1[k, 0], p1[k, 1], p1[k, 2]
    a2x, a2y, a2z = p2[k, 0], p2[k, 1], p2[k, 2]
    vx = (1.0 - u) * (a1x - a0x) + u * (a2x - a1x)
    vy = (1.0 - u) * (a1y - a0y) + u * (a2y - a1y)
    vz = (1.0 - u) * (a1z - a0z) + u * (a2z - a1z)
    vv = vx * vx + vy * vy + vz * vz
    if vv < 1e-18:
        vx, vy, vz = a2x - a0x, a2y - a0y, a2z - a0z
        vv = vx * vx + vy * vy + vz * vz
        if vv < 1e-18:
            vx, vy, vz = a1x - a0x, a1y - a0y, a1z - a0z
            vv = vx * vx + vy * vy + vz * vz
    norm = math.sqrt(max(vv, 1e-18))
    return (w0 * a0x + w1 * a1x + w2 * a2x, w0 * a0y + w1 * a1y + w2 * a2y,
            w0 * a0z + w1 * a1z + w2 * a2z, vx / norm, vy / norm, vz / norm)


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _plane_offset_at(px: float, py: float, pz: float, p0: np.ndarray, p1: np.ndarray,
                     p2: np.ndarray, t: float) -> float:
    """h(t) = (p - s(t)).T(t) for the point (px, py, pz) (_axis_at)."""
    sx, sy, sz, tx, ty, tz = _axis_at(p0, p1, p2, t)
    return (px - sx) * tx + (py - sy) * ty + (pz - sz) * tz


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _scaling_at(scaling: np.ndarray, t: float) -> float:
    """f(t) = 1 + s1 t + ... + sk t^k for scaling (k,) (sweep.scaling_factor)."""
    f = 1.0
    power = 1.0
    for i in range(scaling.shape[0]):
        power *= t
        f += scaling[i] * power
    return f


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _in_plane_radius2(px: float, py: float, pz: float, p0: np.ndarray, p1: np.ndarray,
                      p2: np.ndarray, scaling: np.ndarray, t: float) -> float:
    """The squared distance of the point from the axis point s(t) within the profile
    plane at t, divided by f(t)^2 (inf where f(t) <= 0): x^2 + y^2 of the profile test,
    whatever the frame's turn about the tangent."""
    sx, sy, sz, tx, ty, tz = _axis_at(p0, p1, p2, t)
    rx, ry, rz = px - sx, py - sy, pz - sz
    h = rx * tx + ry * ty + rz * tz
    f = _scaling_at(scaling, t)
    if f <= 0.0:
        return math.inf
    return max(rx * rx + ry * ry + rz * rz - h * h, 0.0) / (f * f)


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _turned(c: float, k: float, forward: bool, s: float, wx: float, wy: float, wz: float,
            nx: float, ny: float, nz: float, x0: float, x1: float, x2: float
            ) -> tuple[float, float, float]:
    """sweep._minimal_rotation's rotate(x) for one vector (x0, x1, x2)."""
    if forward:
        wdx = (wx * x0 + wy * x1 + wz * x2) * k
        return (c * x0 + (wy * x2 - wz * x1) + wx * wdx,
                c * x1 + (wz * x0 - wx * x2) + wy * wdx,
                c * x2 + (wx * x1 - wy * x0) + wz * wdx)
    ndx = (1.0 - c) * (nx * x0 + ny * x1 + nz * x2)
    return (c * x0 + s * (ny * x2 - nz * x1) + ndx * nx,
            c * x1 + s * (nz * x0 - nx * x2) + ndx * ny,
            c * x2 + s * (nx * x1 - ny * x0) + ndx * nz)


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _frame_at(start: np.ndarray, j: int, bx: float, by: float, bz: float
              ) -> tuple[float, float, float, float, float, float]:
    """The frame U, V where segment j's tangent is (bx, by, bz): its start frame turned
    by sweep._minimal_rotation. start (m, 13): per segment its start tangent, U, V,
    normal (3 each) and planar (1.0 or 0.0), from sweep.segment_frames."""
    ax, ay, az = start[j, 0], start[j, 1], start[j, 2]
    ux, uy, uz = start[j, 3], start[j, 4], start[j, 5]
    nx, ny, nz = start[j, 9], start[j, 10], start[j, 11]
    wx, wy, wz = ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx
    c = ax * bx + ay * by + az * bz
    forward = c >= 0.0
    if not forward and start[j, 12] == 0.0:
        # The exact fold: U made normal to the tangent, V = T x U (sweep.py).
        ub = ux * bx + uy * by + uz * bz
        fx, fy, fz = ux - bx * ub, uy - by * ub, uz - bz * ub
        norm = math.sqrt(max(fx * fx + fy * fy + fz * fz, 1e-18))
        fx, fy, fz = fx / norm, fy / norm, fz / norm
        return fx, fy, fz, by * fz - bz * fy, bz * fx - bx * fz, bx * fy - by * fx
    k = 1.0 / (1.0 + c) if forward else 1.0
    s = wx * nx + wy * ny + wz * nz
    ux, uy, uz = _turned(c, k, forward, s, wx, wy, wz, nx, ny, nz, ux, uy, uz)
    vx, vy, vz = _turned(c, k, forward, s, wx, wy, wz, nx, ny, nz,
                         start[j, 6], start[j, 7], start[j, 8])
    return ux, uy, uz, vx, vy, vz


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _unit_tangent(ax: float, ay: float, az: float, bx: float, by: float, bz: float,
                  cx: float, cy: float, cz: float) -> tuple[float, float, float]:
    """sweep._segment_tangent of the candidates a, b, c: the first whose square length
    is at least 1e-18, normalised as sweep._normalize does (by at least 1e-9)."""
    vx, vy, vz = ax, ay, az
    if vx * vx + vy * vy + vz * vz < 1e-18:
        vx, vy, vz = bx, by, bz
        if vx * vx + vy * vy + vz * vz < 1e-18:
            vx, vy, vz = cx, cy, cz
    norm = math.sqrt(max(vx * vx + vy * vy + vz * vz, 1e-18))
    return vx / norm, vy / norm, vz / norm


@numba.njit(cache=True, nogil=True, error_model="numpy")
def segment_start_frames(p0: np.ndarray, p1: np.ndarray, p2: np.ndarray,
                         start: np.ndarray) -> None:
    """sweep.segment_frames of one axis, Bezier segments p0, p1, p2 (m, 3), written to
    start (m, 13) as _frame_at reads it: per segment its start tangent, U, V, the unit
    normal of its plane and planar (1.0 or 0.0). The initial frame is sweep.initial_frame's
    and each segment's frame is the previous one turned to its start tangent (_frame_at)."""
    eps64 = (64.0 * 2.220446049250313e-16) ** 2
    end_x = end_y = end_z = 0.0
    for j in range(p0.shape[0]):
        d0x, d0y, d0z = p1[j, 0] - p0[j, 0], p1[j, 1] - p0[j, 1], p1[j, 2] - p0[j, 2]
        d1x, d1y, d1z = p2[j, 0] - p1[j, 0], p2[j, 1] - p1[j, 1], p2[j, 2] - p1[j, 2]
        cx, cy, cz = p2[j, 0] - p0[j, 0], p2[j, 1] - p0[j, 1], p2[j, 2] - p0[j, 2]
        ax, ay, az = _unit_tangent(d0x, d0y, d0z, cx, cy, cz, d1x, d1y, d1z)
        # sweep._segment_binormal: n = d0 x chord, planar unless the legs are collinear
        # to rounding.
        nx, ny, nz = d0y * cz - d0z * cy, d0z * cx - d0x * cz, d0x * cy - d0y * cx
        nn = nx * nx + ny * ny + nz * nz
        planar = nn > eps64 * (d0x * d0x + d0y * d0y + d0z * d0z) * (
            d1x * d1x + d1y * d1y + d1z * d1z)
        scale = math.sqrt(nn) if planar else 1.0
        start[j, 0], start[j, 1], start[j, 2] = ax, ay, az
        start[j, 9], start[j, 10], start[j, 11] = nx / scale, ny / scale, nz / scale
        start[j, 12] = 1.0 if planar else 0.0
        if j == 0:
            # sweep.initial_frame: W = (-T.y, T.x, 0), or (0, 1, 0) where that vanishes;
            # V = normalize(T x W), U = V x T.
            wx, wy, wz = -ay, ax, 0.0
            if wx * wx + wy * wy < 1e-12:
                wx, wy, wz = 0.0, 1.0, 0.0
            vx, vy, vz = ay * wz - az * wy, az * wx - ax * wz, ax * wy - ay * wx
            norm = math.sqrt(max(vx * vx + vy * vy + vz * vz, 1e-18))
            vx, vy, vz = vx / norm, vy / norm, vz / norm
            ux, uy, uz = vy * az - vz * ay, vz * ax - vx * az, vx * ay - vy * ax
        else:
            ux, uy, uz, vx, vy, vz = _frame_at(start, j - 1, end_x, end_y, end_z)
        start[j, 3], start[j, 4], start[j, 5] = ux, uy, uz
        start[j, 6], start[j, 7], start[j, 8] = vx, vy, vz
        end_x, end_y, end_z = _unit_tangent(d1x, d1y, d1z, cx, cy, cz, -d0x, -d0y, -d0z)


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _profile_level_at(px: float, py: float, pz: float, p0: np.ndarray, p1: np.ndarray,
                      p2: np.ndarray, start: np.ndarray, scaling: np.ndarray,
                      profile: np.ndarray, t: float) -> float:
    """|x/a|^d + |y/b|^d of the point in the profile plane at t (<= 1 inside), with
    x, y its coordinates in the frame at t over f(t) (> 0), as sweep.superellipse_level
    computes it; profile (3,) = a, b, d; start as _frame_at's."""
    sx, sy, sz, tx, ty, tz = _axis_at(p0, p1, p2, t)
    m = p0.shape[0]
    j = int(min(max(math.floor(min(max(t, 0.0), 1.0) * m), 0.0), m - 1.0))
    ux, uy, uz, vx, vy, vz = _frame_at(start, j, tx, ty, tz)
    rx, ry, rz = px - sx, py - sy, pz - sz
    f = _scaling_at(scaling, t)
    x = (rx * ux + ry * uy + rz * uz) / f
    y = (rx * vx + ry * vy + rz * vz) / f
    d = profile[2]
    return max(abs(x / profile[0]), 1e-12) ** d + max(abs(y / profile[1]), 1e-12) ** d


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _regula_falsi(px: float, py: float, pz: float, p0: np.ndarray, p1: np.ndarray,
                  p2: np.ndarray, t0: float, t1: float, h0: float, h1: float,
                  steps: int) -> float:
    """The root of h in the bracket [t0, t1] (h0, h1 of opposite signs) after `steps`
    steps of regula falsi, and one more interpolation."""
    for _ in range(steps):
        den = h0 - h1
        tm = t0 + (t1 - t0) * h0 / (den if den != 0.0 else 1.0)
        tm = min(max(tm, min(t0, t1)), max(t0, t1))
        hm = _plane_offset_at(px, py, pz, p0, p1, p2, tm)
        if np.sign(hm) == np.sign(h0):
            t0, h0 = tm, hm
        else:
            t1, h1 = tm, hm
    den = h0 - h1
    return t0 + (t1 - t0) * h0 / (den if den != 0.0 else 1.0)


@numba.njit(cache=True, nogil=True, error_model="numpy")
def mark_inside(points: np.ndarray, todo: np.ndarray, lo: np.ndarray, hi: np.ndarray,
                coarse: np.ndarray, bound: float, centres: np.ndarray,
                tangent_columns: np.ndarray, offsets: np.ndarray, reach2: np.ndarray,
                t: np.ndarray, p0: np.ndarray, p1: np.ndarray, p2: np.ndarray, steps: int,
                scaling: np.ndarray, inside_r2: float, outside_r2: float,
                start: np.ndarray, profile: np.ndarray, inside: np.ndarray) -> None:
    """Sets inside[q] for each of points (N, 3) where todo (N,) that the primitive holds.
    Only points inside the box lo..hi (3,), within `bound` of a coarse axis sample
    (coarse (C, 3)) are looked at; their profile planes are found at each sign change of
    h between the axis samples t (T,) (centres (T, 3), tangent_columns (3, T), offsets
    (T,) = s.T) within reach (reach2 (T - 1,), squared, from the first sample), refined
    on the exact axis (Bezier segments p0, p1, p2 (m, 3)).

    A root where the point's squared radius in the plane over f(t)^2 (scaling (k,): f's
    coefficients) is at most inside_r2 holds it inside the profile whatever its angle;
    one where it is over outside_r2 cannot hold it; the others are settled by the
    profile test (_profile_level_at; profile (3,) = a, b, d; start (m, 13) as
    _frame_at's)."""
    n_points, n_t, n_coarse = points.shape[0], t.shape[0], coarse.shape[0]
    bound2 = bound * bound
    tx, ty, tz = tangent_columns[0], tangent_columns[1], tangent_columns[2]
    h = np.empty(n_t)
    for q in range(n_points):
        if not todo[q]:
            continue
        x, y, z = points[q, 0], points[q, 1], points[q, 2]
        if x < lo[0] or x > hi[0] or y < lo[1] or y > hi[1] or z < lo[2] or z > hi[2]:
            continue
        near = False
        for c in range(n_coarse):
            dx, dy, dz = x - coarse[c, 0], y - coarse[c, 1], z - coarse[c, 2]
            if dx * dx + dy * dy + dz * dz <= bound2:
                near = True
                break
        if not near:
            continue
        for s in range(n_t):  # one vectorised loop: cheaper than skipping far samples
            h[s] = x * tx[s] + y * ty[s] + z * tz[s] - offsets[s]
        for s in range(n_t - 1):
            if (h[s] >= 0.0) == (h[s + 1] >= 0.0):
                continue
            dx, dy, dz = x - centres[s, 0], y - centres[s, 1], z - centres[s, 2]
            if dx * dx + dy * dy + dz * dz > reach2[s]:
                continue
            root = _regula_falsi(x, y, z, p0, p1, p2, t[s], t[s + 1], h[s], h[s + 1], steps)
            r2 = _in_plane_radius2(x, y, z, p0, p1, p2, scaling, root)
            if r2 > outside_r2:
                continue
            if r2 <= inside_r2 or _profile_level_at(x, y, z, p0, p1, p2, start, scaling,
                                                    profile, root) <= 1.0:
                inside[q] = True
                break
