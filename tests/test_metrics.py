"""The quality protocol (docs/quality.md) against truths computed without the code under
test: distances by hand, lattice counts, and the closed-form Chamfer distance of two coaxial
cylinders."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import quad

from sweepedit.analysis.metrics import chamfer_and_f1, evaluate, iou, outer_surface_samples
from sweepedit.geometry.model import Abstraction, SweepPrimitive
from sweepedit.io.mesh_export import export_abstraction
from sweepedit.io.shapes import load_shape

R_SHAPE, R_PRED, LENGTH = 0.125, 0.1, 1.0


def rod(radius: float, direction=(1.0, 0.0, 0.0)) -> SweepPrimitive:
    """A straight round rod of length 1 through the origin (constant scaling)."""
    u = np.asarray(direction, dtype=float)
    return SweepPrimitive(np.outer([-0.5, 0.0, 0.5], u), a=radius, b=radius, degree=2.0,
                          scaling=())


@pytest.fixture(scope="module")
def rod_shape(tmp_path_factory: pytest.TempPathFactory):
    """A rod of radius 1/8 along x as a mesh file; its box is [-0.5, 0.5] x [-1/8, 1/8]^2,
    so the loader's normalisation is the identity and the rod keeps its size."""
    path = tmp_path_factory.mktemp("rod") / "rod.ply"
    export_abstraction(Abstraction([rod(R_SHAPE)]), path, stations=2, profile_points=256)
    shape = load_shape(path, n_samples=1000)
    assert np.allclose(shape.normalization.center, 0.0, atol=1e-9)
    assert shape.normalization.scale == pytest.approx(1.0)
    return shape


def test_iou_of_boolean_arrays() -> None:
    a = np.array([1, 1, 0, 0, 1], dtype=bool)
    b = np.array([1, 0, 1, 0, 1], dtype=bool)
    assert iou(a, b) == pytest.approx(2 / 4)
    assert iou(np.zeros(3, bool), np.zeros(3, bool)) == 1.0


def test_chamfer_and_f1_by_hand() -> None:
    # A lattice of spacing 0.1 and the same lattice moved by 0.02: every nearest neighbour
    # is the point's own partner, 0.02 away.
    g = np.arange(5) * 0.1
    target = np.stack(np.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3)
    pred = target + np.array([0.02, 0.0, 0.0])
    m = chamfer_and_f1(pred, target)
    assert m["cd_l1"] == pytest.approx(0.02)
    assert m["cd_l2"] == pytest.approx(0.0004)
    assert m["f1_0.05"] == pytest.approx(1.0) and m["f1_0.01"] == 0.0
    # One far outlier among the predictions: precision 125 / 126, recall 1.
    m = chamfer_and_f1(np.vstack([pred, [[3.0, 0.0, 0.0]]]), target)
    p = 125 / 126
    assert m["f1_0.05"] == pytest.approx(2 * p / (p + 1))
    assert m["cd_l1"] == pytest.approx(((125 * 0.02 + (3.0 - 0.4)) / 126 + 0.02) / 2)


def test_outer_surface_samples_skip_covered_parts() -> None:
    # Two crossing rods: no sample may lie strictly inside the other rod, and the count is
    # what was asked for.
    a, b = rod(0.1, (1, 0, 0)), rod(0.1, (0, 1, 0))
    pts = outer_surface_samples([a, b], 20_000, seed=3)
    assert pts.shape == (20_000, 3)
    dist_a = np.hypot(pts[:, 1], pts[:, 2])  # from the x axis
    dist_b = np.hypot(pts[:, 0], pts[:, 2])  # from the y axis
    inside_a = (dist_a < 0.1 - 1e-3) & (np.abs(pts[:, 0]) < 0.5 - 1e-3)
    inside_b = (dist_b < 0.1 - 1e-3) & (np.abs(pts[:, 1]) < 0.5 - 1e-3)
    assert not np.any(inside_a | inside_b)
    np.testing.assert_array_equal(pts, outer_surface_samples([a, b], 20_000, seed=3))


def _disc_cells(radius: float, resolution: int = 64) -> int:
    """Cell centres of one grid slice inside a disc of `radius` about the origin."""
    c = (np.arange(resolution) + 0.5) / resolution - 0.5
    y, z = np.meshgrid(c, c, indexing="ij")
    return int(np.count_nonzero(y**2 + z**2 <= radius**2))


def _coaxial_rods_chamfer() -> tuple[float, float]:
    """CD-L1 and CD-L2 between the surfaces of two coaxial rods of length L (radii r < R),
    area-weighted, from the closed form: a side point is R - r from the other side, a cap
    point of the thin rod lies on the fat one's cap, a cap point at radius s > r of the fat
    rod is s - r from the thin one's rim."""
    r, R, L = R_PRED, R_SHAPE, LENGTH
    pred_area, shape_area = 2 * np.pi * r * (r + L), 2 * np.pi * R * (R + L)
    # pred side points within R - r of a cap end are nearer that cap than the side.
    near = R - r
    side1 = 2 * np.pi * r * (2 * quad(lambda x: x, 0, near)[0] + (L - 2 * near) * near)
    side2 = 2 * np.pi * r * (2 * quad(lambda x: x**2, 0, near)[0] + (L - 2 * near) * near**2)
    cap1 = 2 * quad(lambda s: (s - r) * 2 * np.pi * s, r, R)[0]
    cap2 = 2 * quad(lambda s: (s - r) ** 2 * 2 * np.pi * s, r, R)[0]
    d_pred1, d_pred2 = side1 / pred_area, side2 / pred_area
    d_shape1 = (2 * np.pi * R * L * near + cap1) / shape_area
    d_shape2 = (2 * np.pi * R * L * near**2 + cap2) / shape_area
    return (d_pred1 + d_shape1) / 2, (d_pred2 + d_shape2) / 2


def test_evaluate_a_thinner_rod_against_the_rod(rod_shape) -> None:
    m = evaluate(Abstraction([rod(R_PRED)]), rod_shape, n_samples=50_000)
    # Nested rods spanning the whole grid in x: IoU is the ratio of lattice counts.
    assert m["iou"] == pytest.approx(_disc_cells(R_PRED) / _disc_cells(R_SHAPE), abs=0.005)
    cd1, cd2 = _coaxial_rods_chamfer()
    assert m["cd_l1"] == pytest.approx(cd1, abs=5e-4)
    assert m["cd_l2"] == pytest.approx(cd2, rel=0.03)
    assert m["f1_0.05"] == pytest.approx(1.0)  # nothing is further apart than 0.025
    assert 0.05 < m["f1_0.01"] < 0.15  # only the caps (and the rims' strips) are close
    assert m["n_primitives"] == 1


def test_evaluate_the_rod_against_itself_and_determinism(rod_shape) -> None:
    abstraction = Abstraction([rod(R_SHAPE)])
    m = evaluate(abstraction, rod_shape, n_samples=50_000, seed=5)
    assert m["iou"] == pytest.approx(1.0, abs=1e-3)
    assert m["f1_0.01"] == pytest.approx(1.0) and m["cd_l1"] < 0.003
    assert evaluate(abstraction, rod_shape, n_samples=50_000, seed=5) == m
    assert evaluate(abstraction, rod_shape, n_samples=50_000, seed=6) != m


def test_surface_agreement_estimates_the_protocols_precision_and_recall(tmp_path) -> None:
    """SurfaceAgreement (quick samples, shell pairs) against the protocol itself
    (chamfer_and_f1 on 100,000 samples a side): a cylinder loaded as a shape, swept
    exactly, 0.006 too thin (inside tau = 0.008 of its surface) and 0.012 too thin
    (outside it but for the caps)."""
    import trimesh

    from sweepedit.analysis.metrics import SurfaceAgreement, chamfer_and_f1, outer_surface_samples
    from sweepedit.geometry.model import SweepPrimitive
    from sweepedit.io.shapes import load_shape

    mesh = trimesh.creation.cylinder(radius=0.2, height=0.6, sections=256)
    mesh.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, [0, 1, 0]))
    path = tmp_path / "cylinder.stl"
    mesh.export(path)
    shape = load_shape(path, n_samples=2000)
    tau = 0.008
    agreement = SurfaceAgreement(shape, tau)
    target = shape.surface_samples(100_000, seed=0)
    estimates = []
    for shrink in (0.0, 0.006, 0.012):
        radius = 1 / 3 - shrink
        prim = SweepPrimitive([[-0.5, 0.0, 0.0], [0.0, 0.0, 0.0], [0.5, 0.0, 0.0]], a=radius,
                              b=radius)
        truth = chamfer_and_f1(outer_surface_samples([prim], 100_000, seed=1), target,
                               taus=(tau,))
        # min(P, R) from F1 = 2PR/(P+R) is not recoverable; compare with the protocol's
        # own precision and recall.
        from scipy.spatial import cKDTree

        pred = outer_surface_samples([prim], 100_000, seed=1)
        precision = np.mean(cKDTree(target).query(pred)[0] < tau)
        recall = np.mean(cKDTree(pred).query(target)[0] < tau)
        estimate = agreement([prim])
        estimates.append(estimate)
        assert estimate == pytest.approx(min(precision, recall), abs=0.05), (shrink, truth)
    assert estimates[0] > 0.95 and estimates[2] < 0.5
