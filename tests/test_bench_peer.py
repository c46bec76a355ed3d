"""benchmarks/bench_peer.py: the superquadric inside test, meshes, samples and distance field
that score Marching-Primitives by sweepedit's protocol (no port needed), and one run of
the port where SWEEPEDIT_MP_PATH names it."""

from __future__ import annotations

import importlib.util
import os
import sys
from pathlib import Path

import igl
import numpy as np
import pytest
import trimesh
from scipy.spatial.transform import Rotation
from scipy.special import beta

BENCH = Path(__file__).resolve().parents[1] / "benchmarks" / "bench_peer.py"


@pytest.fixture(scope="module")
def bp():
    spec = importlib.util.spec_from_file_location("bench_peer", BENCH)
    module = importlib.util.module_from_spec(spec)
    sys.modules["bench_peer"] = module
    spec.loader.exec_module(module)
    yield module
    sys.modules.pop("bench_peer", None)


def analytic_volume(e1, e2, a):
    """Volume of a superquadric (Jaklic et al. 2000)."""
    return 2 * a[0] * a[1] * a[2] * e1 * e2 * beta(e1 / 2 + 1, e1) * beta(e2 / 2, e2 / 2)


def params(eps, scale, euler=(0.0, 0.0, 0.0), centre=(0.0, 0.0, 0.0)):
    return [*eps, *scale, *euler, *centre]


def test_euler_matches_the_ports_zyx_convention(bp):
    for euler in ([0.3, -0.7, 1.1], [2.5, 0.2, -3.0], [0.0, 0.0, 0.0]):
        expected = Rotation.from_euler("ZYX", euler).as_matrix()
        assert np.allclose(bp.euler_zyx_matrix(euler), expected, atol=1e-14)


def test_sphere_mesh_and_inside(bp):
    r, centre = 0.2, np.array([0.05, -0.1, 0.02])
    sq = bp.Superquadric.from_params(params((1.0, 1.0), (r, r, r), (0.4, 0.1, -0.3), centre))
    vertices, faces = bp.superquadric_mesh(sq)
    mesh = trimesh.Trimesh(vertices, faces, process=False)
    assert mesh.is_watertight and mesh.is_winding_consistent and mesh.volume > 0
    assert np.allclose(np.linalg.norm(vertices - centre, axis=1), r, atol=1e-12)
    assert mesh.volume == pytest.approx(4 / 3 * np.pi * r**3, rel=2e-3)
    direction = np.array([[1.0, 2.0, -2.0]]) / 3.0
    assert bp.inside_superquadric(centre + 0.999 * r * direction, sq).all()
    assert not bp.inside_superquadric(centre + 1.001 * r * direction, sq).any()


@pytest.mark.parametrize("eps", [(0.1, 0.1), (0.5, 1.5), (2.0, 2.0), (1.0, 0.007), (0.0, 0.3)])
def test_mesh_and_inside_volumes_match_the_formula(bp, eps):
    scale = np.array([0.3, 0.2, 0.1])
    sq = bp.Superquadric.from_params(params(eps, scale, (0.3, -0.7, 1.1), (0.05, 0.0, -0.1)))
    expected = analytic_volume(*sq.eps, scale)  # exponents below EPS_MIN are raised to it
    vertices, faces = bp.superquadric_mesh(sq)
    mesh = trimesh.Trimesh(vertices, faces, process=False)
    assert mesh.is_watertight
    assert mesh.volume == pytest.approx(expected, rel=3e-3)
    points = np.random.default_rng(0).uniform(-0.5, 0.5, (400_000, 3))
    share = bp.inside_superquadric(points, sq).mean()
    assert share == pytest.approx(expected, rel=0.03)  # Monte Carlo in the unit cube


def test_box_like_superquadric_is_nearly_its_box(bp):
    scale = np.array([0.3, 0.2, 0.1])
    sq = bp.Superquadric.from_params(params((0.02, 0.02), scale))
    corners = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)])
    assert bp.inside_superquadric(0.95 * corners * scale, sq).all()
    assert not bp.inside_superquadric(1.01 * corners * scale, sq).any()
    assert not bp.inside_superquadric(np.array([[0.31, 0.0, 0.0], [0.0, 0.0, 0.101]]), sq).any()
    vertices, _ = bp.superquadric_mesh(sq)
    assert np.allclose(np.abs(vertices).max(axis=0), scale, rtol=1e-9)


def test_rotated_ellipsoid_axes(bp):
    scale, euler, centre = np.array([0.25, 0.1, 0.05]), (0.5, -0.4, 0.9), np.array([0.1, 0, 0])
    sq = bp.Superquadric.from_params(params((1.0, 1.0), scale, euler, centre))
    rotation = Rotation.from_euler("ZYX", euler).as_matrix()
    for axis in range(3):
        direction = rotation[:, axis] * scale[axis]
        assert bp.inside_superquadric(centre + 0.99 * direction[None], sq).all()
        assert not bp.inside_superquadric(centre + 1.01 * direction[None], sq).any()


def test_outer_surface_samples_drop_the_overlap(bp):
    r = 0.2
    sqs = [bp.Superquadric.from_params(params((1.0, 1.0), (r, r, r), centre=(x, 0.0, 0.0)))
           for x in (-0.1, 0.1)]
    samples = bp.outer_surface_samples(sqs, 20_000, seed=3)
    assert samples.shape == (20_000, 3)
    d = np.stack([np.linalg.norm(samples - sq.translation, axis=1) for sq in sqs])
    assert np.all(d.min(axis=0) > r - 1e-3)  # nothing inside the other sphere
    assert np.all(np.abs(d.min(axis=0) - r) < 1e-3)  # all on a sphere
    # Each cap of the union holds half the samples.
    assert np.mean(samples[:, 0] < 0) == pytest.approx(0.5, abs=0.02)
    assert bp.inside_superquadrics(np.array([[0.0, 0, 0], [0.29, 0, 0], [0.31, 0, 0]]),
                                   sqs).tolist() == [True, True, False]


def test_port_grid_layout(bp):
    grid = bp.port_voxel_grid()
    n = bp.GRID_SIZE
    assert grid["points"].shape == (3, n**3)
    i, j, k = 3, 57, 98
    assert np.allclose(grid["points"][:, i + n * j + n * n * k],
                       [grid["x"][i], grid["y"][j], grid["z"][k]])
    assert grid["x"][0] == -0.6 and grid["x"][-1] == 0.6
    assert grid["interval"] == pytest.approx(1.2 / 99)
    assert grid["truncation"] == pytest.approx(1.2 * 1.2 / 99)


def test_truncated_sdf_is_the_clipped_exact_distance(bp):
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=0.3)
    slab = trimesh.creation.box(extents=(0.8, 0.6, 0.05))  # long triangles: the filter splits
    grid = bp.port_voxel_grid(size=48)
    points, truncation = grid["points"].T, grid["truncation"]
    for mesh in (sphere, slab):
        V, F = np.asarray(mesh.vertices), np.asarray(mesh.faces)
        inside = mesh.contains
        sdf = bp.truncated_sdf(V, F, inside, points, truncation)
        full = np.sqrt(igl.point_mesh_squared_distance(points, V, F.astype(np.int64))[0])
        expected = np.where(inside(points), -1.0, 1.0) * np.minimum(full, truncation)
        assert np.array_equal(sdf, expected)
        assert (np.abs(sdf) < truncation).sum() > 100
    assert np.all(sdf[np.linalg.norm(points, axis=1) < 0.01] < 0)  # negative inside


def test_score_of_a_sphere(bp, tmp_path):
    from sweepedit.io.shapes import load_shape

    path = tmp_path / "ball.stl"
    trimesh.creation.uv_sphere(radius=1.0, count=(64, 128)).export(path)
    shape = load_shape(path)
    sq = bp.Superquadric.from_params(params((1.0, 1.0), (0.5, 0.5, 0.5)))
    m = bp.score_superquadrics([sq], shape, n_samples=20_000)
    assert m["n_primitives"] == 1
    # As good as the shape's own samples against themselves (at 20,000 a side their
    # spacing, not the fit, bounds F1@0.01).
    from sweepedit.analysis.metrics import chamfer_and_f1

    floor = chamfer_and_f1(shape.surface_samples(20_000, seed=1),
                           shape.surface_samples(20_000, seed=0))
    assert m["iou"] > 0.97 and m["f1_0.05"] == 1.0
    assert m["f1_0.01"] == pytest.approx(floor["f1_0.01"], abs=0.01)
    assert m["cd_l1"] == pytest.approx(floor["cd_l1"], rel=0.05)
    off = bp.Superquadric.from_params(params((1.0, 1.0), (0.5, 0.5, 0.5), centre=(0.05, 0, 0)))
    worse = bp.score_superquadrics([off], shape, n_samples=20_000)
    assert worse["iou"] < m["iou"] and worse["cd_l1"] > m["cd_l1"]
    empty = bp.score_superquadrics([], shape, n_samples=1_000)
    assert empty["iou"] == 0.0 and empty["cd_l1"] == float("inf")


def test_without_the_port_it_says_how_and_exits_0(bp, tmp_path, monkeypatch, capsys):
    monkeypatch.delenv(bp.MP_ENV, raising=False)
    out = tmp_path / "peer.csv"
    assert bp.main(["--methods", "mp", "--shapes", str(tmp_path), "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "FisherYuuri/Marching-Primitives-Python" in text and "--mp-path" in text
    assert len(text.strip().splitlines()) == 1 and not out.exists()


def test_markdown_summary(bp):
    rows = [{"label": "a", "method": m, "shape": s, "status": "ok", "iou": str(v),
             "cd_l1": "0.01", "n_primitives": "8", "fit_seconds": "2", "whole_seconds": "3"}
            for m, v in (("sweepedit", 0.8), ("mp", 0.9)) for s in ("x", "y")]
    rows.append({"label": "a", "method": "mp", "shape": "z", "status": "ok", "iou": "0.1"})
    text = bp.markdown(rows)
    assert "2 shapes done by sweepedit, mp" in text
    assert "| mp | mean | 0.9000 |" in text  # shape z (mp only) is left out of the means


@pytest.mark.slow
def test_the_port_on_a_ball(bp, tmp_path):
    port = os.environ.get(bp.MP_ENV)
    if not port or not (Path(port) / "MPS.py").is_file():
        pytest.skip(f"the Marching-Primitives port is not installed (set {bp.MP_ENV})")
    import json

    path = tmp_path / "ball.stl"
    trimesh.creation.icosphere(subdivisions=4, radius=1.0).export(path)
    out = tmp_path / "ball.json"
    bp.mp_worker(path, Path(port), out)
    record = json.loads(out.read_text())
    # The port covers a ball greedily with many small round pieces (29 here): its fit
    # grows each from a tenth of its region's box for a few steps only.
    assert len(record["superquadrics"]) >= 1
    assert all(len(p) == 11 for p in record["superquadrics"])
    from sweepedit.io.shapes import load_shape

    sqs = [bp.Superquadric.from_params(p) for p in record["superquadrics"]]
    m = bp.score_superquadrics(sqs, load_shape(path), n_samples=20_000)
    assert m["iou"] > 0.95 and m["f1_0.05"] > 0.99


def test_peer_table_means_counts_and_shared_shapes(tmp_path: Path) -> None:
    """peer_table.py: means over the shapes both sides fitted, the median count, and the
    share of shapes with fewer primitives than the peer, from a bench JSON and a CSV."""
    import csv
    import json

    spec = importlib.util.spec_from_file_location("peer_table", BENCH.with_name("peer_table.py"))
    pt = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(pt)
    peer = tmp_path / "peer.csv"
    with peer.open("w", newline="") as f:
        w = csv.DictWriter(f, ["label", "method", "shape", "status", "n_primitives", "iou",
                               "cd_l1", "f1_0.05", "f1_0.01", "whole_seconds"])
        w.writeheader()
        for shape, n, iou in (("a", 10, 0.9), ("b", 20, 0.8), ("c", 5, 0.7)):
            w.writerow({"label": "x", "method": "mp", "shape": shape, "status": "ok",
                        "n_primitives": n, "iou": iou, "cd_l1": 0.005, "f1_0.05": 1.0,
                        "f1_0.01": 0.9, "whole_seconds": 3.0})
    ours = tmp_path / "ours.json"
    rows = [{"shape": s, "metrics": {"iou": iou, "cd_l1": 0.004, "f1_0.05": 0.99,
                                     "f1_0.01": 0.95, "n_primitives": n, "seconds": 2.0}}
            for s, n, iou in (("a", 8, 1.0), ("b", 30, 0.6), ("d", 1, 0.1))]
    ours.write_text(json.dumps({"rows": rows}))
    text = pt.table(pt.read_rows(peer, "mp"), [("us", pt.read_rows(ours, "sweepedit"))])
    us, mp = (line for line in text.splitlines() if line.startswith(("| us", "| Marching")))
    assert us == "| us | 2 | 0.800 | 0.0040 | 0.990 | 0.950 | 19 | 1 of 2 (50%) |"
    assert mp == "| Marching-Primitives | 3 | 0.800 | 0.0050 | 1.000 | 0.900 | 10 |  |"
