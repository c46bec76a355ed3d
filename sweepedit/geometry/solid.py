"""Meshes of the true solid of docs/primitive.md, for export and booleans.

The display mesher (mesher.py) sweeps one tube of rings. Where the profile reaches past
the axis' centre of curvature the rings cross and that tube turns inside-out locally:
still closed and consistently wound, but no longer the boundary of the union over t of
the profile regions. Here each primitive becomes a few pieces that each bound their part
of it, and their union (manifold3d) is the solid.

A profile point o (in the profile's (x, y) coordinates) moves along the axis at the rate
J(t, o) = 1 - o . q(t) relative to the axis itself, with q = f (κN . U, κN . V) (see
sweep.fold_vectors); the sweep folds where J < 0. The parameter domain
[0, 1] x profile is cut into three kinds of cells, each mapped to one kind of piece:

- forward, J >= FOLD_MARGIN: the profile clipped by that half-plane, found radially
  (each profile point pulled towards the centre onto the line), so the ring keeps its
  points and a star stays star-shaped; swept as an ordinary tube (for a primitive that
  nowhere folds, this is the display tube);
- backward, J <= -FOLD_MARGIN: the part of the profile beyond a line (on a star, each
  part holding the same tips), swept as a tube whose faces are reversed (the sweep is
  locally injective there, but turns the orientation over);
- the band in between, and what the tubes leave: per few segments between stations, the
  convex hull of its slices on their rings (on a star, per fan wedge). The band is thin,
  so these hulls stay close to it, and they are small and cheap to union.

A tube is cut where two of its cross-sections would meet (across a tight bend), as
manifold3d does not resolve a piece that overlaps itself. Stations are added where the
axis turns quickly, and profile points for sharp stars.
"""

from __future__ import annotations

from collections.abc import Sequence
from functools import lru_cache
from typing import TYPE_CHECKING, NamedTuple

import numpy as np

from sweepedit.geometry.mesher import (
    DISPLAY_PROFILE_POINTS,
    DISPLAY_STATIONS,
    TriangleMesh,
    _side_and_cap_faces,
    _vertex_normals,
)
from sweepedit.geometry.model import Abstraction, SweepPrimitive, primitive_fold_vectors
from sweepedit.geometry.sweep import (
    axis_frames,
    bezier_segments,
    scaling_factor,
    superellipse,
)
from sweepedit.geometry.volumes import superellipse_area

if TYPE_CHECKING:
    import manifold3d

# Largest turn of the tangent between two stations near a fold (radians), and anywhere:
# a hull or ruled strip between two rings misses the arc between them by about
# reach * turn^2 / 8.
MAX_TURN = 0.1
COARSE_TURN = 0.3
# Where the fold rate J drops below this, stations are MAX_TURN apart.
NEAR_FOLD = 0.25
# For a thin profile both steps shrink, so that the chord error reach * turn^2 / 8 stays
# below this share of the thickness.
THICKNESS_ERROR = 0.004
# A tube piece turns by less than this, so that it has no double normal (a chord normal
# to the axis at both ends), along which two of its cross-sections far apart could meet.
MAX_PIECE_TURN = 0.95 * np.pi
# |J| below this is left to the hulls: rings swept at a rate this far from 0 cannot
# cross their neighbours between stations (MAX_TURN keeps the error of the discrete
# rings well below it).
FOLD_MARGIN = 0.1
# One hull covers the band of up to BAND_CHUNK consecutive segments turning by at most
# BAND_TURN: the band is thin, so the hull of several of its slices stays close to their
# union, and every piece costs a boolean.
BAND_CHUNK = 4
BAND_TURN = 0.4
# The band's hulls reach this share further into the tubes on either side: pieces that
# only share faces or edges leave manifold3d to break ties, and a union of solids that
# touch along an edge alone is not a manifold (its exports merge into a pinched mesh).
OVERLAP = 0.02
# Copies of a vertex where the union's surface touches itself move this share of the
# mesh's size apart (see _separate_pinches): far above float32 rounding, far below sight.
PINCH_SEPARATION = 1e-5
# Samples per segment of the fold rate J (just inside both ends, and between).
_SUBSAMPLES = np.array([1e-7, 1.0 / 3.0, 2.0 / 3.0, 1.0 - 1e-7])
# The solid's profile polygon has at least the points asked for, and more for a sharp
# star, until its area is this close to the superellipse's (relative).
PROFILE_AREA_TOLERANCE = 0.005
MAX_PROFILE_POINTS = 256
# Angles sampled to find where a line cuts the superellipse.
_DENSE_ANGLES = 2048


class _Rings(NamedTuple):
    """A primitive sampled at its stations: t (S,), centres, U, V, T (S, 3), scale f
    (S,), profile points xy (P, 2), the fold vectors q of each segment's samples
    (S - 1, len(_SUBSAMPLES), 2) and the Bezier segment each segment lies in (S - 1,)."""

    t: np.ndarray
    centres: np.ndarray
    U: np.ndarray
    V: np.ndarray
    T: np.ndarray
    f: np.ndarray
    xy: np.ndarray
    q: np.ndarray
    bezier: np.ndarray

    def world(self, i: np.ndarray | int, xy: np.ndarray) -> np.ndarray:
        """Profile coordinates xy (..., 2) at station(s) i (broadcast) -> points (..., 3)."""
        f = np.asarray(self.f[i])[..., None]
        return self.centres[i] + f * (xy[..., :1] * self.U[i] + xy[..., 1:] * self.V[i])


def solid_stations(primitive: SweepPrimitive, stations: int = DISPLAY_STATIONS) -> np.ndarray:
    """Station parameters for a primitive's solid -> t (S,), increasing.

    `stations` uniform values of t, the joints between Bezier segments and their points of
    greatest curvature (_bezier_peaks), and where the tangent has turned by COARSE_TURN
    since the last station, or by MAX_TURN near a fold (J < NEAR_FOLD), where hulls and
    the margin of the fold rate need the finer steps (both smaller for thin profiles).
    """
    cps, n = primitive.control_points, primitive.n_control_points
    # A chord between two rings cuts the arc a reach r sweeps by r turn^2 / 8; it must
    # stay small beside the profile's thickness, so a thin profile needs finer steps. The
    # thickness over the reach is taken as the profile's area over that of the circle of
    # its reach: b / a for an ellipse, much less for a sharp star's spikes.
    reach = max(primitive.a, primitive.b)
    thickness = (superellipse_area(1.0, 1.0, primitive.degree) * primitive.a * primitive.b
                 / (np.pi * reach))
    thin = float(np.sqrt(8.0 * THICKNESS_ERROR * thickness / reach))
    fine = _turning_stations(cps, min(MAX_TURN, thin))
    xy = np.stack(superellipse(np.linspace(0.0, 2.0 * np.pi, 64, endpoint=False),
                               primitive.profile[None]), axis=-1)[0]
    t = np.concatenate([np.linspace(0.0, 1.0, max(stations, 2)), np.arange(1, n - 2) / (n - 2),
                        _bezier_peaks(cps), _turning_stations(cps, min(COARSE_TURN, 3.0 * thin)),
                        fine[_fold_rate(primitive, fine, xy) < NEAR_FOLD]])
    t = np.unique(t)
    return t[np.concatenate([[True], np.diff(t) > 1e-6])]


def _turning_stations(control_points: np.ndarray, max_turn: float) -> np.ndarray:
    """t where each Bezier segment's tangent has turned by a multiple of its total turn /
    ceil(total turn / max_turn), (K,). Within a segment the derivative D(u) = (1 - u) d0
    + u d1 turns monotonically in one plane, so the u at which it has turned by φ is
    closed form."""
    p0, p1, p2 = (x[0] for x in bezier_segments(np.asarray(control_points, np.float64)[None]))
    m = len(p0)
    out = [np.zeros(0)]
    for j in range(m):
        d0, d1 = p1[j] - p0[j], p2[j] - p1[j]
        n0 = float(np.linalg.norm(d0))
        if n0 < 1e-12 or np.linalg.norm(d1) < 1e-12:
            continue  # a degenerate leg: the tangent does not turn inside the segment
        e1 = d0 / n0
        alpha = float(d1 @ e1)
        beta = float(np.linalg.norm(d1 - alpha * e1))
        total = float(np.arctan2(beta, alpha))
        k = int(np.ceil(total / max_turn))
        if k < 2:
            continue
        phi = total * np.arange(1, k) / k
        u = n0 * np.sin(phi) / (beta * np.cos(phi) - (alpha - n0) * np.sin(phi))
        out.append((j + np.clip(u, 0.0, 1.0)) / m)
    return np.concatenate(out)


def _fold_rate(primitive: SweepPrimitive, t: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """The least fold rate J over profile points xy (P, 2) at each t (M,) -> (M,)."""
    return 1.0 - (primitive_fold_vectors(primitive, t) @ xy.T).max(axis=1)


def _bezier_peaks(control_points: np.ndarray) -> np.ndarray:
    """t of each Bezier segment's point of greatest curvature strictly inside it (the
    vertex of its parabola, where |D(u)| = |d0 + u (d1 - d0)| is least), (<= n - 2,)."""
    p0, p1, p2 = (x[0] for x in bezier_segments(np.asarray(control_points, np.float64)[None]))
    d0, dd = p1 - p0, (p2 - p1) - (p1 - p0)
    denom = np.einsum("ij,ij->i", dd, dd)
    u = -np.einsum("ij,ij->i", d0, dd) / np.where(denom > 1e-18, denom, np.inf)
    inside = (u > 1e-6) & (u < 1.0 - 1e-6)
    return (np.flatnonzero(inside) + u[inside]) / len(p0)


@lru_cache(maxsize=64)
def profile_angles(degree: float, points: int) -> np.ndarray:
    """Parameters θ (points,) of the profile polygon, counter-clockwise from the tip on U.

    Placed with density |κ|^(1/3) per arc length (plus a little uniform density), which
    minimises the area between a polygon and a curve: for a sharp star (d near 0.3) this
    halves the area error of equally spaced θ. The density is that of the profile with
    a = b, the same in all four quadrants, so the four tips are kept.
    """
    if points % 4:
        raise ValueError("profile_points must be a multiple of 4 (keeps the profile's tips)")
    theta = np.linspace(0.0, 0.5 * np.pi, _DENSE_ANGLES + 1)
    curve = np.stack(superellipse(theta, np.array([[1.0, 1.0, degree]])), axis=-1)[0]
    step = np.diff(curve, axis=0)
    length = np.linalg.norm(step, axis=1)
    heading = np.unwrap(np.arctan2(step[:, 1], step[:, 0]))
    turn = np.abs(np.diff(heading))
    turn = 0.5 * (np.concatenate([[0.0], turn]) + np.concatenate([turn, [0.0]]))
    weight = length * (turn / np.maximum(length, 1e-300)) ** (1.0 / 3.0)
    weight = weight / weight.sum() + 0.05 * length / length.sum()
    cum = np.concatenate([[0.0], np.cumsum(weight)])
    quarter = np.interp(np.arange(points // 4) / (points // 4), cum / cum[-1], theta)
    half = np.concatenate([quarter, [0.5 * np.pi], np.pi - quarter[1:][::-1]])
    angles = np.concatenate([half, np.pi + half])
    angles.flags.writeable = False
    return angles


@lru_cache(maxsize=64)
def solid_profile_points(degree: float, requested: int = DISPLAY_PROFILE_POINTS) -> int:
    """Points around the solid's profile polygon: at least `requested`, more (up to
    MAX_PROFILE_POINTS) until the polygon's area is within PROFILE_AREA_TOLERANCE of the
    superellipse's; only sharp stars need more."""
    exact = superellipse_area(1.0, 1.0, degree)
    points = requested
    while points < MAX_PROFILE_POINTS:
        x, y = superellipse(profile_angles(degree, points), np.array([[1.0, 1.0, degree]]))
        area = 0.5 * abs(float(np.sum(x[0] * np.roll(y[0], -1) - np.roll(x[0], -1) * y[0])))
        if abs(area / exact - 1.0) <= PROFILE_AREA_TOLERANCE:
            break
        points = min(MAX_PROFILE_POINTS, 4 * int(np.ceil(points * 1.25 / 4)))
    return points


def _sample(primitive: SweepPrimitive, stations: int, profile_points: int) -> _Rings:
    cps = primitive.control_points[None]
    scaling = primitive.scaling_array
    t = solid_stations(primitive, stations)
    x, y = superellipse(profile_angles(primitive.degree, profile_points), primitive.profile[None])
    fr = axis_frames(cps, t)
    ts = (t[:-1, None] + np.diff(t)[:, None] * _SUBSAMPLES[None, :]).reshape(-1)
    q = primitive_fold_vectors(primitive, ts)
    m = primitive.n_control_points - 2
    bezier = np.minimum(np.floor(0.5 * (t[:-1] + t[1:]) * m), m - 1).astype(int)
    return _Rings(t, fr.points[0], fr.U[0], fr.V[0], fr.T[0], scaling_factor(scaling, t)[0],
                  np.stack([x[0], y[0]], axis=1), q.reshape(len(t) - 1, len(_SUBSAMPLES), 2),
                  bezier)


def _forward_clamp(r: _Rings) -> np.ndarray:
    """Radial factors (S, P) in (0, 1] that pull each profile point onto the line
    J = FOLD_MARGIN wherever it is beyond it at some sample of an adjacent segment."""
    reach = np.einsum("pc,smc->smp", r.xy, r.q)  # o . q, (S - 1, M, P)
    with np.errstate(divide="ignore"):
        lam = np.where(reach > 0.0, (1.0 - FOLD_MARGIN) / reach, np.inf).min(axis=1)
    lam = np.minimum(lam, 1.0)  # per segment, (S - 1, P)
    return np.minimum(np.vstack([lam, np.ones_like(lam[:1])]),
                      np.vstack([np.ones_like(lam[:1]), lam]))


def _crossed(rings: np.ndarray, centres: np.ndarray, T: np.ndarray,
             forward: bool) -> np.ndarray:
    """Which segments' rings (S, R, 3) are not strictly ordered along the axis (centres,
    tangents (S, 3)): for a forward sweep ring i + 1 lies ahead of ring i's plane and
    ring i behind ring i + 1's; a backward sweep the other way round. -> bool (S - 1,)."""
    ahead = np.einsum("srk,sk->sr", rings[1:] - centres[:-1, None], T[:-1])
    behind = np.einsum("srk,sk->sr", rings[:-1] - centres[1:, None], T[1:])
    if forward:
        return (ahead.min(axis=1) <= 0.0) | (behind.max(axis=1) >= 0.0)
    return (ahead.max(axis=1) >= 0.0) | (behind.min(axis=1) <= 0.0)


def _runs(ok: np.ndarray, T: np.ndarray, meet: np.ndarray | None = None
          ) -> list[tuple[int, int]]:
    """Station ranges [i0, i1] of maximal runs of segments with ok (S - 1,) set, also cut
    before a station whose cross-section meets an earlier one of the run (meet (S, S)
    bool, see _meeting_sections) and where the tangent (S, 3) would have turned by
    MAX_PIECE_TURN since the run began."""
    steps = np.arccos(np.clip(np.einsum("ij,ij->i", T[:-1], T[1:]), -1.0, 1.0))
    runs = []
    start, turned = None, 0.0
    for i, good in enumerate(ok):
        if start is not None and (not good or turned + steps[i] > MAX_PIECE_TURN
                                  or (meet is not None and meet[start:i, i + 1].any())):
            runs.append((start, i))
            start = None
        if good and start is None:
            start, turned = i, 0.0
        if start is not None:
            turned += steps[i]
    if start is not None:
        runs.append((start, len(ok)))
    return runs


def _meeting_sections(rings: np.ndarray, centres: np.ndarray, T: np.ndarray) -> np.ndarray:
    """Which cross-sections two or more stations apart meet: rings (S, R, 3) planar
    polygons in the planes through centres (S, 3) normal to T (S, 3) -> bool (S, S).

    Two polygons meet when their chords on the line where their planes cross overlap
    (each polygon taken as its hull, so the answer errs on the side of meeting). A tube
    over a run of stations whose sections never meet does not overlap itself.
    """
    S, R = rings.shape[:2]
    meet = np.zeros((S, S), dtype=bool)
    # h[i, p, j]: how far point p of section i lies ahead of plane j; both sections must
    # straddle the other's plane (one matrix product for all pairs).
    h = (rings.reshape(-1, 3) @ T.T).reshape(S, R, S) - np.einsum("jc,jc->j", centres, T)
    straddles = (h.min(axis=1) < 0.0) & (h.max(axis=1) > 0.0)  # (S, S): section i, plane j
    i, j = np.nonzero(np.triu(straddles & straddles.T, 2))
    line = np.cross(T[i], T[j])
    length = np.linalg.norm(line, axis=1)
    keep = length > 1e-9  # parallel planes that both sections straddle: cannot happen
    i, j, line = i[keep], j[keep], line[keep] / length[keep, None]
    if len(i) == 0:
        return meet

    def chord(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        # the extent along the line of where section a's edges cross plane b
        ha = h[a, :, b]  # (K, R)
        ha1 = np.roll(ha, -1, axis=1)
        crossing = (ha >= 0.0) != (ha1 >= 0.0)
        w = np.where(crossing, ha / np.where(crossing, ha - ha1, 1.0), 0.0)
        s0 = np.einsum("kpc,kc->kp", rings[a], line)
        along = s0 + (np.roll(s0, -1, axis=1) - s0) * w
        return (np.where(crossing, along, np.inf).min(axis=1),
                np.where(crossing, along, -np.inf).max(axis=1))

    lo_i, hi_i = chord(i, j)
    lo_j, hi_j = chord(j, i)
    hit = np.maximum(lo_i, lo_j) <= np.minimum(hi_i, hi_j)
    meet[i[hit], j[hit]] = True
    return meet | meet.T


def _chunks(mask: np.ndarray, T: np.ndarray) -> list[np.ndarray]:
    """Consecutive segments with mask (S - 1,) set, in groups of at most BAND_CHUNK that
    turn by at most BAND_TURN (tangents T (S, 3)); one hull covers a group's band."""
    steps = np.arccos(np.clip(np.einsum("ij,ij->i", T[:-1], T[1:]), -1.0, 1.0))
    chunks: list[list[int]] = []
    turned = 0.0
    for s in np.flatnonzero(mask):
        if (chunks and chunks[-1][-1] == s - 1 and len(chunks[-1]) < BAND_CHUNK
                and turned + steps[s] <= BAND_TURN):
            chunks[-1].append(int(s))
            turned += steps[s]
        else:
            chunks.append([int(s)])
            turned = steps[s]
    return [np.asarray(c) for c in chunks]


def _tube(rings: np.ndarray, centres: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A closed tube of rings (R, P, 3) with fan caps about the end centres (2, 3)
    -> vertices (R P + 2, 3), faces (F, 3) (the layout of mesher.sweep_meshes_batch)."""
    R, P = rings.shape[:2]
    return np.concatenate([rings.reshape(-1, 3), centres]), _side_and_cap_faces(R, P, False)


def _reversed_tube(rings: np.ndarray, caps: tuple[np.ndarray, np.ndarray]
                   ) -> tuple[np.ndarray, np.ndarray]:
    """A closed tube of rings (R, Q, 3) whose sweep turns the orientation over, with caps
    (K, 3) triangulating the first and last ring (counter-clockwise in the profile).
    -> vertices (R Q, 3), faces (F, 3)."""
    R, Q = rings.shape[:2]
    side = _side_and_cap_faces(R, Q, False)[: 2 * (R - 1) * Q]
    faces = np.concatenate([side, caps[0][:, ::-1], caps[1] + (R - 1) * Q])
    return rings.reshape(-1, 3), faces[:, ::-1].copy()


def _cap_components(w_dense: np.ndarray, cut: float, tips: bool
                    ) -> dict[tuple[int, ...], tuple[float, float]]:
    """The parts of the profile boundary beyond the line w = cut.

    w_dense (N,): w at N equally spaced profile angles -> {key: (lo, hi)}, each part's
    two crossings as fractional angle indices lo < hi (hi may pass N). On a convex profile
    there is one part (key ()); on a star (tips) a part holds one or more of the four
    tips, the only local maxima of w there, and is keyed by them.
    """
    n = len(w_dense)
    beyond = w_dense >= cut
    if beyond.all() or not beyond.any():
        return {}
    start = int(np.argmin(beyond))  # an angle short of the line: no part wraps past it
    w = np.roll(w_dense, -start)
    b = np.roll(beyond, -start)
    rises = np.flatnonzero(~b[:-1] & b[1:]) + 1  # first index of each part
    falls = np.flatnonzero(b & ~np.roll(b, -1))  # last index of each part
    out = {}
    for first, last in zip(rises, falls, strict=True):
        after = (last + 1) % n
        lo = first - (w[first] - cut) / (w[first] - w[first - 1])
        hi = last + (w[last] - cut) / (w[last] - w[after])
        key = tuple(k for k in range(4) if first <= (k * n // 4 - start) % n <= last) if tips \
            else ()
        out[key] = (lo + start, hi + start)
    return out


def _polygon_index(theta: np.ndarray, angles: np.ndarray) -> np.ndarray:
    """Fractional index into the profile polygon (angles (P,)) of parameters θ (any real)."""
    turns = np.floor(theta / (2.0 * np.pi))
    ext = np.append(angles, 2.0 * np.pi)
    return turns * len(angles) + np.interp(theta - 2.0 * np.pi * turns, ext, np.arange(len(ext)))


def _polygon_angle(index: np.ndarray, angles: np.ndarray) -> np.ndarray:
    """The inverse of _polygon_index."""
    P = len(angles)
    turns = np.floor(index / P)
    ext = np.append(angles, 2.0 * np.pi)
    return 2.0 * np.pi * turns + np.interp(index - P * turns, np.arange(P + 1), ext)


class _Backward(NamedTuple):
    """The reversed tubes of a primitive and what they leave to the band: mu (S - 1, 2, P)
    pulls each profile point in onto the line w = cut (S - 1, 2) at both ends of a
    segment where a reversed tube covers its ray (1 elsewhere); w runs along direction
    (S - 1, 2)."""

    tubes: list[tuple[np.ndarray, np.ndarray]]
    mu: np.ndarray
    cut: np.ndarray
    direction: np.ndarray


def _backward_tubes(primitive: SweepPrimitive, r: _Rings, angles: np.ndarray) -> _Backward:
    """Reversed tubes over the cells J <= -FOLD_MARGIN.

    A cell stays within one Bezier segment: the axis is planar there, so the frames do
    not turn about it and the fold direction q / |q| is fixed in the profile's frame; the
    cell at a station is then the part of the profile beyond a line w = o . q / |q| = cut,
    far enough out for J <= -FOLD_MARGIN on both adjacent segments. Its boundary (an arc
    from crossing to crossing, closed by the chord) keeps its points from station to
    station; on a star, one tube per part beyond the line that holds the same tips.
    """
    S, P = len(r.t), len(angles)
    out = _Backward([], np.ones((S - 1, 2, P)), np.full((S - 1, 2), np.inf), np.zeros((S - 1, 2)))
    star = primitive.degree < 1.0
    theta = np.linspace(0.0, 2.0 * np.pi, _DENSE_ANGLES, endpoint=False)
    dense = np.stack(superellipse(theta, primitive.profile[None]), axis=-1)[0]  # (N, 2)
    for b in range(primitive.n_control_points - 2):
        segs = np.flatnonzero(r.bezier == b)
        qb = r.q[segs]  # (n, M, 2)
        norms = np.linalg.norm(qb, axis=2)
        if len(segs) == 0 or norms.max() < 1e-12:
            continue
        k_hat = qb.reshape(-1, 2)[int(np.argmax(norms))] / norms.max()
        w_dense, w_poly = dense @ k_hat, r.xy @ k_hat
        with np.errstate(divide="ignore"):
            cut_seg = np.full(S - 1, np.inf)
            along = qb @ k_hat  # (n, M)
            cut_seg[segs] = np.where(along > 0.0, (1.0 + FOLD_MARGIN) / along, np.inf).max(1)
        # a cap thinner than 5 % of the profile's reach is left to the band hulls
        for i0, i1 in _runs(cut_seg < 0.95 * w_dense.max(), r.T):
            idx = np.arange(i0, i1 + 1)
            cuts = np.maximum(cut_seg[np.maximum(idx - 1, i0)], cut_seg[np.minimum(idx, i1 - 1)])
            parts = [_cap_components(w_dense, c, star) for c in cuts]
            for key in {k for p in parts for k in p}:
                have = np.array([key in p for p in parts])
                for j0, j1 in _runs(have[:-1] & have[1:], r.T[idx]):
                    _add_backward(out, r, angles, w_poly, k_hat, primitive.profile,
                                  idx[j0:j1 + 1], cuts[j0:j1 + 1],
                                  np.array([parts[j][key] for j in range(j0, j1 + 1)]))
    return out


def _add_backward(out: _Backward, r: _Rings, angles: np.ndarray, w_poly: np.ndarray,
                  k_hat: np.ndarray, profile: np.ndarray, idx: np.ndarray, cuts: np.ndarray,
                  crossings: np.ndarray) -> None:
    """Sweep one part beyond the line over stations idx (R,) with cuts (R,) and crossing
    indices crossings (R, 2) into reversed tubes, cut where its rings cross or its
    sections meet; note what they cover in out."""
    step = 2.0 * np.pi / _DENSE_ANGLES
    span = _polygon_index(crossings * step, angles)  # (R, 2)
    count = max(4, int(np.ceil((span[:, 1] - span[:, 0]).max())) + 2)
    theta = _polygon_angle(span[:, :1] + (span[:, 1:] - span[:, :1])
                           * np.linspace(0.0, 1.0, count)[None, :], angles)  # (R, count)
    x, y = superellipse(theta.reshape(-1), profile[None])
    arcs = np.stack([x[0], y[0]], axis=1).reshape(len(idx), count, 2)
    rings = r.world(idx[:, None], arcs)
    crossed = _crossed(rings, r.centres[idx], r.T[idx], forward=False)
    meet = _meeting_sections(rings, r.centres[idx], r.T[idx])
    ray = np.mod(angles[None, :] - crossings[:, :1] * step, 2.0 * np.pi) \
        <= (crossings[:, 1:] - crossings[:, :1]) * step  # (R, P): rays through the part
    with np.errstate(divide="ignore", invalid="ignore"):
        mu = np.where(ray, np.minimum(1.0, cuts[:, None] / w_poly[None, :]), 1.0)
    import manifold3d as m3d

    for j0, j1 in _runs(~crossed, r.T[idx], meet):
        caps = tuple(np.asarray(m3d.triangulate([arcs[j]]), dtype=np.int64) for j in (j0, j1))
        out.tubes.append(_reversed_tube(rings[j0:j1 + 1], caps))
        seg = idx[j0:j1]
        out.mu[seg, 0] = np.minimum(out.mu[seg, 0], mu[j0:j1])
        out.mu[seg, 1] = np.minimum(out.mu[seg, 1], mu[j0 + 1:j1 + 1])
        out.cut[seg] = np.stack([cuts[j0:j1], cuts[j0 + 1:j1 + 1]], axis=1)
        out.direction[seg] = k_hat


def solid_pieces(primitive: SweepPrimitive, stations: int = DISPLAY_STATIONS,
                 profile_points: int = DISPLAY_PROFILE_POINTS
                 ) -> tuple[list[tuple[np.ndarray, np.ndarray]], list[np.ndarray]]:
    """One primitive cut into embedded pieces whose union is its solid.

    -> tubes, a list of closed outward meshes (vertices (V, 3), faces (F, 3)), and hulls,
    a list of point sets (N, 3) each standing for its convex hull.
    """
    profile_points = solid_profile_points(primitive.degree, profile_points)
    r = _sample(primitive, stations, profile_points)
    S = len(r.t)
    lam = _forward_clamp(r)  # (S, P)
    stations_idx = np.arange(S)[:, None]
    front = r.world(stations_idx, lam[:, :, None] * r.xy[None])  # (S, P, 3)
    # Rings that still cross (not seen so far) are covered by hulls of the whole segment.
    crossed = _crossed(front, r.centres, r.T, forward=True)
    # Clamped sections can meet across a tight bend (either side of a parabola's vertex:
    # the normal lines cross short of both centres of curvature); full ones only where
    # the axis comes back, which MAX_PIECE_TURN keeps out of a piece.
    meet = _meeting_sections(front, r.centres, r.T) if (lam < 1.0).any() else None
    tubes = [_tube(front[i0:i1 + 1], r.centres[[i0, i1]]) for i0, i1 in _runs(~crossed, r.T, meet)]
    star = primitive.degree < 1.0
    clamped = lam < 1.0
    if not clamped.any():
        return tubes, []
    back = _backward_tubes(primitive, r, profile_angles(primitive.degree, profile_points))
    tubes += back.tubes
    full = r.world(stations_idx, np.broadcast_to(r.xy, (S, *r.xy.shape)))
    hulls: list[np.ndarray] = []
    for seg in np.flatnonzero(crossed):
        hulls += _whole_segment(full, r.centres, seg, star)
    band = ~crossed & (clamped[:-1].any(axis=1) | clamped[1:].any(axis=1))
    for chunk in _chunks(band, r.T):
        ends = [_band_end(r, front, clamped, back, s, e) for s in chunk for e in (0, 1)]
        if star:
            hulls += _star_band_hulls(ends)
        else:
            hulls.append(np.concatenate([b.points for b in ends]))
    return tubes, hulls


def _whole_segment(full: np.ndarray, centres: np.ndarray, s: int,
                   star: bool) -> list[np.ndarray]:
    """Hull point sets covering segment s whole: both rings (convex profile), or each fan
    wedge (centre, p_j, p_j+1) of both (star)."""
    if not star:
        return [np.concatenate([full[s], full[s + 1]])]
    P = full.shape[1]
    wedges = [np.concatenate([np.broadcast_to(centres[e], (P, 1, 3)), full[e][:, None],
                              np.roll(full[e], -1, axis=0)[:, None]], axis=1)
              for e in (s, s + 1)]
    return list(np.concatenate(wedges, axis=1))


class _BandEnd(NamedTuple):
    """The band of a segment at one of its ends: points (K, 3) whose hull covers it (a
    convex profile); for each fan wedge (a star) its points (P, 5, 3), whether it holds
    any band (P,), and whether its band lies between the two lines (P,), so that a run of
    such wedges is convex and one hull covers it."""

    points: np.ndarray
    wedges: np.ndarray
    hit: np.ndarray
    between: np.ndarray


def _band_end(r: _Rings, front: np.ndarray, clamped: np.ndarray, back: _Backward, s: int,
              end: int) -> _BandEnd:
    """The band of segment s at station s + end: what lies between the forward ring and
    the profile, short of the reversed tubes that cover the segment. A wedge's points are
    its edges' points on the forward ring and on the outer bound (the profile, or the
    line w = cut where a reversed tube takes over), and where the profile edge crosses
    that line (the corner the two would otherwise cut)."""
    e = s + end
    nxt = np.roll(np.arange(len(r.xy)), -1)
    # Reach a little into the tubes on both sides (see OVERLAP).
    inner = r.centres[e] + (1.0 - OVERLAP) * (front[e] - r.centres[e])
    mu = back.mu[s, end]
    outer = r.world(e, np.where(mu < 1.0, np.minimum(1.0, (1.0 + OVERLAP) * mu), 1.0)[:, None]
                    * r.xy)
    cut, direction = (1.0 + OVERLAP) * back.cut[s, end], back.direction[s]
    corner = outer.copy()
    if np.isfinite(cut):
        w = r.xy @ direction - cut
        j = np.flatnonzero((w >= 0.0) != (w[nxt] >= 0.0))
        along = w[j] / (w[j] - w[nxt][j])
        corner[j] = r.world(e, r.xy[j] + along[:, None] * (r.xy[nxt][j] - r.xy[j]))
    c = clamped[e]
    near = c | c[nxt] | np.roll(c, 1)
    points = np.concatenate([inner[c], outer[near], corner[near]])
    wedges = np.stack([inner, inner[nxt], outer, outer[nxt], corner], axis=1)
    covered = mu < 1.0
    return _BandEnd(points, wedges, c | c[nxt], c & c[nxt] & covered & covered[nxt])


def _star_band_hulls(ends: list[_BandEnd]) -> list[np.ndarray]:
    """Hull point sets covering a star's band over a chunk of segments (the _BandEnd of
    each of their ends): one per run of wedges whose band lies between the two lines
    at every end (their union is convex), one per other wedge holding band."""
    hit = np.any([b.hit for b in ends], axis=0)
    between = np.all([b.between | ~b.hit for b in ends], axis=0) & hit
    wedges = np.concatenate([np.where(b.hit[:, None, None], b.wedges, b.wedges[:, :1])
                             for b in ends], axis=1)  # (P, 5 E, 3)
    out = [wedges[j] for j in np.flatnonzero(hit & ~between)]
    P = len(hit)
    if between.all():  # cannot happen (the forward ring holds the centre); keep it safe
        return list(wedges)
    start = int(np.argmin(between))  # runs of `between` do not wrap past this wedge
    run: list[int] = []
    for j in [(start + k) % P for k in range(P + 1)]:
        if between[j] and len(run) < P:
            run.append(j)
        elif run:
            out.append(wedges[run].reshape(-1, 3))
            run = []
    return out


def _primitive_solid(primitive: SweepPrimitive, stations: int,
                     profile_points: int) -> manifold3d.Manifold | None:
    """One primitive's solid as a manifold3d.Manifold (None if it has no volume)."""
    import manifold3d as m3d

    tubes, hulls = solid_pieces(primitive, stations, profile_points)
    pieces = [m3d.Manifold(m3d.Mesh64(vert_properties=np.ascontiguousarray(v),
                                      tri_verts=np.ascontiguousarray(f, dtype=np.uint64)))
              for v, f in tubes]
    small = [h for h in (m3d.Manifold.hull_points(np.ascontiguousarray(p)) for p in hulls)
             if not h.is_empty()]
    # The band's hulls first, among themselves: they are small and overlap each other,
    # and unioned with the tubes one by one each would cost a boolean with a large mesh.
    if small:
        pieces.append(m3d.Manifold.batch_boolean(small, m3d.OpType.Add))
    pieces = [m for m in pieces if not m.is_empty()]
    if len(pieces) > 1:
        return m3d.Manifold.batch_boolean(pieces, m3d.OpType.Add)
    return pieces[0] if pieces else None


def solid_union(primitives: Sequence[SweepPrimitive], stations: int = DISPLAY_STATIONS,
                profile_points: int = DISPLAY_PROFILE_POINTS) -> TriangleMesh:
    """The union of the primitives' solids as one watertight, outward TriangleMesh.

    stations is the least number of rings along each axis (more are added in tight
    bends); profile_points the least number of points around each profile (more for
    sharp stars).
    """
    import manifold3d as m3d

    solids = [m for m in (_primitive_solid(p, stations, profile_points) for p in primitives)
              if m is not None]
    if not solids:
        return TriangleMesh(np.zeros((0, 3)), np.zeros((0, 3), np.int64), np.zeros((0, 3)))
    result = m3d.Manifold.batch_boolean(solids, m3d.OpType.Add).to_mesh64()
    vertices = np.asarray(result.vert_properties, dtype=np.float64)[:, :3]
    faces = np.asarray(result.tri_verts, dtype=np.int64)
    vertices, faces = _collapse_tiny_edges(vertices, faces)
    vertices = _separate_pinches(vertices, faces)
    return TriangleMesh(vertices, faces, _vertex_normals(vertices, faces))


def _collapse_tiny_edges(vertices: np.ndarray, faces: np.ndarray,
                         share: float = PINCH_SEPARATION / 10.0
                         ) -> tuple[np.ndarray, np.ndarray]:
    """Collapse edges shorter than `share` of the mesh's size (slivers where pieces cross
    at a grazing angle), which float32 formats and position-merging loaders would fold
    into degenerate faces; an edge whose collapse would leave an edge at its vertex with
    other than two faces is kept. vertices (V, 3), faces (F, 3) -> (V', 3), (F', 3)."""
    size = float(np.linalg.norm(vertices.max(axis=0) - vertices.min(axis=0)))
    edges = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]),
                    axis=1)
    short = np.unique(edges[np.linalg.norm(vertices[edges[:, 0]] - vertices[edges[:, 1]],
                                           axis=1) < share * size], axis=0)
    if len(short) == 0:
        return vertices, faces
    # Work on the faces that touch a short edge only (the loop below is per edge).
    near = np.flatnonzero(np.isin(faces, short).any(axis=1))
    sub = faces[near].copy()
    alive = np.ones(len(sub), dtype=bool)
    for a, b in short:
        around = np.flatnonzero(alive & ((sub == a) | (sub == b)).any(axis=1))
        merged = np.where(sub[around] == b, a, sub[around])
        flat = (merged[:, 0] == merged[:, 1]) | (merged[:, 1] == merged[:, 2]) \
            | (merged[:, 2] == merged[:, 0])
        kept = merged[~flat]
        ring = np.sort(np.concatenate([kept[:, [0, 1]], kept[:, [1, 2]], kept[:, [2, 0]]]),
                       axis=1)
        ring = ring[(ring == a).any(axis=1)]
        if len(ring) and np.all(np.unique(ring, axis=0, return_counts=True)[1] == 2):
            sub[around] = merged
            alive[around[flat]] = False
    faces = faces.copy()
    faces[near] = sub
    keep = np.ones(len(faces), dtype=bool)
    keep[near[~alive]] = False
    used, compact = np.unique(faces[keep], return_inverse=True)
    return vertices[used], compact.reshape(-1, 3)


def _separate_pinches(vertices: np.ndarray, faces: np.ndarray,
                      share: float = PINCH_SEPARATION) -> np.ndarray:
    """Move apart the copies of a point where the surface touches itself.

    Pieces that meet only at a point or along an edge leave the union pinched there, and
    manifold3d keeps it a manifold by giving each sheet its own copy of the vertices. A
    format without shared vertices (STL), or a loader that merges equal positions, would
    fuse them into a non-manifold edge; so each copy moves `share` of the mesh's size
    towards the middle of its own faces. vertices (V, 3), faces (F, 3) -> vertices (V, 3).
    """
    from scipy.spatial import cKDTree

    size = float(np.linalg.norm(vertices.max(axis=0) - vertices.min(axis=0)))
    pairs = cKDTree(vertices).query_pairs(1e-6 * size, output_type="ndarray")
    if len(pairs) == 0:
        return vertices
    moved = np.unique(pairs)
    touching = np.isin(faces, moved).any(axis=1)
    centre = np.zeros_like(vertices)
    count = np.zeros(len(vertices))
    middle = vertices[faces[touching]].mean(axis=1)  # (K, 3)
    for c in range(3):
        np.add.at(centre, faces[touching, c], middle)
        np.add.at(count, faces[touching, c], 1.0)
    towards = centre[moved] / count[moved, None] - vertices[moved]
    out = vertices.copy()
    out[moved] += share * size * towards / np.maximum(
        np.linalg.norm(towards, axis=1, keepdims=True), 1e-300)
    return out


def solid_mesh(primitive: SweepPrimitive, stations: int = DISPLAY_STATIONS,
               profile_points: int = DISPLAY_PROFILE_POINTS) -> TriangleMesh:
    """One primitive's solid as a watertight, outward TriangleMesh (see solid_union)."""
    return solid_union([primitive], stations, profile_points)


def abstraction_union(abstraction: Abstraction, stations: int = DISPLAY_STATIONS,
                      profile_points: int = DISPLAY_PROFILE_POINTS,
                      visible_only: bool = True) -> TriangleMesh:
    """The union of an abstraction's (visible) primitives as one watertight mesh."""
    prims = abstraction.visible() if visible_only else abstraction.primitives
    return solid_union(prims, stations, profile_points)
