"""Refit of a selection: only the selected primitives move, the others stay bit for bit,
nothing is added or removed, and the refined ones cover more of what the others miss."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("torch")

from sweepedit.errors import SweepeditError
from sweepedit.fitting.fit import FitSettings
from sweepedit.fitting.refit import refit_selection
from sweepedit.geometry.inside import grid_points, inside_union
from sweepedit.geometry.model import SweepPrimitive


@pytest.fixture(scope="module")
def box_shape(tmp_path_factory):
    trimesh = pytest.importorskip("trimesh")
    from sweepedit.io.shapes import load_shape

    path = tmp_path_factory.mktemp("refit") / "box.obj"
    trimesh.creation.box(extents=(0.6, 0.3, 0.3)).export(path)
    return load_shape(path)


def test_only_the_selection_moves_and_it_fills_the_gap(box_shape) -> None:
    # The left half of the box is covered; a small primitive sits in the right half.
    prims = [SweepPrimitive(control_points=[[-0.45, 0, 0], [-0.25, 0, 0], [-0.05, 0, 0]],
                            a=0.22, b=0.22, degree=4.0, name="left"),
             SweepPrimitive(control_points=[[0.15, 0, 0], [0.25, 0, 0.01], [0.35, 0, 0]],
                            a=0.08, b=0.08, name="right")]
    reports = []
    result = refit_selection(box_shape, prims, [1], FitSettings(refine_iterations=40),
                             callback=reports.append)
    out = result.abstraction.primitives
    assert len(out) == 2 and [p.name for p in out] == ["left", "right"]
    assert out[0].control_points.tobytes() == prims[0].control_points.tobytes()
    assert (out[0].a, out[0].b, out[0].degree, out[0].scaling) == (
        prims[0].a, prims[0].b, prims[0].degree, prims[0].scaling)
    assert not np.array_equal(out[1].control_points, prims[1].control_points)
    # Judged independently: the grid IoU against the box's own inside test.
    grid = grid_points(32)
    target = box_shape.inside(grid)

    def grid_iou(ps) -> float:
        union = inside_union(grid, ps)
        return np.count_nonzero(union & target) / np.count_nonzero(union | target)

    assert grid_iou(out) > grid_iou(prims) + 0.05
    assert reports and all(r.stage == "refit selection" for r in reports)
    assert all(len(r.abstraction.primitives) == 2 for r in reports)
    assert result.abstraction.fit["refit"] == [2]


def test_bad_selections_are_refused(box_shape) -> None:
    prims = [SweepPrimitive(control_points=[[-0.3, 0, 0], [0, 0, 0], [0.3, 0, 0]], a=0.1,
                            b=0.1, name="only", locked=True)]
    with pytest.raises(SweepeditError, match="select"):
        refit_selection(box_shape, prims, [])
    with pytest.raises(SweepeditError, match="no primitive 3"):
        refit_selection(box_shape, prims, [2])
    with pytest.raises(SweepeditError, match="locked"):
        refit_selection(box_shape, prims, [0])
