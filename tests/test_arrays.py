"""Array shapes at public boundaries (sweepedit.geometry.arrays): the shape language, and
public functions that refuse a wrong shape with a ValueError naming the argument,
where a silent reshape or a 2-D computation would have given a wrong answer."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from sweepedit.analysis.metrics import chamfer_and_f1, sample_triangles
from sweepedit.analysis.skeleton import compute_skeleton
from sweepedit.geometry.arrays import as_array, shape_matches
from sweepedit.geometry.axis_edit import mirror_points
from sweepedit.io.occupancy import point_cells, winding_numbers


@pytest.mark.parametrize(("spec", "shape", "expected"), [
    ("N, 3", (5, 3), True),
    ("N, 3", (0, 3), True),
    ("N, 3", (5,), False),
    ("N, 3", (5, 2), False),
    ("N, 3", (1, 5, 3), False),
    ("R, R, R", (4, 4, 4), True),
    ("R, R, R", (4, 4, 5), False),
    ("..., 3", (3,), True),
    ("..., 3", (2, 5, 3), True),
    ("..., 3", (2, 4), False),
    ("..., 3", (), False),
    ("T", (7,), True),
    ("T", (7, 1), False),
    ("M, 2", (6, 2), True),
])
def test_shape_language(spec: str, shape: tuple[int, ...], expected: bool) -> None:
    assert shape_matches(shape, spec) is expected


def test_as_array_converts_and_names_the_argument() -> None:
    out = as_array([[1, 2, 3]], "N, 3", "points")
    assert out.dtype == np.float64 and out.shape == (1, 3)
    grid = as_array(np.zeros((2, 2, 2), np.uint8), "R, R, R", "occupancy", dtype=bool)
    assert grid.dtype == bool
    with pytest.raises(ValueError, match=r"^points must be an \(N, 3\) array, got \(2, 6\)$"):
        as_array(np.zeros((2, 6)), "N, 3", "points")
    with pytest.raises(ValueError, match=r"^t must be an \(T,\) array, got \(3, 1\)$"):
        as_array(np.zeros((3, 1)), "T", "t")


def test_public_functions_refuse_wrong_shapes() -> None:
    box = trimesh.creation.box()
    vertices, faces = np.asarray(box.vertices), np.asarray(box.faces)
    # Two (2, 6) rows would have been read as four points before.
    with pytest.raises(ValueError, match="queries must be an"):
        winding_numbers(vertices, faces, np.zeros((2, 6)))
    with pytest.raises(ValueError, match="faces must be an"):
        winding_numbers(vertices, np.zeros((3, 4), np.int64), np.zeros((1, 3)))
    # scipy's tree would have measured 2-D distances without a word.
    with pytest.raises(ValueError, match="predicted points must be an"):
        chamfer_and_f1(np.zeros((4, 2)), np.zeros((4, 2)))
    with pytest.raises(ValueError, match="faces must be an"):
        sample_triangles(vertices, np.zeros((2, 4), np.int64), 10, np.random.default_rng(0))
    with pytest.raises(ValueError, match="occupancy must be an"):
        compute_skeleton(np.ones((4, 4, 5), bool))
    with pytest.raises(ValueError, match="points must be an"):
        mirror_points(np.zeros((3, 2)), "x")
    with pytest.raises(ValueError, match="points must be an"):
        point_cells(np.zeros((5, 2)))
    # The right shapes still work: the box's centre is inside, a far point is not.
    w = winding_numbers(vertices, faces, np.array([[0.0, 0.0, 0.0], [3.0, 0.0, 0.0]]))
    np.testing.assert_allclose(np.abs(w), [1.0, 0.0], atol=0.01)  # Barnes-Hut, approximate
