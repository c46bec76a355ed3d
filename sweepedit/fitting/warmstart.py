"""Warm start from the medial axis: one primitive per skeleton branch.

Control points come from a least-squares fit of the axis B-spline to the branch; the
profile from the local radius (distance transform); the scaling from how that radius
changes along the branch. With fewer branches than primitives, the longest pieces are
split ("the rest shared out by branch length"); with more, the longest branches win.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from sweepedit.geometry.axis_edit import fit_control_points
from sweepedit.geometry.model import (
    A_RANGE,
    SCALING_RANGE,
    SweepPrimitive,
    palette_color,
    scaling_polynomial_min,
)
from sweepedit.geometry.sweep import axis_points

# Skeleton branches stop about one radius short of a tip; extend them by this share
# of the radius so the warm-started primitive reaches the shape's end.
TIP_EXTENSION = 0.8
MIN_PIECE_POINTS = 4
VOXEL = 1.5 / 64


def _arc_length(points: np.ndarray) -> np.ndarray:
    """Cumulative arc length (M,) of a polyline (M, 3), starting at 0."""
    return np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(points, axis=0), axis=1))])


def fit_axis(points: np.ndarray, n_control_points: int) -> np.ndarray:
    """Least-squares control points (n, 3) of a B-spline through a polyline (M, 3),
    parameterised by arc length, with its ends pinned to the polyline's ends."""
    s = _arc_length(points)
    t = s / s[-1] if s[-1] > 0 else np.linspace(0.0, 1.0, len(points))
    return fit_control_points(points, t, n_control_points)


def _radius_profile(radii: np.ndarray, t: np.ndarray, n_scaling: int) -> tuple[float, tuple]:
    """Half-axis and scaling coefficients (s1..sk) whose f(t) follows the radii.

    The half-axis is the median radius (a branch's end inside a junction sees the
    junction's larger radius, which must not inflate the whole primitive); the scaling
    follows the radius relative to it, within the scaling range.
    """
    base = float(np.clip(np.median(radii), *A_RANGE))
    scaling = np.zeros(n_scaling)
    degree = min(n_scaling, 2, len(t) - 1)
    if degree > 0:
        rel = np.clip(radii / base, 0.5, 1.5) - 1.0
        # f(t) - 1 has no constant term: fit s1 t + s2 t^2 to the relative radius.
        powers = np.stack([t ** (i + 1) for i in range(degree)], axis=1)
        coeffs, *_ = np.linalg.lstsq(powers, rel, rcond=None)
        scaling[:degree] = np.clip(coeffs, *SCALING_RANGE)
    # Halve the coefficients until f stays comfortably positive on [0, 1].
    while scaling_polynomial_min(scaling) < 0.2:
        scaling *= 0.5
    return base, tuple(float(v) for v in scaling)


def _extend_tips(points: np.ndarray, radii: np.ndarray, tips: tuple[bool, bool]) -> np.ndarray:
    """Lengthen a polyline (M, 3) past the ends that are tips by a share of the radius."""
    out = points.copy()
    if len(points) < 2:
        return out
    if tips[0]:
        d = points[0] - points[min(2, len(points) - 1)]
        out[0] = points[0] + TIP_EXTENSION * radii[0] * d / max(np.linalg.norm(d), 1e-9)
    if tips[1]:
        d = points[-1] - points[max(-3, -len(points))]
        out[-1] = points[-1] + TIP_EXTENSION * radii[-1] * d / max(np.linalg.norm(d), 1e-9)
    return out


def axis_fit_error(points: np.ndarray, n_control_points: int) -> float:
    """Largest distance from a polyline (M, 3) to the B-spline that fit_axis gives it."""
    curve = axis_points(fit_axis(points, n_control_points)[None], np.linspace(0, 1, 200))[0]
    d = np.linalg.norm(points[:, None, :] - curve[None, :, :], axis=-1)
    return float(d.min(axis=1).max())


def _split_tolerance(radii: np.ndarray) -> float:
    """How far (normalised units) one axis may stray from a branch of these radii (M,)
    before the branch is split: a quarter of its radius keeps the sweep inside the limb."""
    return 0.25 * float(np.median(radii)) + 0.5 * VOXEL


def _volume(piece: tuple[np.ndarray, np.ndarray]) -> float:
    """What a (points (M, 3), radii (M,)) piece carries: length times squared median
    radius, the radius floored at a voxel so that thin limbs count for their length."""
    return float(_arc_length(piece[0])[-1] * max(float(np.median(piece[1])), VOXEL) ** 2)


def _pieces(branches: Sequence, k: int,
            n_control_points: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """(points (M, 3), radii (M,)) pieces: the k branches that carry the most volume, the
    worst-fitting one split in two while one axis cannot follow it to within a quarter of
    its radius plus half a voxel (a straight handle stays one sweep) and there are fewer
    than k, or a piece of under a quarter of its volume can give up its primitive. Closed
    loops are cut in three first, since one quadratic axis cannot close on itself."""
    pieces: list[tuple[np.ndarray, np.ndarray]] = []
    for br in branches:
        pts, rad = np.asarray(br.points, float), np.asarray(br.radii, float)
        if len(pts) < 2:
            continue
        tips = (getattr(br, "start_kind", None) == "tip", getattr(br, "end_kind", None) == "tip")
        pts = _extend_tips(pts, rad, tips)
        if getattr(br, "is_loop", False) and len(pts) >= 3 * MIN_PIECE_POINTS:
            pieces += [(p, r) for p, r in zip(np.array_split(pts, 3), np.array_split(rad, 3),
                                              strict=True)]
        else:
            pieces.append((pts, rad))
    pieces = sorted(pieces, key=_volume, reverse=True)[:k]
    if not pieces:
        return pieces
    for _ in range(4 * k):  # each round splits a piece; the cap only guards the loop
        excess = [axis_fit_error(p, n_control_points) - _split_tolerance(r)
                  if len(p) >= 2 * MIN_PIECE_POINTS else -np.inf for p, r in pieces]
        worst = int(np.argmax(excess))
        if excess[worst] <= 0.0:
            break
        if len(pieces) >= k:
            # At k pieces, a small piece gives its primitive to the worst-followed one
            # when it carries under a quarter of that one's volume: a nub at a junction
            # (eight: 10 % of a loop) is worth less than the half of a loop that one
            # axis cannot follow.
            volumes = [_volume(pr) if i != worst else np.inf for i, pr in enumerate(pieces)]
            smallest = int(np.argmin(volumes))
            if volumes[smallest] >= 0.25 * _volume(pieces[worst]):
                break
            pieces.pop(smallest)
            worst -= smallest < worst
        pts, rad = pieces[worst]
        mid = len(pts) // 2
        # Overlap by one point so the halves meet.
        pieces[worst:worst + 1] = [(pts[:mid + 1], rad[:mid + 1]), (pts[mid:], rad[mid:])]
    return pieces


def warm_start_primitives(branches: Sequence, k: int, n_control_points: int = 3,
                          n_scaling: int = 2) -> list[SweepPrimitive]:
    """Up to k valid primitives from skeleton branches (objects with .points (M, 3) and
    .radii (M,); optional .start_kind / .end_kind ("tip" extends the end) and .is_loop)."""
    out: list[SweepPrimitive] = []
    for pts, rad in _pieces(branches, k, n_control_points):
        cps = fit_axis(pts, n_control_points)
        if np.linalg.norm(cps[-1] - cps[0]) < 1e-4:  # a piece that collapsed to a point
            continue
        s = _arc_length(pts)
        t = s / s[-1] if s[-1] > 0 else np.linspace(0, 1, len(pts))
        a, scaling = _radius_profile(rad, t, n_scaling)
        prim = SweepPrimitive(np.clip(cps, -0.5, 0.5), a=a, b=a, degree=2.0, scaling=scaling,
                              name=f"primitive {len(out) + 1}", color=palette_color(len(out)))
        out.append(prim)
    return out
