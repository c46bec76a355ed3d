"""The analytic sweeper's bracket search, and its per-bracket soft occupancy with the
gradient, as fused CPU loops.

As torch ops, a bracket's occupancy is about forty operations over all the brackets, and
its backward twice as many; on the CPU each costs ~10 µs of dispatch and allocation for
the ~14k brackets of a refinement step, several times the arithmetic, and the search
built a primitives x queries x stations table. These loops do the same arithmetic once
per bracket and per query (numba; compiled on first use and cached on disk).
The formula is AnalyticSweeper's (sweepers.py), which keeps the torch version for other
devices; tests/test_sweepers.py holds the two to each other and to finite differences.

Table rows (M, 32), as AnalyticSweeper._stations builds them: an affine map A (4, 6),
row-major, that takes [q, 1] to (h0, x0, y0, h1, x1, y1), the query's plane offset and
in-plane coordinates at the bracket's two stations; then f0, f1 (scaling), e0, e1 (arc
length), a, b, d (profile) and the axis's total arc length.
"""

from __future__ import annotations

import math

import numba
import numpy as np

# Per-bracket values the forward pass keeps for the backward: |u/a|^d, |v/b|^d, the
# homogeneous radius r and the logs of |u/a|, |v/b| and the level (no transcendental
# function is evaluated twice).
N_SAVED = 6
# Brackets whose occupancy is provably below exp(-SATURATED) skip the transcendental work.
SATURATED = 40.0
# The runs the loops are cut into for the threads, whatever their number: the gradient's
# sums are then taken in the same order on every machine and under any load.
CHUNKS = 8


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _local(table: np.ndarray, m: int, qx: float, qy: float, qz: float, j: int) -> float:
    """Column j of [q, 1] @ A for table row m."""
    return qx * table[m, j] + qy * table[m, 6 + j] + qz * table[m, 12 + j] + table[m, 18 + j]


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _interpolated(table: np.ndarray, queries: np.ndarray, m: int, p: int
                  ) -> tuple[float, float, float, bool, float, float, float, float, float,
                             float, float, float, float, float]:
    """The bracket's root and what is interpolated there: lam (clamped), the raw lam, the
    denominator h0 - h1 (1e-12 where it vanishes, and whether it did), h0, xw, yw, dx,
    dy, the clamped and raw scaling f, its difference df, the arc length e and its
    difference de."""
    qx, qy, qz = queries[p, 0], queries[p, 1], queries[p, 2]
    h0 = _local(table, m, qx, qy, qz, 0)
    x0 = _local(table, m, qx, qy, qz, 1)
    y0 = _local(table, m, qx, qy, qz, 2)
    h1 = _local(table, m, qx, qy, qz, 3)
    x1 = _local(table, m, qx, qy, qz, 4)
    y1 = _local(table, m, qx, qy, qz, 5)
    denom = h0 - h1
    flat_bracket = abs(denom) < 1e-12
    if flat_bracket:
        denom = 1e-12
    lam_raw = h0 / denom
    lam = min(max(lam_raw, 0.0), 1.0)
    dx, dy = x1 - x0, y1 - y0
    df, de = table[m, 25] - table[m, 24], table[m, 27] - table[m, 26]
    f_raw = table[m, 24] + lam * df
    return (lam, lam_raw, denom, flat_bracket, h0, x0 + lam * dx, y0 + lam * dy, dx, dy,
            max(f_raw, 1e-4), f_raw, df, table[m, 26] + lam * de, de)


@numba.njit(cache=True, nogil=True, error_model="numpy", parallel=True)
def occupancy_forward(table: np.ndarray, queries: np.ndarray, flat: np.ndarray,
                      pair: np.ndarray, sharpness: float, occupancy: np.ndarray,
                      saved: np.ndarray) -> None:
    """occupancy (V,) of each bracket: table (M, 32), queries (NQ, 3), flat and pair (V,)
    the bracket's table row and query; saved (V, N_SAVED) is filled for the backward.
    The brackets are independent, so they are shared out over the threads."""
    for i in numba.prange(flat.shape[0]):
        _forward_one(table, queries, flat, pair, sharpness, occupancy, saved, i)


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _forward_one(table: np.ndarray, queries: np.ndarray, flat: np.ndarray,
                 pair: np.ndarray, sharpness: float, occupancy: np.ndarray,
                 saved: np.ndarray, i: int) -> None:
    """occupancy_forward of bracket i."""
    m = flat[i]
    _, _, _, _, _, xw, yw, _, _, f, _, _, e, _ = _interpolated(table, queries, m, pair[i])
    a, b, d, total = table[m, 28], table[m, 29], table[m, 30], table[m, 31]
    p_u, p_v = abs(xw / f / a), abs(yw / f / b)
    rho = math.sqrt(xw * xw + yw * yw + 1e-12)
    # Far outside (the profile's radius r >= max(p_u, p_v) for every d, so sd is at
    # least rho (1 - 1/max)) or beyond a cap: the occupancy and its gradient are below
    # e^-SATURATED; they are taken as 0 without the logs and powers.
    p_max = max(p_u, p_v)
    if (sharpness * min(e, total - e) < -SATURATED
            or (p_max > 1.0 and sharpness * rho * (1.0 - 1.0 / p_max) > SATURATED)):
        occupancy[i] = 0.0
        saved[i, 2] = -1.0  # marks the bracket for the backward
        return
    log_u = math.log(max(p_u, 1e-12))
    log_v = math.log(max(p_v, 1e-12))
    term_u, term_v = math.exp(d * log_u), math.exp(d * log_v)
    log_level = math.log(max(term_u + term_v, 1e-12))
    r = math.exp(log_level / d)
    sd = rho - rho / max(r, 1e-6)
    # The profile and both caps intersected: the least of their signed distances.
    z = min(-sd, min(e, total - e))
    occupancy[i] = 1.0 / (1.0 + math.exp(-sharpness * z))
    saved[i, 0], saved[i, 1], saved[i, 2] = term_u, term_v, r
    saved[i, 3], saved[i, 4], saved[i, 5] = log_u, log_v, log_level


@numba.njit(cache=True, nogil=True, error_model="numpy", parallel=True)
def occupancy_backward(table: np.ndarray, queries: np.ndarray, flat: np.ndarray,
                       pair: np.ndarray, sharpness: float, occupancy: np.ndarray,
                       saved: np.ndarray, grad: np.ndarray, grad_table: np.ndarray,
                       grad_queries: np.ndarray, want_queries: bool) -> None:
    """Add the gradient of sum(grad * occupancy) to grad_table (M, 32) and, if
    want_queries, to grad_queries (NQ, 3). The derivative of each clamp and of the
    minimum is that of the active branch, as torch's autograd takes it. The brackets are
    cut into CHUNKS runs whose sums the threads take apart, then added in order."""
    n = flat.shape[0]
    partial_table = np.zeros((CHUNKS, grad_table.shape[0], grad_table.shape[1]),
                             dtype=grad_table.dtype)
    partial_queries = np.zeros((CHUNKS, grad_queries.shape[0], grad_queries.shape[1]),
                               dtype=grad_queries.dtype)
    for c in numba.prange(CHUNKS):
        first, last = chunk_bounds(n, c)
        for i in range(first, last):
            _backward_one(table, queries, flat, pair, sharpness, occupancy, saved, grad,
                          partial_table[c], partial_queries[c], want_queries, i)
    for c in range(CHUNKS):
        grad_table += partial_table[c]
        if want_queries:
            grad_queries += partial_queries[c]


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _backward_one(table: np.ndarray, queries: np.ndarray, flat: np.ndarray,
                  pair: np.ndarray, sharpness: float, occupancy: np.ndarray,
                  saved: np.ndarray, grad: np.ndarray, grad_table: np.ndarray,
                  grad_queries: np.ndarray, want_queries: bool, i: int) -> None:
    """occupancy_backward of bracket i."""
    g = grad[i]
    if g == 0.0 or saved[i, 2] < 0.0:  # no gradient, or saturated
        return
    m, p = flat[i], pair[i]
    (lam, lam_raw, denom, flat_bracket, h0, xw, yw, dx, dy, f, f_raw, df, e,
     de) = _interpolated(table, queries, m, p)
    a, b, d, total = table[m, 28], table[m, 29], table[m, 30], table[m, 31]
    term_u, term_v, r = saved[i, 0], saved[i, 1], saved[i, 2]
    log_u, log_v, log_level = saved[i, 3], saved[i, 4], saved[i, 5]
    level_raw = term_u + term_v
    level = max(level_raw, 1e-12)
    rho = math.sqrt(xw * xw + yw * yw + 1e-12)
    r_c = max(r, 1e-6)
    sd = rho - rho / r_c
    o = occupancy[i]
    g_min = g * sharpness * o * (1.0 - o)
    g_sd = g_e = g_total = 0.0
    if -sd <= e and -sd <= total - e:
        g_sd = -g_min
    elif e <= total - e:
        g_e = g_min
    else:
        g_e, g_total = -g_min, g_min
    # sd = rho (1 - 1/r_c); r = level^(1/d); level = |u/a|^d + |v/b|^d.
    g_rho = g_sd * (1.0 - 1.0 / r_c)
    g_r = g_sd * rho / (r_c * r_c) if r >= 1e-6 else 0.0
    g_level = g_r * r / (d * level) if level_raw >= 1e-12 else 0.0
    g_d = -g_r * r * log_level / (d * d)
    u, v = xw / f, yw / f
    g_u = g_v = g_a = g_b = 0.0
    if abs(u / a) >= 1e-12:
        g_u = g_level * d * term_u / u
        g_a = -g_level * d * term_u / a
        g_d += g_level * term_u * log_u
    if abs(v / b) >= 1e-12:
        g_v = g_level * d * term_v / v
        g_b = -g_level * d * term_v / b
        g_d += g_level * term_v * log_v
    # u = xw / f, v = yw / f, rho = |(xw, yw)|; all interpolated linearly in lam.
    g_xw = g_u / f + g_rho * xw / rho
    g_yw = g_v / f + g_rho * yw / rho
    g_f = -(g_u * u + g_v * v) / f if f_raw >= 1e-4 else 0.0
    g_lam = 0.0
    if 0.0 <= lam_raw <= 1.0:
        g_lam = g_xw * dx + g_yw * dy + g_f * df + g_e * de
    g_h1 = 0.0 if flat_bracket else g_lam * h0 / (denom * denom)
    g_h0 = g_lam / denom - g_h1
    keep = 1.0 - lam
    g_loc = (g_h0, g_xw * keep, g_yw * keep, g_h1, g_xw * lam, g_yw * lam)
    qx, qy, qz = queries[p, 0], queries[p, 1], queries[p, 2]
    for j in range(6):
        grad_table[m, j] += qx * g_loc[j]
        grad_table[m, 6 + j] += qy * g_loc[j]
        grad_table[m, 12 + j] += qz * g_loc[j]
        grad_table[m, 18 + j] += g_loc[j]
    grad_table[m, 24] += g_f * keep
    grad_table[m, 25] += g_f * lam
    grad_table[m, 26] += g_e * keep
    grad_table[m, 27] += g_e * lam
    grad_table[m, 28] += g_a
    grad_table[m, 29] += g_b
    grad_table[m, 30] += g_d
    grad_table[m, 31] += g_total
    if want_queries:
        for c in range(3):
            total_c = 0.0
            for j in range(6):
                total_c += table[m, 6 * c + j] * g_loc[j]
            grad_queries[p, c] += total_c


@numba.njit(cache=True, nogil=True, error_model="numpy", parallel=True)
def find_brackets(queries: np.ndarray, points: np.ndarray, tangents: np.ndarray,
                  box_lo: np.ndarray, box_hi: np.ndarray, coarse: np.ndarray,
                  reach: np.ndarray, bracket_reach2: np.ndarray, rows: np.ndarray,
                  pairs: np.ndarray, brackets: np.ndarray, counts: np.ndarray) -> None:
    """AnalyticSweeper._brackets as one loop: for each primitive n and query j of
    queries (N, Q, 3) inside box_lo..box_hi (N, 3) and within reach (N,) of one of the
    coarse stations (N, C, 3), every bracket [i, i+1] of the stations points, tangents
    (N, S, 3) where h = (q - s_i).T_i changes sign (or touches 0) and the query lies
    within bracket_reach2 (N, S - 1) (squared) of one of its two stations: farther, its
    occupancy there is below sigmoid(-sweepers.CULL), as beyond the coarse stations' reach
    (a curved axis's planes pass through queries far from it: sixteen brackets a query for
    8 primitives of 8 control points, most of them far). The primitives are
    cut into CHUNKS runs (chunk_bounds), one a thread at a time: run c writes n,
    n * Q + j and i to row c of rows, pairs, brackets (CHUNKS, V) and how many it found
    to counts[c]; when more than V, only the first V are written and the caller asks
    again with room. Run after run, the brackets come in the order of n, j and i."""
    n_queries = queries.shape[1]
    n_stations, n_coarse = points.shape[1], coarse.shape[1]
    capacity = rows.shape[1]
    for c in numba.prange(CHUNKS):
        h = np.empty(n_stations, dtype=queries.dtype)
        count = 0
        first, last = chunk_bounds(queries.shape[0], c)
        for n in range(first, last):
            reach2 = reach[n] * reach[n]
            # The tangents' columns, contiguous: the loop over the stations vectorises.
            t_x = np.ascontiguousarray(tangents[n, :, 0])
            t_y = np.ascontiguousarray(tangents[n, :, 1])
            t_z = np.ascontiguousarray(tangents[n, :, 2])
            offsets = t_x * points[n, :, 0] + t_y * points[n, :, 1] + t_z * points[n, :, 2]
            for j in range(n_queries):
                x, y, z = queries[n, j, 0], queries[n, j, 1], queries[n, j, 2]
                if (x < box_lo[n, 0] or x > box_hi[n, 0] or y < box_lo[n, 1]
                        or y > box_hi[n, 1] or z < box_lo[n, 2] or z > box_hi[n, 2]):
                    continue
                near = False
                for k in range(n_coarse):
                    dx, dy, dz = (x - coarse[n, k, 0], y - coarse[n, k, 1],
                                  z - coarse[n, k, 2])
                    if dx * dx + dy * dy + dz * dz <= reach2:
                        near = True
                        break
                if not near:
                    continue
                for s in range(n_stations):
                    h[s] = x * t_x[s] + y * t_y[s] + z * t_z[s] - offsets[s]
                for s in range(n_stations - 1):
                    if h[s] * h[s + 1] <= 0.0:
                        d0x = x - points[n, s, 0]
                        d0y = y - points[n, s, 1]
                        d0z = z - points[n, s, 2]
                        d1x = x - points[n, s + 1, 0]
                        d1y = y - points[n, s + 1, 1]
                        d1z = z - points[n, s + 1, 2]
                        if min(d0x * d0x + d0y * d0y + d0z * d0z,
                               d1x * d1x + d1y * d1y + d1z * d1z) > bracket_reach2[n, s]:
                            continue
                        if count < capacity:
                            rows[c, count] = n
                            pairs[c, count] = n * n_queries + j
                            brackets[c, count] = s
                        count += 1
        counts[c] = count


@numba.njit(cache=True, nogil=True, error_model="numpy")
def chunk_bounds(n_items: int, chunk: int) -> tuple[int, int]:
    """The items [first, last) of run `chunk` of CHUNKS over n_items."""
    return chunk * n_items // CHUNKS, (chunk + 1) * n_items // CHUNKS
