"""Lofts through rings of boundary points, as B-spline patches, and whether a loft
through slices crosses itself.

A side surface (SideSurface) is four cubic x cubic B-spline patches that share their
direction along the sweep (t) and each span a quarter turn around it. STEP export writes
them as faces; a loft through slices (slices.py) is made by ring_loft.

A loft through slices by a family of planes that do not cross (slices.SlicingPlanes)
does not cross itself if (a) along every line of the surface across the slices, its
position across the planes ("height") keeps increasing, and (b) at every height, the
curve where the plane meets the surface is star-shaped about some point of that plane.
By (a) each plane meets the surface in one curve around it; by (b) that curve is simple;
so no two points of the surface coincide. Conversely, a level curve that crosses itself
shows the loft crosses itself. The end rings, each the outline of a flat cap in its own
plane (a cap's plane need not be a slice's, and no level lies on it), need only be
simple: one that crosses itself shows the loft does.
loft_verdict tests all this on dense samples of the surface (LOFT_SAMPLES per knot span
each way, LEVELS_PER_ROW heights per row of samples): a sliver finer than that would
pass, and OpenCascade's own check of the solid (crosses_itself in io/step/checks.py) is
asked for where neither is shown. On the 205 lofts STEP export judged for the folding
primitives of the official files and the K = 8 fits in benchmarks/fits/k8, this test
vouched for 113 of the 141 that OpenCascade passes and for none of the 64 it finds
crossing (53 of which it shows crossing), in 48 ms against 0.52 s (median;
benchmarks/bench_loft_check.py, BENCHMARKS.md, STEP export).
Before the end rings were tested it vouched for two lofts whose first ring makes a loop
0.08 rad wide (balloondog.json's 8th primitive, spot.json's 7th).
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum
from itertools import pairwise

import numba
import numpy as np
from scipy.interpolate import BSpline, make_interp_spline

from sweepedit.geometry.arrays import as_array
from sweepedit.geometry.slices import SlicingPlanes, quarter_turns

# Samples per knot span of a loft's patches, in each direction, and heights tested per
# row of samples (loft_is_embedded).
LOFT_SAMPLES = 8
LEVELS_PER_ROW = 4
# Points tried as a level curve's centre, per side of a grid, where the mean of its
# points and its area's centroid fail (a crescent's lie outside it).
CENTRE_GRID = 9
# Level curves that are not star-shaped about their middles looked at for a crossing.
CROSSING_TRIES = 8
# How far round from a full turn (radians) a star-shaped level curve may add up to.
TURN_TOLERANCE = 1e-6


@dataclass(frozen=True)
class SideSurface:
    """A primitive's side surface as four B-spline patches sharing the t direction:
    t_knots (Nt + 4,), for each quadrant (theta_knots (Nk + 4,), poles (Nt, Nk, 3))."""

    t_knots: np.ndarray
    patches: list[tuple[np.ndarray, np.ndarray]]


def ring_loft(rings: np.ndarray, t: np.ndarray, angles: np.ndarray) -> SideSurface:
    """Four B-spline patches interpolating rings (S, P, 3) at stations t (S,), split at
    the quarter turns of angles (P,) (slices.quarter_turns: a slice's rays along the
    frame's axes)."""
    P = rings.shape[1]
    patches = []
    t_knots = None
    for first, last in quarter_turns(angles):
        idx = np.arange(first, last + 1) % P
        theta = np.unwrap(angles[idx])
        across = make_interp_spline(theta, rings[:, idx, :], k=3, axis=1)
        poles = np.moveaxis(np.asarray(across.c), 0, 1)  # (S, Nk, 3)
        along = make_interp_spline(t, poles, k=3, axis=0)
        t_knots = np.asarray(along.t)
        patches.append((np.asarray(across.t), np.asarray(along.c)))
    assert t_knots is not None
    return SideSurface(t_knots, patches)


def _span_samples(knots: np.ndarray, per_span: int, last: bool) -> np.ndarray:
    """per_span parameters evenly in each span of a cubic's knots (..., and the end)."""
    inner = np.unique(knots[3:-3])
    spans = [np.linspace(a, b, per_span, endpoint=False) for a, b in pairwise(inner)]
    return np.concatenate([*spans, inner[-1:]] if last else spans)


def loft_samples(surface: SideSurface, per_span: int = LOFT_SAMPLES) -> np.ndarray:
    """Points of the surface (Mt, Mθ, 3): rows along t from end to end (the first and
    last rows are its end rings), columns once round (the patches one after the other,
    each without its last column: the next one's first)."""
    t = _span_samples(surface.t_knots, per_span, last=True)
    along = BSpline.design_matrix(t, surface.t_knots, 3).toarray()  # (Mt, Nt)
    columns = []
    for theta_knots, poles in surface.patches:
        theta = _span_samples(theta_knots, per_span, last=False)
        around = BSpline.design_matrix(theta, theta_knots, 3).toarray()  # (Mθ_k, Nk)
        columns.append(np.einsum("ui,ijc,vj->uvc", along, poles, around, optimize=True))
    return np.concatenate(columns, axis=1)


def _star_shaped_about(curves: np.ndarray, centres: np.ndarray) -> np.ndarray:
    """Whether each closed polygon of curves (L, M, 2) turns once round its centre
    (L, 1, 2), always the same way (-> (L,) bool): then it is star-shaped about it, and
    simple."""
    d = curves - centres
    angle = np.arctan2(d[..., 1], d[..., 0])
    step = np.diff(np.concatenate([angle, angle[:, :1]], axis=1), axis=1)
    step = (step + np.pi) % (2.0 * np.pi) - np.pi
    turn = step.sum(axis=1)
    return (((step > 0.0).all(axis=1) & (np.abs(turn - 2.0 * np.pi) < TURN_TOLERANCE))
            | ((step < 0.0).all(axis=1) & (np.abs(turn + 2.0 * np.pi) < TURN_TOLERANCE)))


def _area_centroids(curves: np.ndarray) -> np.ndarray:
    """The centroid of the area each closed polygon of curves (L, M, 2) encloses (L, 1, 2)."""
    x, y = curves[..., 0], curves[..., 1]
    xn, yn = np.roll(x, -1, axis=1), np.roll(y, -1, axis=1)
    cross = x * yn - xn * y
    area = cross.sum(axis=1, keepdims=True) / 2.0
    area = np.where(area == 0.0, 1e-300, area)
    sums = np.stack([((x + xn) * cross).sum(axis=1, keepdims=True),
                     ((y + yn) * cross).sum(axis=1, keepdims=True)], axis=-1)
    return sums / (6.0 * area[..., None])


def _grid_centres(curve: np.ndarray) -> np.ndarray:
    """CENTRE_GRID^2 points evenly within the middle of a polygon's (M, 2) bounding box
    -> (C, 1, 2)."""
    lo, hi = curve.min(axis=0), curve.max(axis=0)
    w = np.linspace(0.1, 0.9, CENTRE_GRID)
    return (lo + np.stack(np.meshgrid(w, w), axis=-1).reshape(-1, 1, 2) * (hi - lo))


def _star_shaped_about_middles(curves: np.ndarray) -> np.ndarray:
    """Whether each closed polygon of curves (L, M, 2) is star-shaped about the mean of
    its vertices or its area's centroid (-> (L,) bool)."""
    ok = _star_shaped_about(curves, curves.mean(axis=1, keepdims=True))
    if not ok.all():
        rest = curves[~ok]
        ok[~ok] = _star_shaped_about(rest, _area_centroids(rest))
    return ok


def _star_shaped_about_grid(curve: np.ndarray) -> bool:
    """Whether a closed polygon (M, 2) is star-shaped about one of _grid_centres."""
    centres = _grid_centres(curve)
    return bool(_star_shaped_about(np.broadcast_to(curve, (len(centres), *curve.shape)),
                                   centres).any())


def star_shaped(curves: np.ndarray) -> np.ndarray:
    """Whether each closed polygon of curves (L, M, 2) is star-shaped about the mean of
    its vertices, its area's centroid or, failing those, one of a grid of points in it
    (-> (L,) bool). Star-shaped implies simple (a point the polygon does not turn round
    once fails); a simple polygon star-shaped about none of them reads False."""
    ok = _star_shaped_about_middles(curves)
    for k in np.nonzero(~ok)[0]:
        ok[k] = _star_shaped_about_grid(curves[k])
    return ok


def polygon_crosses_itself(curve: np.ndarray) -> bool:
    """Whether two edges of a closed polygon (M, 2) that share no vertex cross (each
    strictly on both sides of the other's line)."""
    return bool(_edges_cross(as_array(curve, "M, 2", "a polygon", contiguous=True)))


@numba.njit(cache=True, nogil=True)
def _side(px: float, py: float, qx: float, qy: float, rx: float, ry: float) -> float:
    """Twice the signed area of the triangle p, q, r (> 0: r left of p -> q)."""
    return (qx - px) * (ry - py) - (qy - py) * (rx - px)


@numba.njit(cache=True, nogil=True)
def _edges_cross(curve: np.ndarray) -> bool:
    """polygon_crosses_itself's loop over the pairs of edges, stopping at the first
    crossing: as numpy arrays over all M^2 / 2 pairs it took 5 ms a polygon, a third of
    loft_verdict's time."""
    m = curve.shape[0]
    for i in range(m):
        ax, ay = curve[i, 0], curve[i, 1]
        bx, by = curve[(i + 1) % m, 0], curve[(i + 1) % m, 1]
        for j in range(i + 2, m - 1 if i == 0 else m):  # the last edge meets the first
            cx, cy = curve[j, 0], curve[j, 1]
            dx, dy = curve[(j + 1) % m, 0], curve[(j + 1) % m, 1]
            if (_side(ax, ay, bx, by, cx, cy) * _side(ax, ay, bx, by, dx, dy) < 0.0
                    and _side(cx, cy, dx, dy, ax, ay) * _side(cx, cy, dx, dy, bx, by) < 0.0):
                return True
    return False


def _in_own_plane(rings: np.ndarray) -> np.ndarray:
    """Planar rings (R, M, 3) -> (R, M, 2), each in 2D coordinates of its own plane
    (the two main directions of its points)."""
    centred = rings - rings.mean(axis=1, keepdims=True)
    _, _, directions = np.linalg.svd(centred, full_matrices=False)  # (R, 3, 3)
    return np.einsum("rmc,rkc->rmk", centred, directions[:, :2])


class LoftVerdict(Enum):
    """What loft_verdict finds of a loft through slices."""

    EMBEDDED = "embedded"  # it does not cross itself (as far as its samples show)
    CROSSES = "crosses"  # a plane meets it in a curve that crosses itself
    UNKNOWN = "unknown"  # neither shown: a check of the solid must tell


def _verdict_of_levels(curves: np.ndarray) -> LoftVerdict:
    """The verdict on closed level curves (L, M, 2): EMBEDDED where all are
    star-shaped, CROSSES where one of the first CROSSING_TRIES that are not (evenly
    among them) crosses itself, else UNKNOWN."""
    ok = _star_shaped_about_middles(curves)
    failing = np.nonzero(~ok)[0]
    if len(failing) == 0:
        return LoftVerdict.EMBEDDED
    tried = failing[np.unique(np.linspace(0, len(failing) - 1, CROSSING_TRIES).astype(int))]
    if any(polygon_crosses_itself(curves[k]) for k in tried):
        return LoftVerdict.CROSSES
    if all(_star_shaped_about_grid(curves[k]) for k in failing):
        return LoftVerdict.EMBEDDED
    return LoftVerdict.UNKNOWN


def _an_end_ring_crosses(rings: np.ndarray) -> bool:
    """Whether one of the planar end rings (2, M, 2) crosses itself: a cap needs only a
    simple outline (the levels above it are what must be star-shaped), so a ring that is
    star-shaped about its middle is simple, and any other is tested edge against edge."""
    simple = _star_shaped_about_middles(rings)
    return any(polygon_crosses_itself(rings[k]) for k in np.nonzero(~simple)[0])


def loft_verdict(surface: SideSurface, planes: SlicingPlanes, per_span: int = LOFT_SAMPLES,
                 levels_per_row: int = LEVELS_PER_ROW) -> LoftVerdict:
    """Whether the loft through slices by `planes` does not cross itself (EMBEDDED, by
    the test in the module's docstring on its samples), does (CROSSES: a plane meets it
    in a curve that crosses itself), or neither can be told so (UNKNOWN: its height may
    turn back, or a level curve be simple but star-shaped about none of the points
    tried)."""
    samples = loft_samples(surface, per_span)  # (Mt, Mθ, 3)
    local = planes.to_local(samples)
    height = local[..., 0]
    if not (np.diff(height, axis=0) > 0.0).all():
        return LoftVerdict.UNKNOWN
    # The end rings bound the flat caps, each in its own plane (a slice, or a cap of the
    # primitive's that the slices do not parallel); no level below tests them, and a
    # small loop of one is a cap that crosses itself (balloondog.json's 8th, K = 8).
    if _an_end_ring_crosses(_in_own_plane(samples[[0, -1]])):
        return LoftVerdict.CROSSES
    rows, columns = height.shape
    levels = np.linspace(height.min(), height.max(), levels_per_row * rows + 2)[1:-1]
    # Each column's point at each level (its height increases along it).
    across = np.empty((len(levels), columns, 2))
    for j in range(columns):
        for c in (0, 1):
            across[:, j, c] = np.interp(levels, height[:, j], local[:, j, 1 + c])
    below = levels[:, None] < height[0][None, :]  # the column starts above the level
    above = levels[:, None] > height[-1][None, :]  # ... or ends below it
    reached = ~(below | above)
    whole = reached.all(axis=1)
    verdict = _verdict_of_levels(across[whole])
    if verdict is not LoftVerdict.EMBEDDED:
        return verdict
    # Levels through a cap: the columns that reach them must run on from one to the
    # next round (the cap's chord closes the curve), through one cap only.
    for k in np.nonzero(~whole)[0]:
        if below[k].any() and above[k].any():
            return LoftVerdict.UNKNOWN
        count = int(reached[k].sum())
        if count < 3:
            continue
        starts = np.nonzero(reached[k] & ~np.roll(reached[k], 1))[0]
        if len(starts) != 1:
            return LoftVerdict.UNKNOWN
        run = (starts[0] + np.arange(count)) % columns
        verdict = _verdict_of_levels(across[k, run][None])
        if verdict is not LoftVerdict.EMBEDDED:
            return verdict
    return LoftVerdict.EMBEDDED
