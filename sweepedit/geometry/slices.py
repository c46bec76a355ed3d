"""Slices of a primitive's exact solid by planes that do not cross, as rings of boundary
points.

A sweep that folds onto itself, or whose axis comes back onto itself, is the union of
its sections, and sections that cross cannot be lofted. Its solid can still be lofted
through slices by planes that do not cross inside it: if every plane meets the solid in
one region that is star-shaped about a centre, the boundary of each region is a ring
r(φ) around that centre, found on rays by bisection on the exact inside test, and a loft
through the rings is the solid.

Two families of planes are tried. First parallel planes (ParallelPlanes), across the
axis' chord, its principal directions, then a hemisphere of directions, since a bent
solid is single-region only across some. Then the half-planes about the line where the
planes of the two caps meet (PlanesThroughLine): they meet only on that line, so they do
not cross in a solid the line misses, and for a tube bent in an arc they are its
cross-sections.

A loft through slices that ends at the solid's extreme point rounds off the rims of
caps that the planes cut obliquely. So the solid is sliced together with a short
straight continuation past each cap (EndStub) where nothing else of it lies there, and
the rings are then moved onto the caps' planes (rings_on_caps): flat caps, sharp rims.
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Sequence
from typing import Any, NamedTuple

import numba
import numpy as np
from scipy import ndimage
from scipy.interpolate import make_interp_spline

from sweepedit.geometry.axis_edit import axis_length
from sweepedit.geometry.inside import inside_union
from sweepedit.geometry.model import SweepPrimitive
from sweepedit.geometry.sweep import (
    axis_frames,
    axis_points_tangents,
    axis_speed,
    scaling_factor,
    superellipse,
    superellipse_level,
    sweep_surface,
)

# Slices per loft, evenly spaced but for one more halfway into each end's interval (the
# folds' creases, where a loft's errors gather, lie anywhere along it: slices packed
# towards the ends by a cosine left 37 % more of the 64^3 cells of the folding
# primitives wrong and missed two primitives' volume checks; evenly spaced to the ends,
# a loft of a test's crossing sweep intersected itself near an end), rays per slice
# (a multiple of 4), lines of the occupancy grid per side of a slice's window (odd: every
# other line makes the coarse grid tested first), the ends' inset as a share of the
# solid's extent, and bisection steps per ray. (12 steps were 5 % faster, but one
# folding primitive of dog.txt then missed its volume check.)
SLICES = 30
RAYS = 48
GRID = 49
# Every this many slices' coarse grid is tested before the others' (ring_candidates).
PRESCREEN_STRIDE = 4
INSET = 2e-3
BISECTIONS = 18
# How far (in the solid's size) a loft may stray from the boundary halfway between two
# rays or two slices before an exact ray or slice is added there (_refined_rings).
REFINE_TOLERANCE = 5e-3
# The most ring points a refined loft may have (SLICES x RAYS = 1440 unrefined): a
# primitive's STEP text takes about 110 bytes per point, and more in a union, whose fuse
# splits faces (glyph_8.json's: 228 kB per primitive unrefined, 248 kB at 1700 points,
# 285 kB at 2100; the target is 250 kB).
MAX_RING_POINTS = 1700
# Steps along a ray on a slice's occupancy grid, in the cell's shorter side, and how
# far past its first crossing (in cell diagonals) the grid's boundary may waver.
MARCH_STEP = 0.5
STRAY = 1.5
# Directions tried after the chord and the principal ones: a Fibonacci hemisphere.
HEMISPHERE = 40
# Samples of the side surface: the solid's extent along a direction is attained there.
SURFACE_STATIONS = 257
SURFACE_ANGLES = 128
# Half-planes about a line are tried when the caps' planes meet at this angle or more
# (radians), the line clears the solid by CLEARANCE of its size, and the solid spans
# less than MAX_SPAN about it (beyond, the angles wrap round).
MIN_CAP_ANGLE = 0.05
CLEARANCE = 0.02
MAX_SPAN = 0.95 * np.pi
# Samples along the loft per ray when its rings are moved onto the caps' planes (rings_on_caps).
CAP_SEARCH = 2049
# End stubs (EndStub): their length in the end section's smaller half-axis (f min(a, b)
# at the cap) and at most a share of the axis' length (a long stub takes slices from the
# solid), the least share of the cap's scale they taper to, and their surface samples.
STUB_LENGTH = 0.6
STUB_AXIS_SHARE = 0.15
STUB_MIN_SCALE = 0.5
STUB_STATIONS = 17


class ParallelPlanes:
    """Planes across a unit direction (3,). Local coordinates (..., 3) of a point: its
    position along the direction, then two coordinates across it (slicing_frame)."""

    def __init__(self, direction: np.ndarray) -> None:
        self.rows = slicing_frame(direction)

    def to_local(self, points: np.ndarray) -> np.ndarray:
        return points @ self.rows.T

    def to_world(self, local: np.ndarray) -> np.ndarray:
        return local @ self.rows


class PlanesThroughLine:
    """Half-planes bounded by the line through `origin` (3,) along rows[0]; rows (3, 3)
    orthonormal, right-handed. Local coordinates (..., 3) of a point: the angle of its
    half-plane about the line from rows[1] towards rows[2], its position along the line,
    and its distance from the line. Ordered by angle, the half-planes' normals are the
    direction of increasing angle, and (along the line, distance) turn counter-clockwise
    about it, as for ParallelPlanes."""

    def __init__(self, origin: np.ndarray, rows: np.ndarray) -> None:
        self.origin = origin
        self.rows = rows

    def to_local(self, points: np.ndarray) -> np.ndarray:
        q = (points - self.origin) @ self.rows.T
        return np.stack([np.arctan2(q[..., 2], q[..., 1]), q[..., 0],
                         np.hypot(q[..., 1], q[..., 2])], axis=-1)

    def to_world(self, local: np.ndarray) -> np.ndarray:
        angle, along = local[..., 0:1], local[..., 1:2]
        # Past the line is not in the half-plane: onto the line, which the solid misses.
        distance = np.maximum(local[..., 2:3], 0.0)
        return (self.origin + along * self.rows[0]
                + distance * (np.cos(angle) * self.rows[1] + np.sin(angle) * self.rows[2]))


SlicingPlanes = ParallelPlanes | PlanesThroughLine


class SliceRings(NamedTuple):
    """u (S,) in [0, 1], increasing: where each slice lies between the solid's two
    extremes across the planes; rings (S, P, 3): the boundary at angles (P,) about the
    slice's centre, counter-clockwise about the planes' normal (increasing in [0, 2π),
    the quarter turns among them; uniform but where rays were added)."""

    u: np.ndarray
    rings: np.ndarray
    angles: np.ndarray


# Per slice and ray, radii (lo, hi, each (S, P)) between which the ray leaves the region.
_Bracket = tuple[np.ndarray, np.ndarray]
# A slice's occupancy grid: occupied (S, G, G) at the nodes of lines g1, g2 (S, G).
_Grid = tuple[np.ndarray, np.ndarray, np.ndarray]


def surface_samples(primitive: SweepPrimitive) -> np.ndarray:
    """Points of the side surface, (SURFACE_STATIONS * SURFACE_ANGLES, 3)."""
    cps, profile, scaling = primitive.batch_arrays()
    t = np.linspace(0.0, 1.0, SURFACE_STATIONS)
    theta = np.linspace(0.0, 2.0 * np.pi, SURFACE_ANGLES, endpoint=False)
    return sweep_surface(cps, profile, scaling, t, theta)[0].reshape(-1, 3)


def caps_pencil(primitive: SweepPrimitive, surface: np.ndarray) -> PlanesThroughLine | None:
    """The half-planes about the line where the planes of the two caps meet, bounded so
    that the solid lies on their side of it; None where the caps are (nearly) parallel,
    the line comes within CLEARANCE of the solid's size, or the solid spans MAX_SPAN or
    more about it. surface: surface_samples(primitive)."""
    points, tangents = axis_points_tangents(primitive.control_points[None],
                                            np.array([0.0, 1.0]))
    (c0, c1), (t0, t1) = points[0], tangents[0]
    line = np.cross(t0, t1)
    sine = float(np.linalg.norm(line))
    if sine < math.sin(MIN_CAP_ANGLE):
        return None
    line /= sine
    # The point of the line halfway along it between the caps' centres.
    origin = np.linalg.solve(np.stack([t0, t1, line]),
                             np.array([t0 @ c0, t1 @ c1, line @ (c0 + c1) / 2.0]))
    towards = surface.mean(axis=0) - origin
    towards -= (towards @ line) * line
    if np.linalg.norm(towards) < 1e-12:
        return None
    towards /= np.linalg.norm(towards)
    pencil = PlanesThroughLine(origin, np.stack([line, towards, np.cross(line, towards)]))
    local = pencil.to_local(surface)
    size = float(np.linalg.norm(surface.max(axis=0) - surface.min(axis=0)))
    if local[:, 2].min() < CLEARANCE * size or np.abs(local[:, 0]).max() >= MAX_SPAN:
        return None
    return pencil


class EndStub(NamedTuple):
    """A short straight continuation of a sweep past one of its caps: the cap's profile
    (in its frame u, v, each (3,)) carried a distance z in [0, length] beyond the cap's
    centre (3,) along the outward unit tangent (3,), scaled by scale + slope z. The slope
    is the sweep's own dF/ds there, so the side surface goes on tangent-continuously and
    a loft through slices of the sweep with its stubs crosses the cap's plane smoothly;
    its section by that plane (rings_on_caps) is then a flat cap with a sharp rim, which
    a loft ending at the solid's extreme rounds off. (A stub rounded off at its own end
    put the rod's rims 5x closer, but on 21 folding primitives of 8 files as many 64^3
    cells wrong in all; BENCHMARKS.md, STEP export.)"""

    centre: np.ndarray
    tangent: np.ndarray
    u: np.ndarray
    v: np.ndarray
    scale: float
    slope: float
    length: float
    profile: np.ndarray  # (3,) a, b, d

    def local(self, points: np.ndarray) -> np.ndarray:
        """Coordinates (..., 3) of points (..., 3) in the cap's frame: (along u, along v,
        beyond the cap)."""
        q = points - self.centre
        return np.stack([q @ self.u, q @ self.v, q @ self.tangent], axis=-1)

    def scale_at(self, z: np.ndarray | float) -> np.ndarray:
        """The profile's scale at distances z (...) past the cap, held at the stub's ends
        outside [0, length]."""
        return self.scale + self.slope * np.clip(z, 0.0, self.length)

    def inside(self, points: np.ndarray) -> np.ndarray:
        """Whether points (..., 3) lie in the stub -> bool (...)."""
        q = np.reshape(points, (-1, 3)) - self.centre  # (N, 3)
        z = q @ self.tangent
        within = (z >= 0.0) & (z <= self.length)  # most points are not: only these tested
        q, z = q[within], z[within]
        scale = self.scale_at(z)
        x, y = (q @ self.u) / scale, (q @ self.v) / scale
        inside = np.zeros(len(within), dtype=bool)
        inside[within] = superellipse_level(x[None], y[None], self.profile[None])[0] <= 1.0
        return inside.reshape(np.shape(points)[:-1])

    def reach(self) -> float:
        """Half the side of a square about the axis that holds every section."""
        return float(max(self.scale_at(0.0), self.scale_at(self.length))
                     * max(self.profile[0], self.profile[1]))

    def surface(self) -> np.ndarray:
        """Points of its side surface, (STUB_STATIONS * SURFACE_ANGLES, 3)."""
        z = np.linspace(0.0, self.length, STUB_STATIONS)
        theta = np.linspace(0.0, 2.0 * np.pi, SURFACE_ANGLES, endpoint=False)
        x, y = (c[0] for c in superellipse(theta, self.profile[None]))
        ring = x[:, None] * self.u + y[:, None] * self.v  # (P, 3)
        return (self.centre + z[:, None, None] * self.tangent
                + self.scale_at(z)[:, None, None] * ring).reshape(-1, 3)


def end_stubs(primitive: SweepPrimitive, surface: np.ndarray) -> list[EndStub]:
    """The stubs of the primitive's two caps (EndStub) that nothing else of it comes
    near: none where its side surface (surface_samples) reaches past the cap's plane
    within the square about the stub (a fold at the end, or another part of the solid;
    a cut there would cut the solid itself)."""
    cps, _, scaling = primitive.batch_arrays()
    ends = np.array([0.0, 1.0])
    frames = axis_frames(cps, ends)
    f = scaling_factor(scaling, ends)[0]
    poly = np.polynomial.polynomial
    df = poly.polyval(ends, poly.polyder(np.concatenate([[1.0], scaling[0]])))  # f'(t)
    speed = axis_speed(cps, ends)[0]
    size = float(np.linalg.norm(surface.max(axis=0) - surface.min(axis=0)))
    longest = STUB_AXIS_SHARE * axis_length(primitive.control_points)
    stubs = []
    for k, sign in ((0, -1.0), (1, 1.0)):
        length = min(STUB_LENGTH * f[k] * float(min(primitive.a, primitive.b)), longest)
        slope = max(sign * df[k] / speed[k], -(1.0 - STUB_MIN_SCALE) * f[k] / length)
        stub = EndStub(frames.points[0, k], sign * frames.T[0, k], frames.U[0, k],
                       frames.V[0, k], float(f[k]), float(slope), length,
                       np.asarray(primitive.profile, dtype=float))
        x, y, z = np.moveaxis(stub.local(surface), -1, 0)
        half = 1.2 * stub.reach()
        near = (np.abs(x) <= half) & (np.abs(y) <= half) & (z <= 2.0 * length)
        if not (near & (z > 1e-6 * size)).any():
            stubs.append(stub)
    return stubs


def slicing_families(primitive: SweepPrimitive, surface: np.ndarray
                     ) -> Iterator[SlicingPlanes]:
    """The families of planes to slice along: parallel planes across
    slicing_directions, then the caps' pencil (caps_pencil). Tried first, the pencil
    missed more of the folding primitives' cells (its slices lie far apart on the outer
    side of a bend, and its first and last slices are a whole cap's inset from the ends);
    last, it builds one that no direction does (BENCHMARKS.md, STEP export)."""
    for direction in slicing_directions(primitive, surface):
        yield ParallelPlanes(direction)
    pencil = caps_pencil(primitive, surface)
    if pencil is not None:
        yield pencil


def slicing_directions(primitive: SweepPrimitive, surface: np.ndarray) -> Iterator[np.ndarray]:
    """Unit directions (3,) to slice along, the likeliest first: the axis' chord, the
    surface's principal directions, then HEMISPHERE directions spread over a hemisphere."""
    chord = primitive.control_points[-1] - primitive.control_points[0]
    _, _, principal = np.linalg.svd(surface - surface.mean(axis=0), full_matrices=False)
    k = np.arange(HEMISPHERE) + 0.5
    z = k / HEMISPHERE
    turn = np.pi * (1.0 + math.sqrt(5.0)) * k
    ring = np.sqrt(1.0 - z**2)
    spread = np.stack([ring * np.cos(turn), ring * np.sin(turn), z], axis=-1)
    for d in [chord, *principal, *spread]:
        n = float(np.linalg.norm(d))
        if n > 1e-12:
            yield d / n


def slicing_frame(direction: np.ndarray) -> np.ndarray:
    """Rows (3, 3): the direction d and two unit vectors e1, e2 across it, (e1, e2, d)
    right-handed."""
    helper = np.eye(3)[int(np.argmin(np.abs(direction)))]
    e1 = np.cross(direction, helper)
    e1 /= np.linalg.norm(e1)
    return np.stack([direction, e1, np.cross(direction, e1)])


def _slice_windows(local: np.ndarray, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per slice at positions s (S,), a window (lo, hi, each (S, 2)) across the direction
    that holds the slice: the surface samples near the slice (local (N, 3): along, across,
    across), widened by half its size, within the whole surface's window."""
    order = np.argsort(local[:, 0])
    along = local[order, 0]
    across = np.ascontiguousarray(local[order, 1:])
    (whole_lo,), (whole_hi,) = _range_bounds(across, np.array([0]), np.array([len(across)]))
    pad = 0.02 * float(np.max(whole_hi - whole_lo))
    band = 1.5 * (along[-1] - along[0]) / (SURFACE_STATIONS - 1)
    a, b = np.searchsorted(along, s - band), np.searchsorted(along, s + band)
    tip = b - a < 8  # a tip: the nearest samples
    c = np.searchsorted(along, s[tip])
    a[tip], b[tip] = np.maximum(0, c - 8), np.minimum(len(along), c + 8)
    near_lo, near_hi = _range_bounds(across, a, b)
    half = 0.5 * (near_hi - near_lo) + pad
    return (np.maximum(near_lo - half, whole_lo - pad),
            np.minimum(near_hi + half, whole_hi + pad))


@numba.njit(cache=True, nogil=True)
def _range_bounds(values: np.ndarray, a: np.ndarray, b: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray]:
    """The least and greatest of values (N, 2) over each range of rows a[i]:b[i] (each
    (S,), not empty) -> each (S, 2): a loop, where numpy's calls took 4 of
    _slice_windows' 5 ms (its min and max over a column of an (N, 2) array are slow)."""
    lo, hi = np.empty((len(a), 2)), np.empty((len(a), 2))
    for i in range(len(a)):
        for c in range(2):
            lo[i, c], hi[i, c] = values[a[i], c], values[a[i], c]
            for r in range(a[i] + 1, b[i]):
                lo[i, c] = min(lo[i, c], values[r, c])
                hi[i, c] = max(hi[i, c], values[r, c])
    return lo, hi


def _one_region_each(occupied: np.ndarray) -> bool:
    """Whether every slice's occupancy (occupied (S, G, G)) is one region without holes:
    one 8-connected region and one 4-connected outside, labelled in one pass over all
    slices, with no connection across them."""
    S = len(occupied)
    for where, plane in ((occupied, np.ones((3, 3), dtype=bool)),
                         (~occupied, ndimage.generate_binary_structure(2, 1))):
        structure = np.zeros((3, 3, 3), dtype=bool)
        structure[1] = plane
        labels, count = ndimage.label(where, structure=structure)
        slab = np.broadcast_to(np.arange(S)[:, None, None], labels.shape)
        first = np.zeros(count + 1, dtype=int)  # each label's slice
        first[labels.ravel()] = slab.ravel()
        if not np.array_equal(np.bincount(first[1:], minlength=S), np.ones(S, dtype=int)):
            return False
    return True


def _centroids(occupied: np.ndarray, g1: np.ndarray, g2: np.ndarray) -> np.ndarray:
    """Each slice's region's centroid (S, 2): it moves smoothly from slice to slice, where
    the deepest point jumps by grid cells; rays from a jumping centre meet the boundary
    along wavy lines, and the loft through them strays from the surface between slices
    (on the folding primitives of ant.json, now.txt, elephant.json and hand2.txt, 35-65 %
    fewer 64^3 cells on the wrong side with centroids). occupied (S, G, G) on the lines
    g1, g2 (S, G)."""
    weight = occupied.astype(float)
    total = weight.sum(axis=(1, 2))
    return np.stack([(weight.sum(axis=2) * g1).sum(axis=1) / total,
                     (weight.sum(axis=1) * g2).sum(axis=1) / total], axis=-1)


def _deepest(occupied: np.ndarray, g1: np.ndarray, g2: np.ndarray) -> np.ndarray:
    """Each slice's grid node deepest inside its region (S, 2): the centre tried where
    the centroid's rays fail. Distances within each slice only: the slices lie a
    million cells apart for the transform."""
    S, G, _ = occupied.shape
    depth = ndimage.distance_transform_edt(np.pad(occupied, ((0, 0), (1, 1), (1, 1))),
                                           sampling=(1e6, 1.0, 1.0))[:, 1:-1, 1:-1]
    a, b = np.unravel_index(np.argmax(depth.reshape(S, -1), axis=1), (G, G))
    rows = np.arange(S)
    return np.stack([g1[rows, a], g2[rows, b]], axis=-1)


def _inside(primitive: SweepPrimitive, planes: SlicingPlanes, local: np.ndarray,
            stubs: Sequence[EndStub] = ()) -> np.ndarray:
    """The exact inside test of the primitive with its stubs at points of local
    coordinates (..., 3) -> bool (...)."""
    world = planes.to_world(local.reshape(-1, 3))
    inside = inside_union(world, [primitive])
    for stub in stubs:
        inside |= stub.inside(world)
    return inside.reshape(local.shape[:-1])


def _ray_points(s: np.ndarray, centres: np.ndarray, directions: np.ndarray,
                radii: np.ndarray) -> np.ndarray:
    """Local coordinates of points at radii (S, P, ...) from each slice's centre (S, 2)
    along unit directions (P, 2), in the slices at s (S,) -> (S, P, ..., 3)."""
    extra = (1,) * (radii.ndim - 2)
    S, P = radii.shape[:2]
    across = (centres.reshape(S, 1, *extra, 2)
              + radii[..., None] * directions.reshape(1, P, *extra, 2))
    along = np.broadcast_to(s.reshape(S, 1, *extra, 1), (*radii.shape, 1))
    return np.concatenate([along, across], axis=-1)


def _ray_radii(primitive: SweepPrimitive, planes: SlicingPlanes, s: np.ndarray,
               centres: np.ndarray, directions: np.ndarray, bracket: _Bracket,
               stubs: Sequence[EndStub] = ()) -> np.ndarray:
    """Distance from each slice's centre (S, 2) to its boundary along unit directions
    (P, 2) -> (S, P), by BISECTIONS halvings of a bracket (lo, hi, each (S, P)) with lo
    inside and hi outside."""
    lo, hi = bracket
    for _ in range(BISECTIONS):
        mid = 0.5 * (lo + hi)
        hit = _inside(primitive, planes, _ray_points(s, centres, directions, mid), stubs)
        lo, hi = np.where(hit, mid, lo), np.where(hit, hi, mid)
    return 0.5 * (lo + hi)


def _brackets(primitive: SweepPrimitive, planes: SlicingPlanes, s: np.ndarray,
              centres: np.ndarray, directions: np.ndarray, grid: _Grid, reach: float,
              stubs: Sequence[EndStub] = ()) -> _Bracket | None:
    """Per slice at s (S,) and ray, radii (lo, hi, each (S, P)) about the centres (S, 2)
    along the directions (P, 2), lo inside and hi outside, between which the ray leaves
    the region; None where a ray leaves it more than once (it is not star-shaped about
    the centre). Read off the slices' occupancy grid (_grid_brackets) and checked by the
    exact test at both ends; slices where the grid gives no bracket or a wrong one (a
    slice of a few cells at a tip, where its boundary wavers) are marched exactly
    (_march_brackets). The grid spares the exact march of 28 x 48 x 49 points on most
    candidates."""
    lo, hi, ok = _grid_brackets(grid, centres, directions)
    if ok.any():
        ok[ok] = _holds(primitive, planes, s[ok], centres[ok], directions, lo[ok], hi[ok],
                        stubs)
    redo = ~ok
    if redo.any():
        lo[redo], hi[redo], marched = _march_brackets(primitive, planes, s[redo],
                                                      centres[redo], directions, reach,
                                                      stubs)
        if not marched.all():
            return None
    return lo, hi


def _grid_brackets(grid: _Grid, centres: np.ndarray, directions: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Brackets as _brackets (lo, hi, each (S, P)) read off the occupancy grid (grid:
    occupied (S, G, G) on uniform lines g1, g2 (S, G)) by bilinear interpolation at
    steps of MARCH_STEP of a cell's shorter side across the whole window, and per slice
    whether every ray of it got one (S,). The grid's boundary wavers within about a cell
    of the true one: inside steps within STRAY cell diagonals past a ray's first step
    outside set the bracket's far end, inside steps beyond are a second crossing, and
    each bracket is widened by a cell's diagonal at both ends."""
    occupied, g1, g2 = grid
    S, G, _ = occupied.shape
    cell = np.stack([g1[:, 1] - g1[:, 0], g2[:, 1] - g2[:, 0]], axis=-1)  # (S, 2)
    step = MARCH_STEP * cell.min(axis=1)  # (S,)
    count = int(np.ceil(((G - 1) * np.linalg.norm(cell, axis=1) / step).max())) + 2
    radii = np.arange(count) * step[:, None]  # (S, M)
    at = centres[:, None, None, :] + radii[:, None, :, None] * directions[None, :, None, :]
    origin = np.stack([g1[:, 0], g2[:, 0]], axis=-1)
    index = (at - origin[:, None, None, :]) / cell[:, None, None, :]  # (S, P, M, 2)
    slab = np.broadcast_to(np.arange(S, dtype=float)[:, None, None], index.shape[:-1])
    level = ndimage.map_coordinates(occupied.astype(np.float32),
                                    [slab, index[..., 0], index[..., 1]],
                                    order=1, mode="constant", cval=0.0)
    inside = level >= 0.5  # (S, P, M)
    leaves = np.maximum(np.argmin(inside, axis=2), 1)  # the first step outside
    rows, pad = np.arange(S)[:, None], np.linalg.norm(cell, axis=1)[:, None]
    near = radii[:, None, :] <= radii[rows, leaves][..., None] + STRAY * pad[..., None]
    ok = inside[:, :, 0].all(axis=1) & ~(inside & ~near).any(axis=(1, 2))
    last = count - 1 - np.argmax(inside[..., ::-1], axis=2)  # the last step inside
    return (np.maximum(radii[rows, leaves - 1] - pad, 0.0),
            radii[rows, np.minimum(last + 1, count - 1)] + pad, ok)


def _march_brackets(primitive: SweepPrimitive, planes: SlicingPlanes, s: np.ndarray,
                    centres: np.ndarray, directions: np.ndarray, reach: float,
                    stubs: Sequence[EndStub] = ()) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Brackets as _brackets (lo, hi, each (S, P)), by the exact inside test at GRID
    steps along each ray up to `reach`, and per slice whether each of its rays leaves
    the region exactly once, from a centre inside (S,); the brackets of the others are
    meaningless."""
    steps = np.linspace(0.0, reach, GRID)
    radii = np.broadcast_to(steps, (len(s), len(directions), GRID))
    inside = _inside(primitive, planes, _ray_points(s, centres, directions, radii), stubs)
    leaves = np.argmin(inside, axis=2)  # the first sample outside
    later = np.arange(GRID) >= leaves[..., None]
    ok = (inside[:, :, 0] & (leaves > 0) & ~(inside & later).any(axis=2)).all(axis=1)
    return steps[np.maximum(leaves - 1, 0)], steps[leaves], ok


def _holds(primitive: SweepPrimitive, planes: SlicingPlanes, s: np.ndarray,
           centres: np.ndarray, directions: np.ndarray, lo: np.ndarray, hi: np.ndarray,
           stubs: Sequence[EndStub] = ()) -> np.ndarray:
    """Per slice at s (S,), whether every bracket (lo, hi, each (S, P)) of its rays has
    lo inside and hi outside, by the exact test -> (S,)."""
    ends = np.stack([lo, hi], axis=-1)  # (S, P, 2)
    inside = _inside(primitive, planes, _ray_points(s, centres, directions, ends), stubs)
    return inside[..., 0].all(axis=1) & ~inside[..., 1].any(axis=1)


def slice_rings(primitive: SweepPrimitive, planes: SlicingPlanes,
                surface: np.ndarray | None = None,
                stubs: Sequence[EndStub] = ()) -> SliceRings | None:
    """The first of ring_candidates, or None if there is none."""
    return next(ring_candidates(primitive, planes, surface, stubs), None)


def ring_candidates(primitive: SweepPrimitive, planes: SlicingPlanes,
                    surface: np.ndarray | None = None,
                    stubs: Sequence[EndStub] = ()) -> Iterator[SliceRings]:
    """The boundary of the solid with its stubs (EndStub) on SLICES planes of the family
    `planes`, as rings of RAYS points about each slice's centroid, then about its deepest
    point (_centroids, _deepest), wherever every slice is star-shaped about them;
    nothing if a slice is not one region. `surface`: surface_samples(primitive) and the
    stubs' surfaces, when already at hand. The rings about centroids make the closer
    loft, but a loft through them may still fail its volume check where the other does
    not."""
    if surface is None:
        surface = np.concatenate([surface_samples(primitive), *(s.surface() for s in stubs)])
    local = planes.to_local(surface)
    first, last = float(local[:, 0].min()), float(local[:, 0].max())
    even = np.linspace(INSET, 1.0 - INSET, SLICES - 2)
    half = 0.5 * (even[1] - even[0])
    u = np.sort(np.concatenate([even, [even[0] + half, even[-1] - half]]))
    s = first + (last - first) * u
    lo, hi = _slice_windows(local, s)
    w = np.linspace(0.0, 1.0, GRID)
    g1 = lo[:, :1] + w * (hi[:, :1] - lo[:, :1])  # (S, GRID)
    g2 = lo[:, 1:] + w * (hi[:, 1:] - lo[:, 1:])

    def inside_at(slab: np.ndarray, i: np.ndarray, j: np.ndarray) -> np.ndarray:
        """The exact test at grid nodes (slice, line 1, line 2), each (N,)."""
        return _inside(primitive, planes, np.stack([s[slab], g1[slab, i], g2[slab, j]],
                                                   axis=-1), stubs)

    # Every other line first: most families tried are rejected by it, at a quarter of
    # the cost, and the full grid is then tested only where that one leaves it open.
    # Every fourth slice before the others: a slice in two regions is seldom alone, and
    # the family is then rejected at a quarter of that cost again (each slice is judged
    # on its own, so the order changes nothing else).
    coarse_lines = np.arange(0, GRID, 2)
    C = len(coarse_lines)
    coarse = np.zeros((SLICES, C, C), dtype=bool)
    first_slices = np.arange(0, SLICES, PRESCREEN_STRIDE)
    for part in (first_slices, np.setdiff1d(np.arange(SLICES), first_slices)):
        slab, i, j = (a.ravel() for a in np.meshgrid(part, coarse_lines, coarse_lines,
                                                     indexing="ij"))
        coarse[part] = inside_at(slab, i, j).reshape(len(part), C, C)
        if not _one_region_each(coarse[part]):
            return
    occupied, open_ = _refined(coarse)
    slab, i, j = np.nonzero(open_)
    occupied[slab, i, j] = inside_at(slab, i, j)
    if not _one_region_each(occupied):
        return
    angles = np.linspace(0.0, 2.0 * np.pi, RAYS, endpoint=False)
    directions = np.stack([np.cos(angles), np.sin(angles)], axis=-1)
    reach = float(np.hypot(*(local[:, 1:].max(axis=0) - local[:, 1:].min(axis=0))))
    for centre in (_centroids, _deepest):
        centres = centre(occupied, g1, g2)
        bracket = _brackets(primitive, planes, s, centres, directions, (occupied, g1, g2),
                            reach, stubs)
        if bracket is None:
            continue
        radii = _ray_radii(primitive, planes, s, centres, directions, bracket, stubs)
        sliced = SliceRings(u, planes.to_world(_ray_points(s, centres, directions, radii)),
                            angles)
        finer = _refined_rings(primitive, planes, sliced, s, centres, reach, stubs)
        if finer is not sliced:
            yield finer
        yield sliced


class _Rays(NamedTuple):
    """Rays in slices: each slice's position along its family (N,), the ray's origin
    (N, 2) and unit direction (N, 2) across, and a distance along it (N,)."""

    along: np.ndarray
    centre: np.ndarray
    direction: np.ndarray
    radius: np.ndarray

    def at(self, r: np.ndarray) -> np.ndarray:
        """Local points at distances r (N, ...) along the rays -> (N, ..., 3)."""
        extra = (None,) * (r.ndim - 1)
        across = (self.centre[(slice(None), *extra)]
                  + r[..., None] * self.direction[(slice(None), *extra)])
        return np.concatenate([np.broadcast_to(self.along[(..., *extra, None)],
                                               (*r.shape, 1)), across], axis=-1)

    def subset(self, keep: np.ndarray) -> _Rays:
        return _Rays(*(field[keep] for field in self))


def _rays_through(planes: SlicingPlanes, points: np.ndarray, s: np.ndarray,
                  centres: np.ndarray) -> _Rays:
    """The rays through points (N, 3) from the centre of each one's own slice (the
    slices' centres (S, 2) at s (S,), interpolated), their radius the point's distance."""
    local = planes.to_local(points)
    along = local[:, 0]
    centre = np.stack([np.interp(along, s, centres[:, k]) for k in range(2)], axis=-1)
    offset = local[:, 1:] - centre
    radius = np.linalg.norm(offset, axis=-1)
    return _Rays(along, centre, offset / np.maximum(radius, 1e-300)[:, None], radius)


def _strays(primitive: SweepPrimitive, planes: SlicingPlanes, rays: _Rays,
            tolerance: float, stubs: Sequence[EndStub] = ()) -> np.ndarray:
    """Whether the boundary misses each ray's point by more than `tolerance` along the
    ray (N,): the point that much nearer the centre is outside, or the one that much
    further inside (two exact tests per point, where finding the boundary takes 67)."""
    near = _inside(primitive, planes, rays.at(np.maximum(rays.radius - tolerance, 0.0)),
                   stubs)
    far = _inside(primitive, planes, rays.at(rays.radius + tolerance), stubs)
    return ~near | far


def _boundary_points(primitive: SweepPrimitive, planes: SlicingPlanes, rays: _Rays,
                     reach: float, stubs: Sequence[EndStub] = ()
                     ) -> tuple[np.ndarray, np.ndarray]:
    """Where the rays leave the solid with its stubs -> the points (N, 3), by GRID steps
    up to `reach` and BISECTIONS halvings, and whether each ray leaves it exactly once,
    from a centre inside (N,)."""
    steps = np.linspace(0.0, reach, GRID)
    inside = _inside(primitive, planes, rays.at(np.broadcast_to(steps, (len(rays.along),
                                                                        GRID))), stubs)
    leaves = np.argmin(inside, axis=1)  # the first step outside
    later = np.arange(GRID) >= leaves[:, None]
    single = inside[:, 0] & (leaves > 0) & ~(inside & later).any(axis=1)
    lo, hi = steps[np.maximum(leaves - 1, 0)], steps[leaves]
    for _ in range(BISECTIONS):
        mid = 0.5 * (lo + hi)
        hit = _inside(primitive, planes, rays.at(mid), stubs)
        lo, hi = np.where(hit, mid, lo), np.where(hit, hi, mid)
    return planes.to_world(rays.at(0.5 * (lo + hi))), single


def _refined_rings(primitive: SweepPrimitive, planes: SlicingPlanes, sliced: SliceRings,
                   s: np.ndarray, centres: np.ndarray, reach: float,
                   stubs: Sequence[EndStub] = ()) -> SliceRings:
    """`sliced` with exact rays, then exact slices, added where a loft through it strays
    from the boundary (_with_mid_rays, _with_mid_slices); `sliced` itself where it strays
    nowhere, or where the refined loft strays at no smaller share of its own halfway
    points (_straying_share: uneven spacing can make a cubic overshoot next to a ring
    added). On the 64^3 grid, elephant.json's 5th and 6th folding primitives went from
    23 and 46 wrong cells to 5 and 14 (BENCHMARKS.md, STEP export)."""
    with_rays = _with_mid_rays(primitive, planes, sliced, s, centres, reach, stubs)
    finer = _with_mid_slices(primitive, planes, with_rays, s, centres, reach, stubs)
    if finer is sliced:
        return sliced
    tolerance = REFINE_TOLERANCE * _size(sliced.rings)
    before, after = (_straying_share(primitive, planes, rings, s, centres, tolerance, stubs)
                     for rings in (sliced, finer))
    return finer if after < before else sliced


def _halfway_across(sliced: SliceRings) -> np.ndarray:
    """The loft through `sliced` (rings (S, P, 3)) halfway after each ray, in every
    slice, by its cubics across the rays of each quarter turn -> (S, P, 3)."""
    _, rings, angles = sliced
    S, P = rings.shape[:2]
    ends = np.append(angles, 2.0 * np.pi)
    halfway = np.empty((S, P, 3))
    for first, last in quarter_turns(angles):
        theta = ends[first:last + 1]
        across = make_interp_spline(theta, rings[:, np.arange(first, last + 1) % P], k=3,
                                    axis=1)
        halfway[:, first:last] = across(0.5 * (theta[:-1] + theta[1:]))
    return halfway


def _halfway_along(sliced: SliceRings) -> np.ndarray:
    """The loft through `sliced` (rings (S, P, 3)) halfway between each two slices, on
    every ray, by its cubics along the slices -> (S - 1, P, 3)."""
    u = sliced.u
    return make_interp_spline(u, sliced.rings, k=3, axis=0)(0.5 * (u[:-1] + u[1:]))


def _straying_share(primitive: SweepPrimitive, planes: SlicingPlanes, sliced: SliceRings,
                    s: np.ndarray, centres: np.ndarray, tolerance: float,
                    stubs: Sequence[EndStub] = ()) -> float:
    """The share of the loft's points halfway between its rays and between its slices
    that lie further than `tolerance` from the boundary (_strays; the rays from the
    centres (S, 2) of the slices at s (S,))."""
    points = np.concatenate([_halfway_across(sliced).reshape(-1, 3),
                             _halfway_along(sliced).reshape(-1, 3)])
    rays = _rays_through(planes, points, s, centres)
    return float(np.mean(_strays(primitive, planes, rays, tolerance, stubs)))


def _with_mid_rays(primitive: SweepPrimitive, planes: SlicingPlanes, sliced: SliceRings,
                   s: np.ndarray, centres: np.ndarray, reach: float,
                   stubs: Sequence[EndStub] = ()) -> SliceRings:
    """`sliced` (its slices at s (S,) with centres (S, 2)) with a ray added halfway
    between two rays, in every slice, where the loft's cubic across them strays from the
    boundary by more than REFINE_TOLERANCE of the solid's size in some slice (and the
    ray leaves every slice's region once): the furthest-straying first, up to half the
    rays that MAX_RING_POINTS leaves room for. A fold's crease in a slice is a corner of
    its ring, which evenly spaced rays round off. The rays at the quarter turns, the
    patches' seams (quarter_turns), stay where they are. A ray added goes through the
    loft's point, not at the angle halfway: close enough, and the loft keeps its order."""
    u, rings, angles = sliced
    S, P = rings.shape[:2]
    room = (MAX_RING_POINTS // S - P) // 2
    ends = np.append(angles, 2.0 * np.pi)
    lofted = _halfway_across(sliced)
    rays = _rays_through(planes, lofted.reshape(-1, 3), s, centres)
    tolerance = REFINE_TOLERANCE * _size(rings)
    candidates = np.flatnonzero(
        _strays(primitive, planes, rays, tolerance, stubs).reshape(S, P).any(axis=0))
    if room <= 0 or not len(candidates):
        return sliced
    keep = np.zeros((S, P), dtype=bool)
    keep[:, candidates] = True
    points, single = _boundary_points(primitive, planes, rays.subset(keep.ravel()), reach,
                                      stubs)
    points = points.reshape(S, -1, 3)
    error = np.linalg.norm(points - lofted[:, candidates], axis=2).max(axis=0)
    error[~single.reshape(S, -1).all(axis=0)] = -1.0
    chosen = _furthest(error, room)
    if not len(chosen):
        return sliced
    all_angles = np.concatenate([angles, (0.5 * (ends[:-1] + ends[1:]))[candidates[chosen]]])
    order = np.argsort(all_angles)
    rings = np.concatenate([rings, points[:, chosen]], axis=1)
    return SliceRings(u, rings[:, order], all_angles[order])


def _furthest(error: np.ndarray, count: int) -> np.ndarray:
    """The indices of the `count` largest non-negative errors (N,), at most."""
    order = np.argsort(-error)[:count]
    return order[error[order] >= 0.0]


def _size(rings: np.ndarray) -> float:
    """The diagonal of the box about rings (..., 3)."""
    return float(np.linalg.norm(np.ptp(rings.reshape(-1, 3), axis=0)))


def quarter_turns(angles: np.ndarray) -> list[tuple[int, int]]:
    """The rays (first, last) of each quarter turn of a ring's angles (P,), increasing
    in [0, 2π) with the quarter turns among them: the rays first..last of a quarter
    (last = P, ray 0 again, for the fourth) make one side patch of a loft."""
    # Less a hair: linspace's quarter turns may lie an ulp below π/2's.
    seams = [*np.searchsorted(angles, np.arange(4) * np.pi / 2.0 - 1e-9).tolist(), len(angles)]
    return [(int(seams[k]), int(seams[k + 1])) for k in range(4)]


def _with_mid_slices(primitive: SweepPrimitive, planes: SlicingPlanes, sliced: SliceRings,
                     s: np.ndarray, centres: np.ndarray, reach: float,
                     stubs: Sequence[EndStub] = ()) -> SliceRings:
    """`sliced` (its slices at s (S,) with centres (S, 2)) with a ring of the exact
    boundary added halfway between two slices where the loft through it strays from the
    boundary there by more than REFINE_TOLERANCE of the solid's size (and every ray of
    that ring leaves the region once): the furthest-straying first, as many as
    MAX_RING_POINTS leaves room for. A fold's crease runs across the slices, and evenly
    spaced slices round it off between them. The loft's points halfway are moved onto
    the boundary along the rays through them (_rays_through)."""
    u, rings, angles = sliced
    S, P = rings.shape[:2]
    room = MAX_RING_POINTS // P - S
    mid_u = 0.5 * (u[:-1] + u[1:])
    lofted = _halfway_along(sliced)
    rays = _rays_through(planes, lofted.reshape(-1, 3), s, centres)
    tolerance = REFINE_TOLERANCE * _size(rings)
    candidates = np.flatnonzero(
        _strays(primitive, planes, rays, tolerance, stubs).reshape(S - 1, P).any(axis=1))
    if room <= 0 or not len(candidates):
        return sliced
    keep = np.zeros((S - 1, P), dtype=bool)
    keep[candidates] = True
    points, single = _boundary_points(primitive, planes, rays.subset(keep.ravel()), reach,
                                      stubs)
    points = points.reshape(-1, P, 3)
    error = np.linalg.norm(points - lofted[candidates], axis=2).max(axis=1)
    error[~single.reshape(-1, P).all(axis=1)] = -1.0
    chosen = _furthest(error, room)
    if not len(chosen):
        return sliced
    all_u = np.concatenate([u, mid_u[candidates[chosen]]])
    order = np.argsort(all_u)
    return SliceRings(all_u[order], np.concatenate([rings, points[chosen]])[order], angles)


def _refined(coarse: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The occupancy of every slice's full grid (S, 2C - 1, 2C - 1) from the one on every
    other line (coarse (S, C, C)), and where it is still open (S, 2C - 1, 2C - 1): the
    nodes off the coarse grid in a coarse cell whose corners disagree, or next to one.
    Elsewhere a node takes the value its cell's four corners share."""
    C = coarse.shape[1]
    corners = (coarse[:, :-1, :-1].astype(np.int8) + coarse[:, 1:, :-1]
               + coarse[:, :-1, 1:] + coarse[:, 1:, 1:])  # (S, C-1, C-1) in 0..4
    mixed = (corners > 0) & (corners < 4)
    undecided = ndimage.binary_dilation(mixed, structure=np.ones((1, 3, 3), dtype=bool))
    cell = np.minimum(np.arange(2 * C - 1) // 2, C - 2)  # each node's cell along a side
    occupied = (corners == 4)[:, cell][:, :, cell]
    open_ = undecided[:, cell][:, :, cell]
    occupied[:, ::2, ::2] = coarse
    open_[:, ::2, ::2] = False
    return occupied, open_


def rings_on_caps(sliced: SliceRings, stubs: Sequence[EndStub]) -> SliceRings | None:
    """The loft through `sliced` (rings of a solid with its end stubs) cut back at the
    stubs' caps, as rings: per ray k, the loft's curve along the slices (the cubic
    through rings[:, k], which is the loft's surface at that ray's angle) is cut where it
    crosses each stub's cap plane, and SLICES new rings are spaced between the cuts as the
    slices were. So the first (or last) ring is the loft's own section by the cap's
    plane: its points lie in the plane, the loft's cap is flat, and its rim a sharp edge
    on the loft's surface; nothing past the cap is kept. None where a ray's curve crosses
    a cap's plane other than once, from the stub's side."""
    u = sliced.u
    P = sliced.rings.shape[1]
    curves = make_interp_spline(u, sliced.rings, k=3, axis=0)  # (S, P, 3) along u
    fine = np.linspace(u[0], u[-1], CAP_SEARCH)
    points = curves(fine)  # (F, P, 3)
    ends = {0: np.full(P, u[0]), -1: np.full(P, u[-1])}  # per ray, where the rings end
    planes = {}
    for stub in stubs:
        beyond = (points - stub.centre) @ stub.tangent  # (F, P): > 0 on the stub's side
        sign = beyond > 0.0
        if not (np.count_nonzero(sign[1:] != sign[:-1], axis=0) == 1).all():
            return None
        end = 0 if sign[0].all() else -1 if sign[-1].all() else None
        if end is None or end in planes:
            return None
        ends[end] = _crossing(curves, fine, beyond, stub)
        planes[end] = stub
    if not (ends[0] < ends[-1]).all():
        return None
    w = (u - u[0]) / (u[-1] - u[0])
    along = ends[0] + w[:, None] * (ends[-1] - ends[0])  # (S, P)
    rings = np.stack([_on_rays(curves, row) for row in along])  # (S, P, 3)
    for end, stub in planes.items():  # onto the plane exactly, from within 1e-12 or so
        gap = (rings[end] - stub.centre) @ stub.tangent
        rings[end] -= gap[:, None] * stub.tangent
    return SliceRings(u, rings, sliced.angles)


def _crossing(curves: Any, fine: np.ndarray, beyond: np.ndarray, stub: EndStub) -> np.ndarray:
    """Per ray, where its curve along the slices (curves, a spline over u of (P, 3))
    crosses the stub's cap plane -> (P,); `beyond` (F, P): the distance past the plane at
    the samples `fine` (F,), which change sign once per ray."""
    P = beyond.shape[1]
    i = np.argmax((beyond[1:] > 0.0) != (beyond[:-1] > 0.0), axis=0)  # the sample before
    a, b = fine[i], fine[i + 1]
    fa = beyond[i, np.arange(P)]
    for _ in range(40):  # bisection on each ray's own curve
        mid = 0.5 * (a + b)
        fm = (_on_rays(curves, mid) - stub.centre) @ stub.tangent
        same = (fm > 0.0) == (fa > 0.0)
        a, fa = np.where(same, mid, a), np.where(same, fm, fa)
        b = np.where(same, b, mid)
    return 0.5 * (a + b)


def _on_rays(curves: Any, u: np.ndarray) -> np.ndarray:
    """Each ray's point at its own parameter: curves a spline over u of (P, 3), u (P,)
    -> (P, 3), ray k's curve at u[k]."""
    rays = np.arange(len(u))
    return curves(u)[rays, rays]
