"""LiveMetrics: evaluate's protocol, recomputing only the edited primitive's share."""

from __future__ import annotations

import numpy as np
import pytest

from sweepedit.analysis.live_metrics import LiveMetrics
from sweepedit.analysis.metrics import evaluate
from sweepedit.geometry.model import Abstraction, SweepPrimitive


@pytest.fixture(scope="module")
def box_shape(tmp_path_factory):
    trimesh = pytest.importorskip("trimesh")
    from sweepedit.io.shapes import load_shape

    path = tmp_path_factory.mktemp("live") / "box.obj"
    trimesh.creation.box(extents=(0.6, 0.3, 0.3)).export(path)
    return load_shape(path)


def primitives() -> list[SweepPrimitive]:
    return [SweepPrimitive(control_points=[[-0.45, 0, 0], [-0.2, 0.02, 0], [0.05, 0, 0]],
                           a=0.2, b=0.2, degree=4.0),
            SweepPrimitive(control_points=[[0.0, -0.1, 0], [0.2, 0.0, 0.02], [0.4, 0.05, 0]],
                           a=0.12, b=0.1, degree=2.5, scaling=(0.1, -0.05))]


def test_matches_evaluate(box_shape) -> None:
    prims = primitives()
    live = LiveMetrics(box_shape, n_samples=20000).evaluate(prims)
    full = evaluate(Abstraction(prims), box_shape, n_samples=20000)
    assert live["iou"] == full["iou"]  # the same grid and inside tests
    assert live["n_primitives"] == 2
    # Surface metrics from other samples of the same surfaces: sampling noise only.
    assert live["cd_l1"] == pytest.approx(full["cd_l1"], rel=0.05)
    assert live["cd_l2"] == pytest.approx(full["cd_l2"], rel=0.1)
    assert live["f1_0.05"] == pytest.approx(full["f1_0.05"], abs=0.02)
    assert live["f1_0.01"] == pytest.approx(full["f1_0.01"], abs=0.03)


def test_an_edit_gives_what_a_fresh_start_gives(box_shape) -> None:
    prims = primitives()
    live = LiveMetrics(box_shape, n_samples=5000)
    before = live.evaluate(prims)
    moved = prims[1].copy()
    moved.control_points = moved.control_points + np.array([0.05, 0.02, 0.0])
    after = live.evaluate([prims[0], moved])
    assert after == LiveMetrics(box_shape, n_samples=5000).evaluate([prims[0], moved])
    assert after != before
    assert live.evaluate(prims) == before  # back again (an undo): the same numbers
    empty = live.evaluate([])
    assert empty["iou"] == 0.0 and empty["cd_l1"] == float("inf")


def test_folding_primitive_matches_evaluate(box_shape) -> None:
    """A primitive whose profile reaches past its axis's centre of curvature: live
    metrics sample its solid's boundary from its pieces (no boolean), evaluate samples
    the boolean solid; the two agree within sampling noise."""
    from sweepedit.geometry.model import folds_onto_itself

    bend = SweepPrimitive(control_points=[[-0.15, -0.05, 0], [0.3, 0.0, 0], [-0.15, 0.05, 0]],
                          a=0.12, b=0.09, degree=2.5)
    assert folds_onto_itself(bend)
    prims = [bend, primitives()[1]]
    live = LiveMetrics(box_shape, n_samples=20000).evaluate(prims)
    full = evaluate(Abstraction(prims), box_shape, n_samples=20000)
    assert live["iou"] == full["iou"]
    assert live["cd_l1"] == pytest.approx(full["cd_l1"], rel=0.05)
    assert live["cd_l2"] == pytest.approx(full["cd_l2"], rel=0.1)
    assert live["f1_0.05"] == pytest.approx(full["f1_0.05"], abs=0.02)
    assert live["f1_0.01"] == pytest.approx(full["f1_0.01"], abs=0.03)


def test_folding_primitive_samples_cover_its_solid(box_shape) -> None:
    """The folding primitive's samples lie on its boolean solid's surface and cover it
    at the shape's density: as many as the density times the solid's area (within 10 %),
    with the symmetric Chamfer distance to samples of that surface at sampling noise."""
    from scipy.spatial import cKDTree

    from sweepedit.analysis.metrics import (
        _SAMPLE_PROFILE_POINTS,
        _SAMPLE_STATIONS,
        sample_triangles,
    )
    from sweepedit.geometry.solid import solid_mesh

    bend = SweepPrimitive(control_points=[[-0.15, -0.05, 0], [0.3, 0.0, 0], [-0.15, 0.05, 0]],
                          a=0.12, b=0.09, degree=2.5)
    live = LiveMetrics(box_shape, n_samples=20000)
    samples = live._sample(bend.geometry_key(), bend)
    mesh = solid_mesh(bend, _SAMPLE_STATIONS, _SAMPLE_PROFILE_POINTS)
    tri = mesh.vertices[mesh.faces]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]),
                                axis=1).sum()
    assert len(samples) == pytest.approx(live.density * area, rel=0.1)
    reference = sample_triangles(mesh.vertices, mesh.faces, len(samples),
                                 np.random.default_rng(1))[0]
    spacing = np.sqrt(area / len(samples))
    chamfer = (cKDTree(reference).query(samples)[0].mean()
               + cKDTree(samples).query(reference)[0].mean())
    assert chamfer < 1.5 * spacing
