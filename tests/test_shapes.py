"""Shape loading: formats, normalisation, defects of real files, and bad input."""

from __future__ import annotations

import hashlib
import os
import time
from pathlib import Path

import numpy as np
import pytest
import scipy.ndimage as ndi
import trimesh

from sweepedit.errors import DegenerateShapeError, FileFormatError
from sweepedit.io import occupancy as occ
from sweepedit.io.shapes import load_shape

R = 64
H = 1.0 / R


@pytest.fixture(scope="module")
def offset_box() -> trimesh.Trimesh:
    """A box far from the origin, longest side 6 (along y)."""
    box = trimesh.creation.box(extents=(2.0, 6.0, 3.0))
    box.apply_translation((10.0, -4.0, 7.0))
    return box


def _load(path: Path, **kw):
    kw.setdefault("n_samples", 2000)
    return load_shape(path, **kw)


# --------------------------------------------------------------------------- normalisation


def test_normalisation_centres_and_scales(tmp_path, offset_box):
    path = tmp_path / "box.ply"
    offset_box.export(path)
    shape = _load(path)
    assert shape.kind == "mesh" and shape.path == path
    lo, hi = shape.surface.bounds
    assert np.allclose((lo + hi) / 2, 0.0, atol=1e-9)
    assert np.max(hi - lo) == pytest.approx(1.0)
    assert np.allclose(hi - lo, np.array([2, 6, 3]) / 6.0)
    assert shape.normalization.scale == pytest.approx(6.0)
    assert np.allclose(shape.normalization.center, (10.0, -4.0, 7.0))
    back = shape.normalization.to_original(shape.surface.vertices)
    assert np.allclose(np.sort(back, axis=0)[[0, -1]], offset_box.bounds)
    assert shape.sha256 == hashlib.sha256(path.read_bytes()).hexdigest()
    # Box sides 1/3, 1, 1/2 of the cube.
    assert shape.occupancy.sum() * H**3 == pytest.approx(1 / 6, rel=0.05)


@pytest.mark.parametrize("ext", [".obj", ".ply", ".stl", ".off", ".glb"])
def test_mesh_formats_agree(tmp_path, ext):
    torus = trimesh.creation.torus(major_radius=3.0, minor_radius=1.0)
    path = tmp_path / f"torus{ext}"
    torus.export(path)
    shape = _load(path)
    assert shape.kind == "mesh"
    # Normalised: longest side 8 -> 1, so the tube radius becomes 1/8.
    analytic = 2 * np.pi**2 * (3 / 8) * (1 / 8) ** 2
    assert shape.occupancy.sum() * H**3 == pytest.approx(analytic, rel=0.04)
    assert shape.surface_samples(500).shape == (500, 3)


def test_gltf_with_embedded_buffers_and_scene_transforms(tmp_path):
    a = trimesh.creation.box(extents=(1, 1, 1))
    scene = trimesh.Scene()
    scene.add_geometry(a, node_name="a")
    scene.add_geometry(a, node_name="b", transform=trimesh.transformations.translation_matrix(
        (3.0, 0.0, 0.0)))
    files = trimesh.exchange.gltf.export_gltf(scene, embed_buffers=True)
    path = tmp_path / "two.gltf"
    path.write_bytes(files["model.gltf"])
    shape = _load(path)
    lo, hi = shape.surface.bounds
    assert np.allclose(hi - lo, [1.0, 0.25, 0.25])  # both boxes, 4 long in x
    assert ndi.label(shape.occupancy, np.ones((3, 3, 3)))[1] == 2
    assert shape.n_components == 2


def test_obj_split_at_texture_seams_is_merged(tmp_path):
    sphere = trimesh.creation.icosphere(subdivisions=3)
    # Every face with its own three vertices (the worst case of seam splitting), with UVs.
    v = sphere.vertices[sphere.faces].reshape(-1, 3)
    lines = [f"v {x:.9f} {y:.9f} {z:.9f}" for x, y, z in v]
    lines += [f"vt {u:.3f} {w:.3f}" for u, w in np.random.default_rng(0).random((len(v), 2))]
    lines += [f"f {3*i+1}/{3*i+1} {3*i+2}/{3*i+2} {3*i+3}/{3*i+3}"
              for i in range(len(sphere.faces))]
    path = tmp_path / "split.obj"
    path.write_text("\n".join(lines) + "\n")
    shape = _load(path)
    assert len(shape.surface.vertices) == len(sphere.vertices)
    assert shape.surface.is_watertight
    assert shape.occupancy.sum() * H**3 == pytest.approx(np.pi / 6, rel=0.03)


def test_inside_out_mesh_is_turned_outward(tmp_path):
    sphere = trimesh.creation.icosphere(subdivisions=3)
    sphere.invert()
    path = tmp_path / "inverted.stl"
    sphere.export(path)
    shape = _load(path)
    assert shape.surface.volume > 0
    assert shape.occupancy.sum() * H**3 == pytest.approx(np.pi / 6, rel=0.03)


def test_mixed_face_orientations_are_made_consistent(tmp_path):
    """A torus with the faces of one side flipped (as scans and exports can come): the
    winding number of the mixed faces cancels inside, so the faces are turned to agree
    first; the occupancy is then the consistent torus's, whose volume is 2 pi^2 R r^2."""
    torus = trimesh.creation.torus(major_radius=0.3, minor_radius=0.1, major_sections=48,
                                   minor_sections=24)
    faces = torus.faces.copy()
    side = torus.triangles_center[:, 0] > 0.0
    faces[side] = faces[side][:, ::-1]
    mixed = trimesh.Trimesh(torus.vertices, faces, process=False)
    assert not mixed.is_winding_consistent
    mixed.export(tmp_path / "mixed.ply")
    torus.export(tmp_path / "torus.ply")
    shape, reference = _load(tmp_path / "mixed.ply"), _load(tmp_path / "torus.ply")
    assert shape.surface.is_winding_consistent
    np.testing.assert_array_equal(shape.winding_occupancy, reference.winding_occupancy)
    volume = shape.winding_occupancy.sum() * (shape.normalization.scale / 64) ** 3
    assert volume == pytest.approx(2 * np.pi**2 * 0.3 * 0.1**2, rel=0.05)


def test_surface_samples_are_area_uniform_and_seeded(tmp_path):
    box = trimesh.creation.box(extents=(1.0, 1.0, 0.1))
    path = tmp_path / "plate.off"
    box.export(path)
    shape = _load(path)
    a = shape.surface_samples(20_000, seed=3)
    assert np.array_equal(a, shape.surface_samples(20_000, seed=3))
    assert not np.array_equal(a, shape.surface_samples(20_000, seed=4))
    # The two big faces hold 2 / (2 + 4 * 0.1) of the area.
    on_big = np.isclose(np.abs(a[:, 2]), 0.05, atol=1e-9)
    assert on_big.mean() == pytest.approx(2 / 2.4, abs=0.02)


# --------------------------------------------------------------------------- voxels


def _l_shape(n: int = 40) -> np.ndarray:
    grid = np.zeros((n, n, n), dtype=bool)
    grid[5:15, 2:22, 0:40] = True  # 10 x 20 x 40 voxels
    return grid


def test_npy_npz_and_binvox_voxels(tmp_path):
    grid = _l_shape()
    np.save(tmp_path / "g.npy", grid)
    np.save(tmp_path / "g_int.npy", grid.astype(np.uint8) * 255)
    np.savez(tmp_path / "g.npz", occupancy=grid.astype(np.float32))
    vox = trimesh.voxel.VoxelGrid(grid)
    (tmp_path / "g.binvox").write_bytes(trimesh.exchange.binvox.export_binvox(vox))
    for name in ("g.npy", "g_int.npy", "g.npz", "g.binvox"):
        shape = _load(tmp_path / name)
        assert shape.kind == "voxels"
        lo, hi = shape.surface.bounds
        assert np.allclose(hi - lo, [0.25, 0.5, 1.0], atol=1e-6), name
        # 10 x 20 x 40 voxels of side 1/40: a 0.25 x 0.5 x 1 box.
        assert shape.occupancy.sum() * H**3 == pytest.approx(0.125, rel=0.03), name


def test_voxel_grid_spanning_the_cube_comes_back_unchanged(tmp_path):
    rng = np.random.default_rng(0)
    grid = ndi.gaussian_filter(rng.random((R, R, R)), 4) > 0.5
    for i in (0, R - 1):  # touch every side, so normalising is the identity on cells
        grid[i, 30, 30] = grid[30, i, 30] = grid[30, 30, i] = True
    np.save(tmp_path / "blob.npy", grid)
    shape = _load(tmp_path / "blob.npy")
    assert np.array_equal(shape.winding_occupancy, grid)
    assert np.array_equal(shape.occupancy, grid)


def test_voxels_of_other_resolution_and_single_voxel(tmp_path):
    grid = np.zeros((7, 9, 5), dtype=bool)
    grid[3, 4, 2] = True
    np.save(tmp_path / "one.npy", grid)
    shape = _load(tmp_path / "one.npy")
    assert shape.occupancy.any()
    big = np.zeros((300, 300, 300), dtype=bool)
    big[100:200, 120:180, 140:160] = True
    np.save(tmp_path / "big.npy", big)
    shape = _load(tmp_path / "big.npy")
    lo, hi = shape.surface.bounds
    assert np.allclose(hi - lo, [1.0, 0.6, 0.2], atol=0.02)


# --------------------------------------------------------------------------- point clouds


def _sphere_cloud(n: int = 20_000, seed: int = 0) -> np.ndarray:
    d = np.random.default_rng(seed).normal(size=(n, 3))
    return 2.0 * d / np.linalg.norm(d, axis=1, keepdims=True) + 5.0


def test_point_cloud_formats(tmp_path):
    points = _sphere_cloud()
    trimesh.PointCloud(points).export(tmp_path / "cloud.ply")
    np.savetxt(tmp_path / "cloud.xyz", np.hstack([points, np.ones_like(points)]))
    (tmp_path / "cloud.pts").write_text(
        f"{len(points)}\n" + "\n".join(f"{x} {y} {z} 10 1 2 3" for x, y, z in points))
    for name in ("cloud.ply", "cloud.xyz", "cloud.pts"):
        shape = _load(tmp_path / name)
        assert shape.kind == "points" and shape.cloud is not None
        assert shape.cloud.shape == (len(points), 3)
        assert shape.occupancy.sum() * H**3 == pytest.approx(np.pi / 6, rel=0.04), name
        s = shape.surface_samples(1000)
        # The samples are input points (on a sphere of radius ~0.5 after normalising).
        assert np.allclose(np.linalg.norm(s, axis=1), 0.5, atol=1e-3)


# --------------------------------------------------------------------------- bad input


def _bad_inputs(tmp: Path) -> dict[str, Path]:
    cases: dict[str, Path] = {}
    cases["missing"] = tmp / "nope.obj"
    (tmp / "empty.stl").write_bytes(b"")
    cases["empty"] = tmp / "empty.stl"
    (tmp / "shape.xyz3").write_text("1 2 3\n")
    cases["unknown extension"] = tmp / "shape.xyz3"
    good = tmp / "good.ply"
    trimesh.creation.icosphere(subdivisions=3).export(good)
    (tmp / "cut.ply").write_bytes(good.read_bytes()[: len(good.read_bytes()) // 2])
    cases["truncated ply"] = tmp / "cut.ply"
    stl = tmp / "good.stl"
    trimesh.creation.icosphere(subdivisions=3).export(stl)
    (tmp / "cut.stl").write_bytes(stl.read_bytes()[:500])
    cases["truncated stl"] = tmp / "cut.stl"
    (tmp / "verts.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\n")
    cases["obj without faces"] = tmp / "verts.obj"
    (tmp / "nofaces.off").write_text("OFF\n4 0 0\n0 0 0\n1 0 0\n0 1 0\n0 0 1\n")
    cases["off without faces"] = tmp / "nofaces.off"
    (tmp / "garbage.obj").write_bytes(os.urandom(2000))
    cases["garbage obj"] = tmp / "garbage.obj"
    (tmp / "garbage.glb").write_bytes(b"glTF" + os.urandom(200))
    cases["garbage glb"] = tmp / "garbage.glb"
    np.save(tmp / "empty.npy", np.zeros((16, 16, 16), dtype=bool))
    cases["all-empty voxels"] = tmp / "empty.npy"
    np.save(tmp / "flat.npy", np.ones((16, 16), dtype=bool))
    cases["2d array"] = tmp / "flat.npy"
    (tmp / "bad.npz").write_bytes(b"PK\x03\x04 not really a zip")
    cases["broken npz"] = tmp / "bad.npz"
    (tmp / "cut.binvox").write_bytes(b"#binvox 1\ndim 8 8 8\ntranslate 0 0 0\nscale 1\ndata\n"
                                     b"\x01\x10")
    cases["truncated binvox"] = tmp / "cut.binvox"
    (tmp / "nan.xyz").write_text("0 0 0\n1 0 0\n0 1 0\nnan 0 1\n0 0 1\n")
    cases["nan in cloud"] = tmp / "nan.xyz"
    (tmp / "text.xyz").write_text("0 0 0\n1 zero 0\n")
    cases["non-numeric cloud"] = tmp / "text.xyz"
    (tmp / "nan.ply").write_text("ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\n"
                                 "property float y\nproperty float z\nend_header\n"
                                 "0 0 0\n1 0 0\nnan 1 0\n0 0 1\n")
    cases["nan in ply cloud"] = tmp / "nan.ply"
    (tmp / "point.off").write_text("OFF\n3 1 0\n0 0 0\n0 0 0\n0 0 0\n3 0 1 2\n")
    cases["degenerate mesh"] = tmp / "point.off"
    (tmp / "badidx.off").write_text("OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 7\n")
    cases["face index out of range"] = tmp / "badidx.off"
    (tmp / "folder.obj").mkdir()
    cases["a directory"] = tmp / "folder.obj"
    return cases


def test_bad_inputs_raise_file_format_error(tmp_path):
    for what, path in _bad_inputs(tmp_path).items():
        with pytest.raises(FileFormatError) as info:
            load_shape(path, n_samples=100)
        assert info.value.path == str(path), what
        assert str(path) in str(info.value), what
        assert isinstance(info.value, ValueError)


def test_ply_without_faces_is_a_point_cloud_not_an_error(tmp_path):
    path = tmp_path / "cloud.ply"
    trimesh.PointCloud(_sphere_cloud(3000)).export(path)
    assert _load(path).kind == "points"


# --------------------------------------------------------------------------- shared shapes


def test_horse_is_inside_out_but_solid(shapes_dir):
    raw = trimesh.load(shapes_dir / "horse.ply", process=False)
    assert raw.volume < 0  # the file is inside-out
    shape = _load(shapes_dir / "horse.ply")
    expected = -raw.volume / np.max(raw.extents) ** 3
    fraction = shape.occupancy.mean()
    assert fraction == pytest.approx(expected, rel=0.05) and fraction > 0.03
    assert shape.surface.volume > 0
    assert ndi.label(shape.occupancy, np.ones((3, 3, 3)))[1] == 1


@pytest.mark.parametrize("name", ["cat.obj", "bike_frame.stl", "hammer.obj", "ant.ply"])
def test_shared_shapes_with_defects(shapes_dir, name):
    """Seams (cat), thin parts (bike_frame, hammer), many components (ant)."""
    shape = _load(shapes_dir / name, n_samples=500)
    raw = trimesh.load(shapes_dir / name)
    lo, hi = shape.surface.bounds
    assert np.max(hi - lo) == pytest.approx(1.0) and np.allclose(lo + hi, 0.0, atol=1e-9)
    # Volume of the grid ~ the mesh's own volume (normalised) for these closed meshes; tubes
    # about one cell thick alias with the grid (bike_frame: -9% to +15% as the grid shifts).
    expected = abs(raw.volume) / np.max(raw.extents) ** 3
    assert shape.winding_occupancy.mean() == pytest.approx(expected, rel=0.2)
    assert shape.occupancy.sum() >= shape.winding_occupancy.sum()
    # The fitting grid is as connected as the surface cells say.
    n = ndi.label(shape.occupancy, np.ones((3, 3, 3)))[1]
    assert n <= ndi.label(shape.winding_occupancy, np.ones((3, 3, 3)))[1]
    assert n == (5 if name == "ant.ply" else 1)


@pytest.mark.slow
@pytest.mark.skipif(not os.environ.get("SWEEPEDIT_SLOW"),
                    reason="set SWEEPEDIT_SLOW=1 to load a 1.3M-face mesh")
def test_million_face_mesh_loads_in_seconds(tmp_path):
    mesh = trimesh.creation.icosphere(subdivisions=8)
    path = tmp_path / "ico8.ply"
    mesh.export(path)
    start = time.perf_counter()
    shape = load_shape(path)
    elapsed = time.perf_counter() - start
    assert shape.occupancy.sum() * H**3 == pytest.approx(np.pi / 6, rel=0.02)
    assert elapsed < 15.0


def test_a_few_points_in_a_plane_are_refused(tmp_path):
    # Issue 18: fewer than 10 points, or points in one plane, enclose nothing to fit.
    path = tmp_path / "flat.xyz"
    path.write_text("0 0 0\n1 0 0\n0 1 0\n1 1 0\n0.5 0.5 0\n")
    with pytest.raises(DegenerateShapeError, match="too few"):
        _load(path)
    path.write_text("".join(f"{x} {y} 0\n" for x in range(4) for y in range(4)))
    with pytest.raises(DegenerateShapeError, match="one plane"):
        _load(path)


def test_grid_surface_keeps_a_sparse_shell_of_cells():
    # Where blurring would take every cell below the level (a sparse shell of single
    # cells), the display surface keeps the cells instead of blurring them away.
    grid = np.zeros((8, 8, 8), dtype=bool)
    grid[[1, 6, 1, 6, 3], [1, 1, 6, 6, 3], 4] = True
    surface = occ.grid_surface(grid, np.full(3, -0.5), np.full(3, 0.5), smooth=0.7)
    assert len(surface.faces) > 0 and surface.is_watertight
    assert len(trimesh.graph.connected_components(surface.face_adjacency)) == 5


def test_obj_relative_face_indices_count_back_from_the_face(tmp_path) -> None:
    """OBJ's -1 is the last vertex defined before the face (trimesh counts from the end
    of the file): a cube and a small box written with relative indices load as the same
    mesh as with absolute ones; an index reaching before the first vertex is refused."""
    import trimesh

    from sweepedit.errors import FileFormatError
    from sweepedit.io.shapes import load_shape

    cube = trimesh.creation.box(extents=(1.0, 1.0, 1.0))
    small = trimesh.creation.box(extents=(0.2, 0.2, 0.2))
    small.apply_translation((2.0, 0.0, 0.0))
    relative, absolute, seen = [], [], 0
    for mesh in (cube, small):
        block = [f"v {x:.6f} {y:.6f} {z:.6f}" for x, y, z in mesh.vertices]
        relative += block + [f"f {a - 8} {b - 8} {c - 8}" for a, b, c in mesh.faces]
        absolute += block + [f"f {a + seen + 1} {b + seen + 1} {c + seen + 1}"
                             for a, b, c in mesh.faces]
        seen += len(mesh.vertices)
    paths = {}
    for name, lines in (("relative", relative), ("absolute", absolute)):
        paths[name] = tmp_path / f"{name}.obj"
        paths[name].write_text("\n".join(lines) + "\n")
    got, want = (load_shape(paths[n], resolution=16, n_samples=100) for n in paths)
    assert len(got.surface.vertices) == len(want.surface.vertices) == 16
    np.testing.assert_allclose(got.surface.vertices, want.surface.vertices)
    np.testing.assert_array_equal(got.surface.faces, want.surface.faces)
    assert got.surface.volume == pytest.approx((1.0 + 0.008) / 2.6**3, rel=1e-6)  # normalised

    bad = tmp_path / "bad.obj"
    bad.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf -1 -2 -4\n")
    with pytest.raises(FileFormatError, match=r"bad\.obj.*line 4"):
        load_shape(bad, resolution=16, n_samples=100)


def test_misleading_files_get_messages_that_name_their_fault(tmp_path) -> None:
    """Coordinates whose span overflows, a binary STL whose count is too small (its
    triangles are read) or too large, voxels stored as Python objects, a truncated PLY:
    each a FileFormatError that says what is wrong, not what it led to."""
    import struct

    import trimesh

    from sweepedit.errors import FileFormatError
    from sweepedit.io.shapes import load_shape

    box = trimesh.creation.box(extents=(1.0, 2.0, 3.0))
    huge = tmp_path / "huge.off"
    lines = ["OFF", f"{len(box.vertices)} {len(box.faces)} 0"]
    lines += [" ".join(f"{1e308 * np.sign(c):.6g}" for c in v) for v in box.vertices]
    lines += [f"3 {a} {b} {c}" for a, b, c in box.faces]
    huge.write_text("\n".join(lines) + "\n")
    stl = box.export(file_type="stl")
    assert len(stl) == 84 + 50 * 12
    small = tmp_path / "small_count.stl"
    small.write_bytes(stl[:80] + struct.pack("<I", 5) + stl[84:])
    large = tmp_path / "large_count.stl"
    large.write_bytes(stl[:80] + struct.pack("<I", 99) + stl[84:])
    objects = tmp_path / "objects.npz"
    np.savez(objects, occupancy=np.array([np.zeros(3), "x"], dtype=object))
    ply = box.export(file_type="ply")
    truncated = tmp_path / "truncated.ply"
    truncated.write_bytes(ply[:-50])
    expected = {huge: "size overflows", large: "claims 99 triangles",
                objects: "holds Python objects", truncated: "ends before the data"}
    for path, words in expected.items():
        with pytest.raises(FileFormatError, match=words) as info:
            load_shape(path, resolution=16, n_samples=100)
        assert path.name in str(info.value)
    read = load_shape(small, resolution=16, n_samples=100)
    assert len(read.surface.faces) == 12
    assert read.surface.volume == pytest.approx(6.0 / 27.0, rel=1e-6)  # longest side 3 -> 1
