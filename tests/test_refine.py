"""Refinement: pruning by score, residual primitives, direct refinement of a known sweep."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from sweepedit.fitting.params import ParamLayout
from sweepedit.fitting.refine import (
    Adam,
    RefineSettings,
    ScoringPoints,
    missed_parts,
    prune,
    refine_primitives,
    residual_primitives,
)
from sweepedit.geometry.inside import grid_points, inside_primitive
from sweepedit.geometry.mesher import sweep_mesh
from sweepedit.geometry.model import SweepPrimitive

RES = 32
BAR_X = SweepPrimitive([[-0.35, 0.0, 0.0], [0.0, 0.0, 0.0], [0.35, 0.0, 0.0]], a=0.06, b=0.06)
BAR_Y = SweepPrimitive([[0.2, -0.35, 0.1], [0.2, 0.0, 0.1], [0.2, 0.35, 0.1]], a=0.05, b=0.05)
FAT = SweepPrimitive([[-0.35, 0.0, -0.15], [0.0, 0.0, -0.15], [0.35, 0.0, -0.15]], a=0.1, b=0.1)
THIN = SweepPrimitive([[0.2, -0.35, 0.2], [0.2, 0.0, 0.2], [0.2, 0.35, 0.2]], a=0.02, b=0.02)
ARCH = SweepPrimitive([[-0.35, -0.1, 0.0], [0.0, 0.3, 0.05], [0.35, -0.1, 0.0]], a=0.08,
                      b=0.06, degree=2.5, scaling=(0.2, -0.3))


def truth_grid(primitives: list[SweepPrimitive], res: int) -> np.ndarray:
    """(res, res, res) bool: the exact inside test of the union at the cell centres."""
    cells = grid_points(res)
    return np.any([inside_primitive(cells, p) for p in primitives], axis=0).reshape((res,) * 3)


def truth_points(primitives: list[SweepPrimitive], res: int = RES,
                 n_samples: int = 4000) -> ScoringPoints:
    """Scoring points labelled by the exact inside test of the true primitives: the grid,
    and points jittered off their surfaces."""
    rng = np.random.default_rng(1)
    surface = []
    for p in primitives:
        mesh = sweep_mesh(p, 48, 32)
        surface.append(mesh.vertices[rng.integers(0, len(mesh.vertices), n_samples)])
    samples = np.concatenate(surface)
    samples = samples + rng.normal(scale=0.6 / res, size=samples.shape)
    labels = np.zeros(len(samples), dtype=bool)
    for p in primitives:
        labels |= inside_primitive(samples, p)
    return ScoringPoints(truth_grid(primitives, res), samples, labels.astype(np.float32))


def test_prune_drops_what_adds_nothing_and_keeps_what_counts() -> None:
    points = truth_points([BAR_X, BAR_Y])
    inside_x = inside_primitive(points.points, BAR_X)
    inside_y = inside_primitive(points.points, BAR_Y)
    part_of_x = inside_x & (points.points[:, 0] < 0.0)  # a primitive inside BAR_X: redundant
    occupancy = np.stack([inside_x, part_of_x, inside_y])
    assert prune(occupancy, points) == [0, 2]
    # A primitive covering nothing of the shape but some empty space lowers the score and
    # goes; one that is the only cover of a bar stays even at a high bar.
    stray = np.zeros_like(inside_x)
    stray[points.points[:, 2] > 0.45] = True
    assert prune(np.stack([inside_x, stray, inside_y]), points) == [0, 2]
    assert prune(np.stack([inside_x, inside_y]), points, min_gain=0.05) == [0, 1]
    # With min_gain above what a bar adds, the smaller bar goes too.
    share_y = points.score(inside_x | inside_y) - points.score(inside_x)
    assert 0.0 < share_y < 0.9
    assert prune(np.stack([inside_x, inside_y]), points, min_gain=share_y + 1e-6) == [0]


def test_missed_parts_ignore_specks_and_residuals_follow_the_missed_bar() -> None:
    points = truth_points([BAR_X, BAR_Y])
    covered = inside_primitive(points.points, BAR_X)
    missed = missed_parts(points, covered, min_cells=12)
    bar_y_cells = points.grid_target & ~covered[: points.n_cells].reshape(points.grid_target.shape)
    assert missed.sum() == pytest.approx(bar_y_cells.sum(), rel=0.2)
    assert not missed_parts(points, covered, min_cells=int(bar_y_cells.sum()) + 1).any()
    layout = ParamLayout()
    new = residual_primitives(missed, budget=3, layout=layout)
    assert 1 <= len(new) <= 3
    axis = np.concatenate([p.control_points for p in new])
    # Along y at x = 0.2, z = 0.1 (within a couple of cells), and spanning most of it.
    np.testing.assert_allclose(axis[:, [0, 2]], np.tile([0.2, 0.1], (len(axis), 1)),
                               atol=2.5 / RES)
    assert np.ptp(axis[:, 1]) > 0.4
    assert residual_primitives(missed, budget=0, layout=layout) == []


def test_refinement_recovers_a_perturbed_sweep() -> None:
    points = truth_points([ARCH])
    start = ARCH.copy()
    start.control_points = start.control_points + np.array([0.03, -0.04, 0.02])
    start.a, start.b, start.degree, start.scaling = 0.12, 0.04, 2.0, (0.0, 0.0)
    start_score = points.score(inside_primitive(points.points, start))
    settings = RefineSettings(iterations=120, cells=2048, samples=1024, residual_rounds=0)
    result = refine_primitives([start], ParamLayout(), points, settings, seed=0)
    refined, score = result.primitives, result.score
    assert len(refined) == 1
    refined[0].validate()
    assert score == pytest.approx(points.score(inside_primitive(points.points, refined[0])))
    assert start_score < 0.7
    assert score > 0.9, (start_score, score)
    # Judged on a finer grid than it was fitted on, against the exact test of the truth.
    fine = grid_points(48)
    truth, got = inside_primitive(fine, ARCH), inside_primitive(fine, refined[0])
    assert np.count_nonzero(truth & got) / np.count_nonzero(truth | got) > 0.85


def test_refinement_keeps_locked_primitives_out_and_is_never_worse() -> None:
    points_all = truth_points([BAR_X, BAR_Y])
    points = ScoringPoints(points_all.grid_target, points_all.points[points_all.n_cells:],
                           points_all.labels[points_all.n_cells:].astype(np.float32),
                           locked=[BAR_X])
    assert points.locked.any()
    # BAR_Y itself is already the best answer: refinement may not make it worse.
    before = points.score(inside_primitive(points.points, BAR_Y))
    result = refine_primitives([BAR_Y], ParamLayout(), points,
                               RefineSettings(iterations=30, residual_rounds=0))
    refined, score = result.primitives, result.score
    assert score >= before - 1e-12
    assert before > 0.9
    assert len(refined) == 1


def test_at_the_budget_a_primitive_is_swapped_for_a_bigger_missed_part() -> None:
    thin = SweepPrimitive([[0.2, -0.35, 0.2], [0.2, 0.0, 0.2], [0.2, 0.35, 0.2]],
                          a=0.04, b=0.04)
    points = truth_points([FAT, thin])
    # One primitive allowed, sitting on the thin bar: the fat one is worth more.
    settings = RefineSettings(iterations=10, residual_rounds=1, residual_iterations=60)
    before = points.score(inside_primitive(points.points, thin))
    result = refine_primitives([thin], ParamLayout(), points, settings, budget=1)
    refined, score = result.primitives, result.score
    assert len(refined) == 1
    axis = refined[0].control_points
    assert np.ptp(axis[:, 0]) > 0.4 and np.ptp(axis[:, 1]) < 0.1, axis
    assert score > before
    # With room for two, both bars are covered.
    result = refine_primitives([thin], ParamLayout(), points, settings, budget=2)
    both, score_both = result.primitives, result.score
    assert len(both) == 2 and score_both > score


def surface_points(primitives: list[SweepPrimitive], weight: float,
                   res: int = 64) -> ScoringPoints:
    """Scoring points on a grid alone (so that the IoU is a share of volume), labelled
    by the exact inside test, with area-uniform samples of the true surfaces."""
    import trimesh

    meshes = [sweep_mesh(p, 64, 48).to_trimesh() for p in primitives]
    surface, _ = trimesh.sample.sample_surface(trimesh.util.concatenate(meshes), 3000, seed=2)
    return ScoringPoints(truth_grid(primitives, res), np.zeros((0, 3)), np.zeros(0),
                         surface=surface, reach=0.03, surface_weight=weight)


def test_surface_coverage_is_the_share_of_the_surface_near_the_union() -> None:
    points = surface_points([FAT, THIN], weight=1.0)
    inside_fat = inside_primitive(points.points, FAT)
    inside_thin = inside_primitive(points.points, THIN)
    # The bars are 0.21 apart, more than the reach: covering one bar covers its own
    # surface and none of the other's, so coverage is its share of the surface area.
    area_fat, area_thin = (sweep_mesh(p, 64, 48).to_trimesh().area for p in (FAT, THIN))
    share_fat = area_fat / (area_fat + area_thin)
    assert points.surface_coverage(inside_fat) == pytest.approx(share_fat, abs=0.03)
    assert points.surface_coverage(inside_fat | inside_thin) > 0.99
    assert points.surface_coverage(np.zeros_like(inside_fat)) == 0.0
    # The score is the IoU plus the weighted coverage.
    both = inside_fat | inside_thin
    assert points.score(both) == pytest.approx(points.iou(both) + points.surface_coverage(both))


def test_surface_weight_keeps_a_thin_part_that_iou_alone_would_prune() -> None:
    plain, weighted = surface_points([FAT, THIN], 0.0), surface_points([FAT, THIN], 1.0)
    occupancy = np.stack([inside_primitive(plain.points, FAT),
                          inside_primitive(plain.points, THIN)])
    thin_iou_gain = plain.score(occupancy.any(axis=0)) - plain.score(occupancy[0])
    # The thin bar is a small share of the volume but a large one of the surface.
    assert 0.0 < thin_iou_gain < 0.1
    min_gain = 2 * thin_iou_gain
    assert prune(occupancy, plain, min_gain) == [0]
    assert prune(occupancy, weighted, min_gain) == [0, 1]


def test_boundary_cells_leave_out_the_deep_interior_and_keep_every_disagreement() -> None:
    from scipy import ndimage as ndi

    points = truth_points([FAT])
    shape = points.grid_target
    covered = np.zeros(len(points.points), dtype=bool)
    covered[: points.n_cells] = shape.reshape(-1)
    cells = np.zeros(shape.size, dtype=bool)
    cells[points.boundary_cells(covered, 2)] = True
    cells = cells.reshape(shape.shape)
    # Independent truth: the shell is the dilation minus the erosion of the shape.
    shell = ndi.binary_dilation(shape, iterations=2) & ~ndi.binary_erosion(shape, iterations=2)
    np.testing.assert_array_equal(cells, shell)
    assert (shape & ~cells).any()  # the deep interior is left out
    # A union cell far from the shape (a false positive) is always sampled.
    far = np.zeros(shape.shape, dtype=bool)
    far[2, 2, 2] = True
    covered[: points.n_cells] |= far.reshape(-1)
    assert np.ravel_multi_index((2, 2, 2), shape.shape) in points.boundary_cells(covered, 2)


def test_union_near_equals_the_exact_union_after_a_small_move() -> None:
    points = truth_points([ARCH])
    before = points.occupancy([ARCH]).any(axis=0)
    moved = ARCH.copy()
    moved.control_points = moved.control_points + np.array([0.02, -0.015, 0.01])  # < 1 cell
    moved.a *= 1.05
    exact = points.occupancy([moved]).any(axis=0)
    near = points.union_near([moved], before, width=3)
    np.testing.assert_array_equal(near, exact)


def test_adam_matches_torch_optim_adam():
    """refine.Adam is torch.optim.Adam's default update (to float rounding) over many steps
    of a non-convex loss, so refinement keeps its behaviour without importing dynamo."""
    torch.manual_seed(0)
    target = torch.randn(5, 7)
    ours = torch.randn(5, 7, requires_grad=True)
    theirs = ours.detach().clone().requires_grad_(True)
    mine = Adam(ours, lr=0.02)
    reference = torch.optim.Adam([theirs], lr=0.02)
    for _ in range(50):
        for p, opt in ((ours, mine), (theirs, reference)):
            p.grad = None
            (torch.sin(3 * p) * target).sum().backward()
            opt.step()
    assert torch.allclose(ours, theirs, rtol=0, atol=1e-6)
    assert not torch.equal(ours, target)  # it moved


def test_shell_accuracy_sees_a_boundary_off_by_more_than_the_offset(tmp_path) -> None:
    """Shell pairs 0.005 to either side of a cylinder's surface (a trimesh cylinder of
    radius 0.2, loaded as a shape): the sweep of the same radius and length puts the
    boundary between nearly every pair; one 0.01 wider misses the outer point of every
    pair on the side (three quarters of the area), so about 5/8 are right; the score
    carries the term with its weight."""
    import trimesh

    from sweepedit.geometry.inside import inside_union
    from sweepedit.io.shapes import load_shape

    mesh = trimesh.creation.cylinder(radius=0.2, height=0.6, sections=256)
    mesh.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, [0, 1, 0]))
    path = tmp_path / "cylinder.stl"
    mesh.export(path)
    shape = load_shape(path, n_samples=2000)
    # The loader normalises the longest side (0.6) to 1: radius 1/3, axis along x.
    shell, labels = shape.shell_samples(3000, 0.005, seed=2)
    assert len(shell) == 6000 and labels.mean() == pytest.approx(0.5, abs=0.01)
    points = ScoringPoints(shape.winding_occupancy, shape.samples.points,
                           shape.samples.labels, shell=shell, shell_labels=labels,
                           shell_weight=2.0)
    accuracy = {}
    for radius in (1 / 3, 1 / 3 + 0.01):
        prim = SweepPrimitive([[-0.5, 0.0, 0.0], [0.0, 0.0, 0.0], [0.5, 0.0, 0.0]], a=radius,
                              b=radius)
        covered = inside_union(points.points, [prim])
        accuracy[radius] = points.shell_accuracy(covered)
        assert points.score(covered) == pytest.approx(points.iou(covered)
                                                      + 2.0 * accuracy[radius])
    side = 2 * np.pi * (1 / 3) * 1.0 / (2 * np.pi * (1 / 3) * 1.0 + 2 * np.pi / 9)
    assert accuracy[1 / 3] > 0.99
    assert accuracy[1 / 3 + 0.01] == pytest.approx(1.0 - side / 2, abs=0.03)
    # The IoU counts the cells and samples only.
    assert points.n_labelled == len(points.points) - 6000


def test_a_thin_tail_outside_the_shape_is_drawn_back_by_the_axis_term() -> None:
    """A sweep along BAR_X whose axis runs on 0.12 beyond the bar's end while its scaling
    thins it to under a cell there: no cell centre lies in the tail, so the cross-entropy
    leaves it where it is; with the axis term the axis comes back within the shape."""
    points = truth_points([BAR_X])
    outside = points.outside_distance()
    start = SweepPrimitive([[-0.35, 0.0, 0.0], [0.06, 0.0, 0.0], [0.47, 0.0, 0.0]],
                           a=0.06, b=0.06, scaling=(-0.5, -0.4))
    t = np.linspace(0.0, 1.0, 65)
    layout = ParamLayout(3, 2)

    def farthest(settings: RefineSettings) -> float:
        got = refine_primitives([start], layout, points, settings, seed=0).primitives[0]
        axis = torch.as_tensor(got.control_points[None])
        from sweepedit.geometry.sweep import axis_points

        pts = axis_points(axis, torch.as_tensor(t)).numpy()[0]
        index = np.clip(((pts + 0.5) * RES).astype(int), 0, RES - 1)
        return float(outside[index[:, 0], index[:, 1], index[:, 2]].max())

    plain = RefineSettings(iterations=120, residual_rounds=0)
    assert farthest(plain) > 2.5 / RES  # the tail stays out
    assert farthest(RefineSettings(iterations=120, residual_rounds=0, axis_weight=5.0)) \
        <= 1.5 / RES
