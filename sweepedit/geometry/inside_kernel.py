"""The exact inside test's root search (inside.py) as one compiled loop per point.

For each point it does what inside.py's docstring says, up to the roots: the box and
tube filters, h(t) = (p - s(t)).T(t) at the axis samples, its sign changes where the
point is within reach of the sample, and REFINE_STEPS of regula falsi on the exact curve.
As numpy array operations over all points this took 1.7 ms a call whatever its size and
about 2 µs a point, and STEP export's slicer calls the test ~65 times per folding
primitive (BENCHMARKS.md, STEP export). numba; compiled on first use and cached on disk.

The axis point and unit tangent at t (_axis_at) are sweep.py's _points_and_tangents
written out for one point, and f(t) (_in_plane_radius2) its scaling_factor;
tests/test_geometry.py holds the first to sweep.py's h(t), and the inside test with and
without the radius shortcut to each other. The
frames at the roots and the profile test stay in sweep.py; a root is settled here only
by the point's radius in its plane, within the profile's inscribed circle or beyond its
circumscribed one (inside.profile_radii2).
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
def _in_plane_radius2(px: float, py: float, pz: float, p0: np.ndarray, p1: np.ndarray,
                      p2: np.ndarray, scaling: np.ndarray, t: float) -> float:
    """The squared distance of the point from the axis point s(t) within the profile
    plane at t, divided by f(t)^2 (inf where f(t) <= 0): x^2 + y^2 of the profile test,
    whatever the frame's turn about the tangent."""
    sx, sy, sz, tx, ty, tz = _axis_at(p0, p1, p2, t)
    rx, ry, rz = px - sx, py - sy, pz - sz
    h = rx * tx + ry * ty + rz * tz
    f = 1.0
    power = 1.0
    for i in range(scaling.shape[0]):
        power *= t
        f += scaling[i] * power
    if f <= 0.0:
        return math.inf
    return max(rx * rx + ry * ry + rz * rz - h * h, 0.0) / (f * f)


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
def profile_plane_roots(points: np.ndarray, todo: np.ndarray, lo: np.ndarray,
                        hi: np.ndarray, coarse: np.ndarray, bound: float,
                        centres: np.ndarray, tangent_columns: np.ndarray,
                        offsets: np.ndarray, reach2: np.ndarray, t: np.ndarray,
                        p0: np.ndarray, p1: np.ndarray, p2: np.ndarray, steps: int,
                        scaling: np.ndarray, inside_r2: float, outside_r2: float,
                        inside: np.ndarray, rows: np.ndarray, roots: np.ndarray) -> int:
    """Every t where a point's profile plane may hold it: points (N, 3) where todo (N,)
    is True, inside the box lo..hi (3,), within `bound` of a coarse axis sample
    (coarse (C, 3)), at each sign change of h between the axis samples t (T,)
    (centres (T, 3), tangent_columns (3, T), offsets (T,) = s.T) within reach (reach2
    (T - 1,), squared, from the first sample), refined on the exact axis (Bezier
    segments p0, p1, p2 (m, 3)).

    A root where the point's squared radius in the plane over f(t)^2 (scaling (k,): f's
    coefficients) is at most inside_r2 holds it inside the profile whatever its angle:
    inside[q] is set and its other roots dropped. One where it is over outside_r2 cannot
    hold it. The others are left to the profile test: the point's index and the root
    are written to rows, roots (capacity V), and how many there are is returned; beyond
    V only the count goes on, and the caller asks again with room."""
    n_points, n_t, n_coarse = points.shape[0], t.shape[0], coarse.shape[0]
    capacity = rows.shape[0]
    bound2 = bound * bound
    tx, ty, tz = tangent_columns[0], tangent_columns[1], tangent_columns[2]
    h = np.empty(n_t)
    count = 0
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
        first = count  # this point's roots start here
        for s in range(n_t - 1):
            if (h[s] >= 0.0) == (h[s + 1] >= 0.0):
                continue
            dx, dy, dz = x - centres[s, 0], y - centres[s, 1], z - centres[s, 2]
            if dx * dx + dy * dy + dz * dz > reach2[s]:
                continue
            root = _regula_falsi(x, y, z, p0, p1, p2, t[s], t[s + 1], h[s], h[s + 1], steps)
            r2 = _in_plane_radius2(x, y, z, p0, p1, p2, scaling, root)
            if r2 <= inside_r2:
                inside[q] = True
                count = first
                break
            if r2 > outside_r2:
                continue
            if count < capacity:
                rows[count] = q
                roots[count] = root
            count += 1
    return count
