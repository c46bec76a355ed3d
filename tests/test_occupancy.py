"""Voxelisation, inside tests and fitting samples against analytic solids."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.ndimage as ndi
import trimesh

from sweepedit.io import occupancy as occ

R = 64
H = 1.0 / R
CENTERS = occ.cell_centers(R)


def _torus(major: float = 0.3, minor: float = 0.1) -> trimesh.Trimesh:
    return trimesh.creation.torus(major_radius=major, minor_radius=minor,
                                  major_sections=96, minor_sections=48)


def _torus_inside(p: np.ndarray, major: float = 0.3, minor: float = 0.1) -> np.ndarray:
    ring = np.hypot(p[:, 0], p[:, 1]) - major
    return ring**2 + p[:, 2] ** 2 < minor**2


@pytest.fixture(scope="module")
def sphere() -> trimesh.Trimesh:
    return trimesh.creation.icosphere(subdivisions=5, radius=0.45)


@pytest.fixture(scope="module")
def sphere_voxels(sphere):
    return occ.voxelize_mesh(sphere, R, n_samples=20_000, seed=1)


def test_cell_centres_and_indexing():
    c = occ.cell_coordinates(R)
    assert c[0] == pytest.approx(-0.5 + H / 2) and c[-1] == pytest.approx(0.5 - H / 2)
    grid = CENTERS.reshape(R, R, R, 3)
    # [ix, iy, iz] indexing: the x coordinate follows the first index.
    assert grid[5, 0, 0, 0] == pytest.approx(c[5]) and grid[0, 7, 0, 1] == pytest.approx(c[7])
    assert grid[0, 0, 9, 2] == pytest.approx(c[9])
    ijk = occ.point_cells(grid[3, 40, 63][None], R)
    assert ijk.tolist() == [[3, 40, 63]]


def test_sphere_volume_and_cells(sphere_voxels):
    grids, _ = sphere_voxels
    truth = (np.linalg.norm(CENTERS, axis=1) < 0.45).reshape(R, R, R)
    assert grids.occupancy.dtype == bool and grids.occupancy.shape == (R, R, R)
    volume = grids.occupancy.sum() * H**3
    assert volume == pytest.approx(4 / 3 * np.pi * 0.45**3, rel=0.02)
    # Cells that disagree with the analytic ball lie within a facet's sag of its surface.
    assert np.mean(grids.winding_occupancy == truth) > 0.999
    assert not np.any(grids.occupancy & ~grids.winding_occupancy)  # no thin parts here


def test_box_matches_analytic_cells():
    box = trimesh.creation.box(extents=(0.9, 0.53, 0.31))
    box.apply_translation((0.02, -0.1, 0.07))
    grids, _ = occ.voxelize_mesh(box, R, n_samples=1000)
    lo, hi = box.bounds
    centres = CENTERS
    truth = np.all((centres > lo) & (centres < hi), axis=1).reshape(R, R, R)
    assert np.array_equal(grids.winding_occupancy, truth)
    assert grids.occupancy.sum() * H**3 == pytest.approx(0.9 * 0.53 * 0.31, rel=0.05)


def test_torus_volume_and_inside_test():
    torus = _torus()
    grids, _ = occ.voxelize_mesh(torus, R, n_samples=1000)
    analytic = 2 * np.pi**2 * 0.3 * 0.1**2
    assert grids.occupancy.sum() * H**3 == pytest.approx(analytic, rel=0.03)
    q = np.random.default_rng(3).uniform(-0.5, 0.5, size=(20_000, 3))
    agree = occ.mesh_inside(torus, q) == _torus_inside(q)
    assert agree.mean() > 0.995


def test_inside_out_mesh_gives_the_same_grid(sphere, sphere_voxels):
    flipped = sphere.copy()
    flipped.invert()
    grids, _ = occ.voxelize_mesh(flipped, R, n_samples=1000, seed=1)
    assert np.array_equal(grids.occupancy, sphere_voxels[0].occupancy)
    assert np.array_equal(grids.winding_occupancy, sphere_voxels[0].winding_occupancy)
    points = sphere_voxels[1].points
    assert np.array_equal(occ.mesh_inside(flipped, points), sphere_voxels[1].labels > 0.5)


def test_mesh_with_small_hole(sphere, sphere_voxels):
    holed = sphere.copy()
    # Remove the faces around one vertex: a hole about two facets wide.
    faces = np.flatnonzero(~np.any(np.isin(holed.faces, [0, 1]), axis=1))
    holed.update_faces(faces)
    assert not holed.is_watertight
    grids, _ = occ.voxelize_mesh(holed, R, n_samples=1000)
    assert np.mean(grids.winding_occupancy == sphere_voxels[0].winding_occupancy) > 0.9995


def test_samples_counts_labels_and_placement(sphere_voxels):
    _, samples = sphere_voxels
    assert samples.points.shape == (20_000, 3) and samples.points.dtype == np.float32
    assert samples.labels.shape == (20_000,) and samples.labels.dtype == np.float32
    assert set(np.unique(samples.labels)) <= {0.0, 1.0}
    r = np.linalg.norm(samples.points.astype(np.float64), axis=1)
    # Away from the facets' sag (< 1e-4 here) labels match the analytic ball.
    clear = np.abs(r - 0.45) > 5e-4
    assert np.mean((r < 0.45) == (samples.labels > 0.5)) > 0.99
    assert np.mean(((r < 0.45) == (samples.labels > 0.5))[clear]) > 0.9995
    near = np.abs(r[: samples.n_near] - 0.45) <= 2 * H + 1e-3
    assert samples.n_near > len(samples) / 2 and near.all()
    assert np.all(np.abs(samples.points) <= 0.5)


def test_samples_are_reproducible(sphere):
    a = occ.voxelize_mesh(sphere, R, n_samples=500, seed=7)[1]
    b = occ.voxelize_mesh(sphere, R, n_samples=500, seed=7)[1]
    c = occ.voxelize_mesh(sphere, R, n_samples=500, seed=8)[1]
    assert np.array_equal(a.points, b.points) and not np.array_equal(a.points, c.points)


def _dumbbell(rod_radius: float) -> trimesh.Trimesh:
    left = trimesh.creation.icosphere(subdivisions=3, radius=0.12)
    left.apply_translation((-0.3, 0.0, 0.0))
    right = left.copy()
    right.apply_translation((0.6, 0.0, 0.0))
    rod = trimesh.creation.cylinder(radius=rod_radius, segment=[(-0.3, 0.013, 0.021),
                                                               (0.3, 0.013, 0.021)])
    return trimesh.util.concatenate([left, right, rod])


def test_part_thinner_than_a_cell_survives():
    mesh = _dumbbell(rod_radius=0.25 * H)
    grids, _ = occ.voxelize_mesh(mesh, R, n_samples=5000)
    _, n_winding = ndi.label(grids.winding_occupancy, occ.STRUCTURE_26)
    _, n_fit = ndi.label(grids.occupancy, occ.STRUCTURE_26)
    assert n_winding == 2  # the rod holds no cell centre
    assert n_fit == 1  # the fitting grid keeps it, as a line of cells
    # Every x cell column between the balls has rod voxels, and few extras were added.
    ix = np.arange(occ.point_cells(np.array([[-0.17, 0, 0]]), R)[0, 0],
                   occ.point_cells(np.array([[0.17, 0, 0]]), R)[0, 0])
    assert grids.occupancy[ix].any(axis=(1, 2)).all()
    added = grids.occupancy.sum() - grids.winding_occupancy.sum()
    assert added < 4 * len(ix)


def test_dotted_thin_rod_is_reconnected():
    # Radius ~0.6 cells: some cell centres fall inside, the rod comes out dotted.
    mesh = _dumbbell(rod_radius=0.6 * H)
    grids, _ = occ.voxelize_mesh(mesh, R, n_samples=1000)
    assert ndi.label(grids.occupancy, occ.STRUCTURE_26)[1] == 1


def test_separate_parts_stay_separate():
    a = trimesh.creation.box(extents=(0.2, 0.2, 0.2))
    a.apply_translation((-0.3, 0, 0))
    b = a.copy()
    b.apply_translation((0.6, 0, 0))
    grids, _ = occ.voxelize_mesh(trimesh.util.concatenate([a, b]), R, n_samples=1000)
    assert ndi.label(grids.occupancy, occ.STRUCTURE_26)[1] == 2


def test_connect_pieces_joins_through_allowed_cells():
    base = np.zeros((10, 10, 10), dtype=bool)
    base[1, 1, 1] = base[8, 1, 1] = True
    allowed = np.zeros_like(base)
    allowed[1:9, 1, 1] = True
    allowed[1, 1:9, 1] = True  # a detour that must not be taken
    out = occ.connect_pieces(base, allowed)
    assert out[1:9, 1, 1].all() and out.sum() == 8
    # Not connected through `allowed`: nothing added.
    lonely = occ.connect_pieces(base, np.zeros_like(base))
    assert np.array_equal(lonely, base)


def test_point_cloud_inside_sphere():
    rng = np.random.default_rng(0)
    d = rng.normal(size=(20_000, 3))
    points = 0.45 * d / np.linalg.norm(d, axis=1, keepdims=True)
    grids, samples, inside = occ.voxelize_points(points, R, n_samples=5000)
    assert grids.winding_occupancy.sum() * H**3 == pytest.approx(4 / 3 * np.pi * 0.45**3,
                                                                 rel=0.03)
    q = rng.uniform(-0.5, 0.5, size=(20_000, 3))
    assert np.mean(inside(q) == (np.linalg.norm(q, axis=1) < 0.45)) > 0.99
    r = np.linalg.norm(samples.points, axis=1)
    assert np.mean((r < 0.45) == (samples.labels > 0.5)) > 0.97


def test_fast_winding_numbers_match_exact():
    torus = _torus(major=0.3, minor=0.1)
    q = np.random.default_rng(5).uniform(-0.5, 0.5, size=(3000, 3))
    fast = occ.winding_numbers(torus.vertices, torus.faces, q)
    import igl

    exact = igl.winding_number(np.asarray(torus.vertices, dtype=np.float64),
                               np.asarray(torus.faces, dtype=np.int64), q)
    assert np.max(np.abs(fast - exact)) < 0.02
    # Long triangles get split first; the result is unchanged.
    box = trimesh.creation.box(extents=(0.8, 0.8, 0.8))
    w = occ.winding_numbers(box.vertices, box.faces, q)
    assert np.array_equal(np.abs(w) > 0.5, np.all(np.abs(q) < 0.4, axis=1))


def test_winding_numbers_in_chunks_keep_the_query_order(monkeypatch):
    # 5,120 faces with edges under LONG_EDGE, so none is split and chunks are 4 x 5,120
    sphere = trimesh.creation.icosphere(subdivisions=4, radius=0.35)
    q = np.random.default_rng(6).uniform(-0.5, 0.5, size=(100_000, 3))
    whole = occ.winding_numbers(sphere.vertices, sphere.faces, q)
    monkeypatch.setattr(occ, "WINDING_CHUNK_QUERIES", 10)
    assert len(q) > 4 * 4 * len(sphere.faces)  # at least four chunks
    chunked = occ.winding_numbers(sphere.vertices, sphere.faces, q)
    np.testing.assert_array_equal(chunked, whole)
    r = np.linalg.norm(q, axis=1)
    clear = np.abs(r - 0.35) > 0.01  # away from the faceted surface
    assert np.array_equal((chunked > 0.5)[clear], (r < 0.35)[clear])
