"""Slices of a primitive's exact solid (geometry/slices.py) against shapes whose slices
are known in closed form."""

from __future__ import annotations

import numpy as np
import pytest

from sweepedit.geometry.inside import inside_union
from sweepedit.geometry.model import SweepPrimitive
from sweepedit.geometry.slices import (
    GRID,
    INSET,
    MAX_RING_POINTS,
    RAYS,
    REFINE_TOLERANCE,
    SLICES,
    STUB_AXIS_SHARE,
    STUB_LENGTH,
    ParallelPlanes,
    _brackets,
    _centroids,
    _deepest,
    _grid_brackets,
    _one_region_each,
    _ray_radii,
    _refined,
    _straying_share,
    caps_pencil,
    end_stubs,
    quarter_turns,
    ring_candidates,
    rings_on_caps,
    slice_rings,
    slicing_families,
    slicing_frame,
    surface_samples,
)

# A straight round rod along x: length 0.6 (x in [-0.3, 0.3]), radius 0.1, no scaling.
ROD = SweepPrimitive([[-0.3, 0.0, 0.0], [0.0, 0.0, 0.0], [0.3, 0.0, 0.0]], a=0.1, b=0.1,
                     degree=2.0)


def test_slices_across_a_rod_are_its_circles() -> None:
    sliced = slice_rings(ROD, ParallelPlanes(np.array([1.0, 0.0, 0.0])))
    assert sliced is not None
    assert sliced.rings.shape == (SLICES, RAYS, 3)
    # The slices span the rod end to end, inset by INSET of its length at each end.
    x = sliced.rings[..., 0]
    assert np.allclose(x, x[:, :1])
    assert np.allclose(x[:, 0], -0.3 + 0.6 * sliced.u, atol=1e-12)
    assert np.isclose(x[0, 0], -0.3 + 0.6 * INSET, rtol=0.0, atol=1e-12)
    radius = np.hypot(sliced.rings[..., 1], sliced.rings[..., 2])
    assert np.abs(radius - 0.1).max() < 1e-4
    # Counter-clockwise about the direction, from angle 0 on.
    rows = slicing_frame(np.array([1.0, 0.0, 0.0]))
    across = (sliced.rings[0] - sliced.rings[0].mean(axis=0)) @ rows[1:].T
    turn = np.unwrap(np.arctan2(across[:, 1], across[:, 0]))
    assert np.all(np.diff(turn) > 0)


def test_slices_along_a_rod_are_its_rectangles() -> None:
    # Planes y = c cut the rod in rectangles |x| <= 0.3, |z| <= sqrt(0.01 - c^2).
    sliced = slice_rings(ROD, ParallelPlanes(np.array([0.0, 1.0, 0.0])))
    assert sliced is not None
    c = sliced.rings[:, :1, 1]
    assert np.allclose(sliced.rings[..., 1], c)
    half = np.sqrt(0.01 - c**2)
    x, z = sliced.rings[..., 0], sliced.rings[..., 2]
    on_side = np.abs(np.abs(z) - half) < 1e-4 * 0.6
    on_cap = np.abs(np.abs(x) - 0.3) < 1e-4 * 0.6
    assert np.all(on_side | on_cap)
    assert np.all(np.abs(x) <= 0.3 + 1e-6) and np.all(np.abs(z) <= half + 1e-6)


def test_a_slice_of_two_regions_is_refused() -> None:
    # A U: planes across its arms (y = c for the arms along y) meet it twice.
    u_bend = SweepPrimitive([[-0.2, -0.3, 0.0], [0.0, 0.5, 0.0], [0.2, -0.3, 0.0]], a=0.04,
                            b=0.04, degree=2.0)
    assert slice_rings(u_bend, ParallelPlanes(np.array([0.0, 1.0, 0.0]))) is None
    assert slice_rings(u_bend, ParallelPlanes(np.array([1.0, 0.0, 0.0]))) is not None


# A bend that does not fold: one Bezier segment from (0.3, 0, 0) up +y to (0, 0.3, 0)
# along -x. Its caps lie in the planes y = 0 and x = 0, which meet on the z axis.
BEND = SweepPrimitive([[0.3, 0.0, 0.0], [0.3, 0.3, 0.0], [0.0, 0.3, 0.0]], a=0.05, b=0.04,
                      degree=2.5)


def test_the_caps_pencil_turns_about_the_line_where_the_caps_planes_meet() -> None:
    surface = surface_samples(BEND)
    pencil = caps_pencil(BEND, surface)
    assert pencil is not None
    assert np.allclose(np.abs(pencil.rows[0]), [0.0, 0.0, 1.0], atol=1e-12)
    assert np.allclose(pencil.origin[:2], 0.0, atol=1e-12)
    # local coordinates: the half-plane's angle, the position along the line, the distance
    rng = np.random.default_rng(0)
    points = rng.uniform(-0.5, 0.5, (200, 3))
    local = pencil.to_local(points)
    assert np.allclose(local[:, 1], points @ pencil.rows[0])
    assert np.allclose(local[:, 2], np.hypot(points[:, 0], points[:, 1]))
    assert np.allclose(pencil.to_world(local), points, atol=1e-12)
    # each cap's rim lies in one half-plane, a quarter turn apart
    angle = pencil.to_local(surface.reshape(257, 128, 3)[[0, -1]])[..., 0]
    assert np.ptp(angle, axis=1).max() < 1e-9
    assert abs(angle[1, 0] - angle[0, 0]) == pytest.approx(np.pi / 2, abs=1e-9)
    # straight: the caps are parallel, there is no such line
    assert caps_pencil(ROD, surface_samples(ROD)) is None


def test_end_stubs_go_on_straight_past_the_caps_of_a_rod() -> None:
    # A rod of radius 0.1 along x from -0.3 to 0.3 whose scale grows as f = 1 + 0.5 t:
    # past x = 0.3 its sections go on growing at df/dx = 0.5 / 0.6, past x = -0.3 they
    # shrink at that rate.
    rod = SweepPrimitive(ROD.control_points, a=0.1, b=0.1, degree=2.0, scaling=(0.5,))
    stubs = end_stubs(rod, surface_samples(rod))
    assert len(stubs) == 2
    start, end = stubs
    length = min(STUB_LENGTH * 0.1, STUB_AXIS_SHARE * 0.6)
    assert np.allclose(start.centre, [-0.3, 0, 0]) and np.allclose(start.tangent, [-1, 0, 0])
    assert np.allclose(end.centre, [0.3, 0, 0]) and np.allclose(end.tangent, [1, 0, 0])
    assert start.length == pytest.approx(length) and end.length == pytest.approx(1.5 * length)
    assert start.scale == pytest.approx(1.0) and end.scale == pytest.approx(1.5)
    assert end.slope == pytest.approx(0.5 / 0.6, rel=1e-5)
    assert start.slope == pytest.approx(-0.5 / 0.6, rel=1e-5)
    # inside: within the grown circle and the stub's length, and nowhere behind the cap
    z = 0.5 * end.length
    radius = 0.1 * (1.5 + end.slope * z)
    points = np.array([[0.3 + z, 0.99 * radius, 0.0], [0.3 + z, 0.0, 1.01 * radius],
                       [0.3 + 1.01 * end.length, 0.0, 0.0], [0.29, 0.0, 0.0]])
    assert end.inside(points).tolist() == [True, False, False, False]
    # its side surface starts on the cap's rim and lies on the grown circles
    ring = end.surface().reshape(-1, 128, 3)
    assert np.allclose(ring[0, :, 0], 0.3)
    assert np.allclose(np.hypot(ring[..., 1], ring[..., 2]),
                       0.1 * (1.5 + end.slope * (ring[..., 0] - 0.3)))


def test_no_stub_where_the_solid_itself_lies_past_a_cap() -> None:
    # A hook: out along +x, up, and back along -x, its end cap facing its own first arm
    # (which lies within reach past that cap); past the first cap there is nothing.
    hook = SweepPrimitive([[0.0, 0.0, 0.0], [0.6, 0.0, 0.0], [0.6, 0.2, 0.0],
                           [0.1, 0.2, 0.0]], a=0.12, b=0.12, degree=2.0)
    stubs = end_stubs(hook, surface_samples(hook))
    assert len(stubs) == 1
    assert np.allclose(stubs[0].centre, 0.0) and np.allclose(stubs[0].tangent, [-1, 0, 0])


def test_rings_moved_onto_the_caps_planes_end_on_the_rods_rims() -> None:
    # Slanted planes cut the rod's caps obliquely; sliced with its stubs, the rings moved
    # onto the caps' planes begin and end on the rims (x = -0.3 and 0.3, radius 0.1) and
    # keep to the rod's surface in between.
    stubs = end_stubs(ROD, surface_samples(ROD))
    direction = np.array([1.0, 0.6, 0.0]) / np.hypot(1.0, 0.6)
    sliced = slice_rings(ROD, ParallelPlanes(direction), stubs=stubs)
    assert sliced is not None
    capped = rings_on_caps(sliced, stubs)
    assert capped is not None
    assert capped.rings.shape == sliced.rings.shape
    assert np.abs(capped.rings[0, :, 0] + 0.3).max() < 1e-12
    assert np.abs(capped.rings[-1, :, 0] - 0.3).max() < 1e-12
    radius = np.hypot(capped.rings[..., 1], capped.rings[..., 2])
    assert np.abs(radius - 0.1).max() < 2e-3
    assert np.abs(radius[[0, -1]] - 0.1).max() < 2e-3
    # Planes along the rod cut both stubs in every slice: not cut back, refused.
    along = slice_rings(ROD, ParallelPlanes(np.array([0.0, 1.0, 0.0])), stubs=stubs)
    assert along is not None and rings_on_caps(along, stubs) is None


def _disk_slices(radius: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Three slices across the rod (x = -0.2, 0, 0.2), each a window [-0.15, 0.15]^2 of
    GRID lines, and the occupancy of a disk of `radius` about the axis at its nodes
    -> s (3,), g1, g2 (3, GRID), occupied (3, GRID, GRID)."""
    s = np.array([-0.2, 0.0, 0.2])
    lines = np.broadcast_to(np.linspace(-0.15, 0.15, GRID), (3, GRID))
    occupied = np.broadcast_to(np.hypot(lines[0][:, None], lines[0][None, :]) <= radius,
                               (3, GRID, GRID))
    return s, lines, lines, occupied


def test_the_grid_refined_from_every_other_line_is_the_exact_one() -> None:
    # Nodes off the coarse grid are taken from their cell's corners where those agree,
    # and left open (to be tested exactly) only near the boundary.
    _, g1, g2, exact = _disk_slices(0.1)
    occupied, open_ = _refined(exact[:, ::2, ::2])
    assert np.array_equal(occupied[~open_], exact[~open_])
    assert np.array_equal(occupied[:, ::2, ::2], exact[:, ::2, ::2])
    assert not open_[:, ::2, ::2].any()
    assert 0 < open_.sum() < 0.3 * open_.size
    # Every node the boundary passes between is open or on the coarse grid.
    near = np.abs(np.hypot(g1[0][:, None], g2[0][None, :]) - 0.1) < 0.5 * (g1[0, 1] - g1[0, 0])
    assert (open_[0] | (np.add.outer(np.arange(GRID) % 2, np.arange(GRID) % 2) == 0))[near].all()


def test_ray_radii_from_the_grid_and_from_the_exact_march_where_the_grid_misleads() -> None:
    angles = np.linspace(0.0, 2.0 * np.pi, RAYS, endpoint=False)
    directions = np.stack([np.cos(angles), np.sin(angles)], axis=-1)
    planes = ParallelPlanes(np.array([1.0, 0.0, 0.0]))
    centres = np.zeros((3, 2))
    for grid_radius in (0.1, 0.06):  # the rod's own disk; one a cell-width too small
        s, g1, g2, occupied = _disk_slices(grid_radius)
        lo, hi, ok = _grid_brackets((occupied, g1, g2), centres, directions)
        assert ok.all() and (lo < hi).all()
        bracket = _brackets(ROD, planes, s, centres, directions, (occupied, g1, g2), 0.3)
        assert bracket is not None
        assert (bracket[0] < 0.1).all() and (bracket[1] > 0.1).all()
        radii = _ray_radii(ROD, planes, s, centres, directions, bracket)
        assert np.abs(radii - 0.1).max() < 1e-6
    # An annulus is not star-shaped about its centre, on the grid or exactly.
    s, g1, g2, occupied = _disk_slices(0.1)
    ring = occupied & ~_disk_slices(0.04)[3]
    assert not _grid_brackets((ring, g1, g2), centres + 0.07, directions)[2].all()


def test_one_region_each_centroids_and_deepest_points_of_known_slices() -> None:
    _, g1, g2, disk = _disk_slices(0.1)
    assert _one_region_each(disk)
    two = disk.copy()
    two[1, :, GRID // 2] = False  # the middle slice cut in two
    assert not _one_region_each(two)
    holed = disk & ~_disk_slices(0.03)[3]
    assert not _one_region_each(holed)
    # A disk off the axis: its centroid and deepest node are its centre.
    shifted = np.hypot(g1[0][:, None] - 0.05, g2[0][None, :] + 0.02) <= 0.08
    occupied = np.broadcast_to(shifted, (3, GRID, GRID))
    assert np.abs(_centroids(occupied, g1, g2) - [0.05, -0.02]).max() < 1e-3
    cell = g1[0, 1] - g1[0, 0]
    assert np.abs(_deepest(occupied, g1, g2) - [0.05, -0.02]).max() <= cell


def test_quarter_turns_are_the_patches_seams_among_rays_added_anywhere() -> None:
    angles = np.linspace(0.0, 2.0 * np.pi, RAYS, endpoint=False)
    assert quarter_turns(angles) == [(0, 12), (12, 24), (24, 36), (36, 48)]
    # Rays added halfway after rays 3, 11 and 47: each seam moves by the rays before it.
    added = np.sort(np.concatenate([angles, (angles[[3, 11, 47]] + np.pi / RAYS)]))
    seams = quarter_turns(added)
    assert seams == [(0, 14), (14, 26), (26, 38), (38, 51)]
    assert np.allclose(added[[first for first, _ in seams]], np.arange(4) * np.pi / 2.0)


# elephant.json's 6th primitive of a K = 8 fit: it folds sharply just after t = 0 (its
# first control points almost double back), and a loft through evenly spaced slices and
# rays rounds off the crease (46 of its 64^3 cells wrong; 16 refined).
CREASED = SweepPrimitive([[0.14042526483535767, 0.0216330885887146, 0.012282729148864746],
                          [0.10584115982055664, 0.0033708810806274414, 0.0016536116600036621],
                          [0.33777862787246704, 0.20355159044265747, 0.21037817001342773]],
                         a=0.10559287667274475, b=0.15146180987358093,
                         degree=1.8577744960784912,
                         scaling=(-0.49931469559669495, -0.4349518120288849))


def _loft_off_boundary(primitive: SweepPrimitive, sliced, distance: float) -> int:
    """How many points of the loft through `sliced` (its B-spline patches, as STEP export
    builds them, on a 200 x 96 grid of their parameters, the ends left out) lie further
    than `distance` from the solid's boundary along the loft's own normal, by the exact
    inside test on both sides."""
    from scipy.interpolate import BSpline

    from sweepedit.geometry.loft import ring_loft

    loft = ring_loft(sliced.rings, sliced.u, sliced.angles)
    t_knots, patches = loft.t_knots, loft.patches
    t = np.linspace(t_knots[0], t_knots[-1], 200)
    sheets = []
    for v_knots, poles in patches:
        across = BSpline(t_knots, poles, 3)(t)  # (200, Nv, 3)
        v = np.linspace(v_knots[0], v_knots[-1], 24)
        sheets.append(np.stack([BSpline(v_knots, row, 3)(v) for row in across]))
    grid = np.concatenate(sheets, axis=1)  # (200, 96, 3)
    normal = np.cross(np.gradient(grid, axis=0), np.gradient(grid, axis=1))
    normal /= np.linalg.norm(normal, axis=2, keepdims=True)
    outward = np.sign(np.sum(normal * (grid - grid.mean(axis=1, keepdims=True)), axis=2))
    normal *= outward[..., None]
    points, normal = grid[1:-1].reshape(-1, 3), normal[1:-1].reshape(-1, 3)
    missed = ~inside_union(points - distance * normal, [primitive])
    excess = inside_union(points + distance * normal, [primitive])
    return int(np.count_nonzero(missed | excess))


def test_rays_and_slices_added_where_the_loft_strays_bring_it_onto_the_crease() -> None:
    surface = surface_samples(CREASED)
    size = float(np.linalg.norm(np.ptp(surface, axis=0)))
    planes = next(family for family in slicing_families(CREASED, surface)
                  if next(ring_candidates(CREASED, family, surface), None) is not None)
    # The first centre's refined rings come first, then its plain ones.
    refined, base = list(ring_candidates(CREASED, planes, surface))[:2]
    assert base.rings.shape == (SLICES, RAYS, 3)
    S, P = refined.rings.shape[:2]
    assert S > SLICES and P > RAYS and S * P <= MAX_RING_POINTS
    # The plain rings are among the refined ones, which stay in order.
    assert np.all(np.diff(refined.u) > 0) and np.all(np.diff(refined.angles) > 0)
    assert np.isin(base.u, refined.u).all() and np.isin(base.angles, refined.angles).all()
    kept = np.ix_(np.isin(refined.u, base.u), np.isin(refined.angles, base.angles))
    assert np.array_equal(refined.rings[kept], base.rings)
    # The loft's surface, sampled between its rings and checked by the exact inside
    # test along its own normals, strays from the boundary less than half as often.
    distance = 2.0 * REFINE_TOLERANCE * size
    plain, finer = (_loft_off_boundary(CREASED, c, distance) for c in (base, refined))
    assert plain > 100
    assert 2 * finer < plain


def test_the_straying_share_counts_the_loft_points_off_the_boundary_by_more_than_asked() -> None:
    planes = ParallelPlanes(np.array([1.0, 0.0, 0.0]))
    sliced = slice_rings(ROD, planes)
    assert sliced is not None and sliced.rings.shape == (SLICES, RAYS, 3)
    s = sliced.rings[:, 0, 0]  # the planes x = s, the rod's axis through (0, 0) in each
    centres = np.zeros((SLICES, 2))

    def share(scale: float, tolerance: float) -> float:
        # The rings pushed out radially: the loft's points between them lie about
        # 0.1 (scale - 1) off the rod's side.
        rings = sliced.rings * np.array([1.0, scale, scale])
        return _straying_share(ROD, planes, sliced._replace(rings=rings), s, centres,
                               tolerance)

    assert share(1.0, 1e-4) == 0.0
    # 0.005 outside the side, or inside it: every point strays by more than 0.004, none
    # by more than 0.006.
    for scale in (1.05, 0.95):
        assert share(scale, 4e-3) == 1.0
        assert share(scale, 6e-3) == 0.0
