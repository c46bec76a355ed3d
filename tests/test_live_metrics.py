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
