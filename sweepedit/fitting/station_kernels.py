"""The analytic sweeper's station table (AnalyticSweeper._stations) and its gradient on
the CPU, as one compiled loop instead of some 300 autograd operations.

As torch operations the table -- the axis points and rotation-minimising frames at the
stations, the arc length, the affine maps of each bracket -- is a few hundred tiny
operations forward and as many backward, whose dispatch costs far more than their
arithmetic: 7 ms a step for 8 primitives of 3 control points, 16 ms of 8 (dino's warm
start), two thirds of a refinement step. Here the geometry at the stations comes from
geometry/inside_kernel.py's compiled functions (each segment's start frame, the axis
point and tangent, the frame turned from the segment's start), each held to sweep.py by
tests, so the math is still written once.

The gradient with respect to the control points is taken by central differences in
float64, all moved axes in one batch through the same loop. The step, 1e-10, lies below
the thresholds of sweep.py's degenerate branches (a tangent shorter than 1e-9 falls back
on the chord; an initial tangent within 1e-6 of the z axis takes the fixed W), so where
an axis sits exactly on such a branch (a warm start straight along z, two equal control
points) both moved copies stay on it, as autograd's derivative does; float64 roundoff
leaves a relative error of about 1e-6, far below what float32 fitting resolves. The
table is linear in the profile (copied) and the scaling (f(t) = 1 + sum s_i t^i), whose
gradients are exact. tests/test_sweepers.py holds the table and its gradient to the
torch path's.
"""

from __future__ import annotations

import math
from typing import Any

import numba
import numpy as np
import torch

from sweepedit.geometry.inside_kernel import _axis_at, _frame_at, segment_start_frames
from sweepedit.geometry.sweep import bezier_segments

# Columns of the geometric part that the kernel writes per bracket row: the affine map
# (24), the arc length at both stations (2), the total arc length (1), and at row i < S
# the axis's bend at station i (2: the curvature vector along U and V).
N_GEOMETRY = 29
BEND_COLUMNS = slice(27, 29)
# Where those land in the sweeper's 32-column table.
GEOMETRY_COLUMNS = np.array([*range(24), 26, 27, 31])  # (the first 27 of the kernel's)
# Central-difference step for the control points (normalised units; see above).
STEP = 1e-10
_EPS = 1e-9  # sweepers._EPS: keeps a zero-length segment's arc length finite


@numba.njit(cache=True, nogil=True, error_model="numpy", parallel=True)
def station_geometry(p0: np.ndarray, p1: np.ndarray, p2: np.ndarray, t: np.ndarray,
                     margin: float, geometry: np.ndarray, points: np.ndarray,
                     tangents: np.ndarray) -> None:
    """For each of E axes (Bezier segments p0, p1, p2 (E, m, 3)) at the stations t (S,):
    geometry (E, S + 1, N_GEOMETRY), per bracket [i, i + 1] of the stations extended by
    `margin` along the end tangents, the affine map that takes [q, 1] to (h, x, y) at
    both its stations, their arc lengths and the axis's total arc length, and the bend
    at station i (sweep.axis_curvature_vectors' kN . U, kN . V; 0 in the last row);
    points and tangents (E, S + 2, 3) of the extended stations."""
    n_axes, n_t = p0.shape[0], t.shape[0]
    m = p0.shape[1]
    for e in numba.prange(n_axes):  # the axes are independent: shared over the threads
        frames = np.empty((n_t + 2, 9))  # T, U, V at each extended station
        arc = np.empty(n_t + 2)
        start = np.empty((m, 13))
        segment_start_frames(p0[e], p1[e], p2[e], start)
        length = 0.0
        for s in range(n_t):
            px, py, pz, tx, ty, tz = _axis_at(p0[e], p1[e], p2[e], t[s])
            j = int(min(max(math.floor(min(max(t[s], 0.0), 1.0) * m), 0.0), m - 1.0))
            ux, uy, uz, vx, vy, vz = _frame_at(start, j, tx, ty, tz)
            points[e, s + 1, 0], points[e, s + 1, 1], points[e, s + 1, 2] = px, py, pz
            qu, qv = _bend_at(p0[e], p1[e], p2[e], j, t[s], ux, uy, uz, vx, vy, vz)
            geometry[e, s, 27], geometry[e, s, 28] = qu, qv
            frames[s + 1, 0], frames[s + 1, 1], frames[s + 1, 2] = tx, ty, tz
            frames[s + 1, 3], frames[s + 1, 4], frames[s + 1, 5] = ux, uy, uz
            frames[s + 1, 6], frames[s + 1, 7], frames[s + 1, 8] = vx, vy, vz
            if s:
                dx = px - points[e, s, 0]
                dy = py - points[e, s, 1]
                dz = pz - points[e, s, 2]
                length += math.sqrt(dx * dx + dy * dy + dz * dz + _EPS * _EPS)
            arc[s + 1] = length
        # The extensions beyond the ends, along the end tangents, keep the end frames.
        for c in range(9):
            frames[0, c] = frames[1, c]
            frames[n_t + 1, c] = frames[n_t, c]
        for c in range(3):
            points[e, 0, c] = points[e, 1, c] - margin * frames[1, c]
            points[e, n_t + 1, c] = points[e, n_t, c] + margin * frames[n_t, c]
        arc[0] = -margin
        arc[n_t + 1] = length + margin
        for s in range(n_t + 2):
            for c in range(3):
                tangents[e, s, c] = frames[s, c]
        for i in range(n_t + 1):
            for side in range(2):
                s = i + side
                for axis in range(3):  # h, x, y: along T, U, V
                    column = 3 * side + axis
                    offset = 0.0
                    for r in range(3):
                        value = frames[s, 3 * axis + r]
                        geometry[e, i, 6 * r + column] = value
                        offset += points[e, s, r] * value
                    geometry[e, i, 18 + column] = -offset
            geometry[e, i, 24] = arc[i]
            geometry[e, i, 25] = arc[i + 1]
            geometry[e, i, 26] = length
        geometry[e, n_t, 27] = geometry[e, n_t, 28] = 0.0


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _bend_at(p0: np.ndarray, p1: np.ndarray, p2: np.ndarray, j: int, t: float, ux: float,
             uy: float, uz: float, vx: float, vy: float, vz: float) -> tuple[float, float]:
    """The curvature vector kN = (s'' - (s''.T) T) / |s'|^2 of the axis at t in its
    segment j (sweep.axis_curvature_vectors), along U and along V."""
    m = p0.shape[0]
    u = min(max(t, 0.0), 1.0) * m - j
    a0x, a0y, a0z = p0[j, 0], p0[j, 1], p0[j, 2]
    a1x, a1y, a1z = p1[j, 0], p1[j, 1], p1[j, 2]
    a2x, a2y, a2z = p2[j, 0], p2[j, 1], p2[j, 2]
    d1x = 2.0 * m * ((1.0 - u) * (a1x - a0x) + u * (a2x - a1x))
    d1y = 2.0 * m * ((1.0 - u) * (a1y - a0y) + u * (a2y - a1y))
    d1z = 2.0 * m * ((1.0 - u) * (a1z - a0z) + u * (a2z - a1z))
    d2x = 2.0 * m * m * (a2x - 2.0 * a1x + a0x)
    d2y = 2.0 * m * m * (a2y - 2.0 * a1y + a0y)
    d2z = 2.0 * m * m * (a2z - 2.0 * a1z + a0z)
    speed2 = max(d1x * d1x + d1y * d1y + d1z * d1z, 1e-9)
    along = (d2x * d1x + d2y * d1y + d2z * d1z) / speed2
    kx = (d2x - d1x * along) / speed2
    ky = (d2y - d1y * along) / speed2
    kz = (d2z - d1z * along) / speed2
    return kx * ux + ky * uy + kz * uz, kx * vx + ky * vy + kz * vz


def _evaluate(control_points: np.ndarray, t: np.ndarray, margin: float
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """station_geometry of axes control_points (E, n, 3) float64 -> geometry
    (E, S + 1, N_GEOMETRY), points and tangents (E, S + 2, 3)."""
    n_axes, n_t = control_points.shape[0], t.shape[0]
    segments = [np.ascontiguousarray(p) for p in bezier_segments(control_points)]
    geometry = np.empty((n_axes, n_t + 1, N_GEOMETRY))
    points = np.empty((n_axes, n_t + 2, 3))
    tangents = np.empty((n_axes, n_t + 2, 3))
    station_geometry(*segments, t, margin, geometry, points, tangents)
    return geometry, points, tangents


def scaling_at(scaling: np.ndarray, t: np.ndarray) -> np.ndarray:
    """f at the extended stations: scaling (N, k), t (S,) -> (N, S + 2) (the extensions
    keep the end values), with the powers of t (S + 2, k) it is linear in."""
    t_ext = np.concatenate([[t[0]], t, [t[-1]]])
    powers = t_ext[:, None] ** np.arange(1, scaling.shape[1] + 1)[None, :]
    return 1.0 + scaling @ powers.T, powers


class FusedStations(torch.autograd.Function):
    """The table of AnalyticSweeper._stations (N, S + 1, 32) from control points
    (N, n, 3), profile (N, 3) and scaling (N, k) at the stations t (S,) with the
    extension `margin`, and the axes' bend at the stations (N, S, 2); also returns (not
    differentiable) the extended stations' points and tangents (N, S + 2, 3)."""

    @staticmethod
    def forward(ctx: Any, control_points: torch.Tensor, profile: torch.Tensor,
                scaling: torch.Tensor, t: np.ndarray, margin: float
                ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        cps = control_points.detach().to(torch.float64).numpy()
        n_prims, n_cps = cps.shape[0], cps.shape[1]
        n_vars = 3 * n_cps
        # Base, then each coordinate moved by +STEP and -STEP: (N, 1 + 2 n_vars, n, 3).
        moved = np.repeat(cps[:, None], 1 + 2 * n_vars, axis=1)
        flat = moved[:, 1:].reshape(n_prims, 2, n_vars, n_vars)
        idx = np.arange(n_vars)
        flat[:, 0, idx, idx] += STEP
        flat[:, 1, idx, idx] -= STEP
        moved[:, 1:] = flat.reshape(n_prims, 2 * n_vars, n_cps, 3)
        geometry, points, tangents = _evaluate(moved.reshape(-1, n_cps, 3), t, margin)
        geometry = geometry.reshape(n_prims, 1 + 2 * n_vars, *geometry.shape[1:])
        f, powers = scaling_at(scaling.detach().to(torch.float64).numpy(), t)
        table = np.empty((n_prims, t.shape[0] + 1, 32))
        table[..., GEOMETRY_COLUMNS] = geometry[:, 0, :, :27]
        table[..., 24], table[..., 25] = f[:, :-1], f[:, 1:]
        table[..., 28:31] = profile.detach().to(torch.float64).numpy()[:, None, :]
        # d(geometry)/d(coordinate): (N, n_vars, S + 1, N_GEOMETRY).
        precision = np.float64 if control_points.dtype == torch.float64 else np.float32
        ctx.jacobian = ((geometry[:, 1:1 + n_vars] - geometry[:, 1 + n_vars:])
                        / (2.0 * STEP)).astype(precision)
        ctx.powers = powers
        ctx.shapes = (control_points.shape, control_points.dtype)
        base = slice(None, None, 1 + 2 * n_vars)
        dtype = control_points.dtype
        bend = geometry[:, 0, :-1, BEND_COLUMNS]
        return (torch.from_numpy(table).to(dtype), torch.from_numpy(bend.copy()).to(dtype),
                torch.from_numpy(points[base]).to(dtype),
                torch.from_numpy(tangents[base]).to(dtype))

    @staticmethod
    def backward(ctx: Any, grad_table: torch.Tensor, grad_bend: torch.Tensor,
                 *_: Any) -> tuple[Any, ...]:
        grad = grad_table.detach().numpy().astype(ctx.jacobian.dtype, copy=False)
        shape, dtype = ctx.shapes
        grad_geometry = np.zeros(ctx.jacobian.shape[:1] + ctx.jacobian.shape[2:],
                                 dtype=ctx.jacobian.dtype)  # (N, S + 1, N_GEOMETRY)
        grad_geometry[..., :27] = grad[..., GEOMETRY_COLUMNS]
        grad_geometry[:, :-1, BEND_COLUMNS] = grad_bend.detach().numpy()
        grad_cps = np.einsum("nvsc,nsc->nv", ctx.jacobian, grad_geometry)
        grad_profile = grad[..., 28:31].sum(axis=1)
        powers = ctx.powers  # (S + 2, k)
        grad_scaling = grad[..., 24] @ powers[:-1] + grad[..., 25] @ powers[1:]
        return (torch.from_numpy(grad_cps.reshape(shape)).to(dtype),
                torch.from_numpy(grad_profile).to(dtype),
                torch.from_numpy(np.asarray(grad_scaling)).to(dtype),
                None, None)
