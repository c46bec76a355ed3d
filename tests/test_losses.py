"""SweepNet's losses against values computed by hand on tiny cases."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from sweepedit.fitting.losses import (
    LossWeights,
    axis_chamfer_loss,
    boltzmann_union,
    outside_axis_loss,
    overlap_loss,
    parsimony_loss,
    reconstruction_loss,
)
from sweepedit.fitting.warmstart import fit_axis, warm_start_primitives
from sweepedit.geometry.axis_edit import bspline_basis
from sweepedit.geometry.sweep import axis_points


def test_boltzmann_union_of_one_primitive_is_itself() -> None:
    occ = torch.tensor([[[0.2, 0.9, 0.0]]])
    np.testing.assert_allclose(boltzmann_union(occ, torch.ones(1, 1)), occ[:, 0], atol=1e-7)


def test_boltzmann_union_by_hand() -> None:
    occ = torch.tensor([[[1.0], [0.0]]])  # two primitives, one point
    a = 40.0
    expected = (1.0 * math.exp(a)) / (math.exp(a) + 1.0)
    assert float(boltzmann_union(occ, torch.ones(1, 2))[0, 0]) == pytest.approx(expected)
    # a deselected primitive does not count
    assert float(boltzmann_union(occ, torch.tensor([[0.0, 1.0]]))[0, 0]) == pytest.approx(0.0)


def test_reconstruction_overlap_parsimony_by_hand() -> None:
    union = torch.tensor([[1.0, 0.5, 0.0, 0.0]])
    target = torch.tensor([[1.0, 1.0, 0.0, 1.0]])
    assert float(reconstruction_loss(union, target)) == pytest.approx((0.25 + 1.0) / 4)
    occ = torch.tensor([[[1.0, 1.0, 0.0], [1.0, 0.5, 0.0], [1.0, 0.0, 1.0]]])  # K=3, Q=3
    sel = torch.tensor([[1.0, 1.0, 0.5]])
    # coverage per point: 2.5, 1.5, 0.5 -> beyond 1: 1.5, 0.5, 0 -> mean 2/3
    assert float(overlap_loss(occ, sel)) == pytest.approx(2.0 / 3.0)
    assert float(parsimony_loss(sel)) == pytest.approx(math.sqrt(2.5), rel=1e-5)


def test_axis_chamfer_by_hand() -> None:
    skeleton = torch.tensor([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]])
    axes = torch.tensor([[[0.0, 0.0, 0.0], [0.0, 0.5, 0.0]]])  # K=1, S=2
    # skeleton -> axes: 0 and 1 -> mean 0.5; axis -> skeleton: 0 and 0.25 -> mean 0.125
    loss = axis_chamfer_loss(skeleton, axes, torch.ones(1))
    assert float(loss) == pytest.approx(0.5 + 0.125, rel=1e-5)


def test_parsimony_weight_and_axis_decay() -> None:
    w = LossWeights()
    assert w.parsimony_weight(16) == pytest.approx(0.6)
    assert w.axis_weight(0.0) == pytest.approx(5.0)
    assert w.axis_weight(1.0) == pytest.approx(5.0 * w.axis_decay)


def test_bspline_basis_reproduces_the_axis() -> None:
    rng = np.random.default_rng(0)
    cps = rng.uniform(-0.5, 0.5, (5, 3))
    t = np.linspace(0, 1, 40)
    np.testing.assert_allclose(bspline_basis(5, t) @ cps, axis_points(cps[None], t)[0],
                               atol=1e-12)


def test_fit_axis_recovers_a_bspline() -> None:
    cps = np.array([[-0.3, 0.0, 0.0], [0.0, 0.3, 0.1], [0.3, 0.0, 0.0]])
    # dense arc-length-uniform samples of the curve
    t = np.linspace(0, 1, 2000)
    pts = axis_points(cps[None], t)[0]
    s = np.concatenate([[0], np.cumsum(np.linalg.norm(np.diff(pts, axis=0), axis=1))])
    even = np.interp(np.linspace(0, s[-1], 200), s, np.arange(len(pts)))
    samples = pts[np.round(even).astype(int)]
    fitted = fit_axis(samples, 3)
    assert np.abs(axis_points(fitted[None], t)[0] - pts).max() < 0.02


class _Branch:
    def __init__(self, points: np.ndarray, radius: float) -> None:
        self.points = points
        self.radii = np.full(len(points), radius)


def test_warm_start_one_primitive_per_branch_and_splits_to_fill() -> None:
    line = np.linspace([-0.4, 0, 0], [0.4, 0, 0], 40)
    other = np.linspace([0, -0.3, 0], [0, 0.3, 0], 30)
    prims = warm_start_primitives([_Branch(line, 0.05), _Branch(other, 0.08)], k=2)
    assert len(prims) == 2
    # the thicker branch carries more volume and comes first
    assert prims[0].a == pytest.approx(0.08, abs=1e-6)
    assert prims[1].a == pytest.approx(0.05, abs=1e-6)
    np.testing.assert_allclose(prims[1].control_points[[0, -1]], line[[0, -1]], atol=1e-9)
    for p in prims:
        p.validate()
    # straight branches stay one sweep each even when more primitives are allowed
    prims = warm_start_primitives([_Branch(line, 0.05), _Branch(other, 0.08)], k=4)
    assert len(prims) == 2
    # a branch that one quadratic axis cannot follow (an S) is split
    t = np.linspace(0, 2 * np.pi, 80)
    s_curve = np.stack([0.4 * t / t[-1] - 0.2, 0.15 * np.sin(t), np.zeros_like(t)], axis=1)
    prims = warm_start_primitives([_Branch(s_curve, 0.02)], k=4)
    assert 2 <= len(prims) <= 4
    # a parabolic arc is exactly one quadratic axis, so it is not split however bent
    u = np.linspace(-1, 1, 60)
    arc = np.stack([0.4 * u, 0.3 * u**2, np.zeros_like(u)], axis=1)
    assert len(warm_start_primitives([_Branch(arc, 0.03)], k=4)) == 1


def test_fold_loss_is_positive_exactly_where_the_sweep_folds() -> None:
    """fold_loss at limit 1 against model.folds_onto_itself (an independent test over
    64 profile points): random bent primitives of several profiles, bends and scalings;
    zero for every primitive that does not fold, positive for one that folds by more
    than the sampling can blur."""
    from sweepedit.fitting.losses import fold_loss
    from sweepedit.fitting.params import ParamLayout
    from sweepedit.fitting.sweepers import AnalyticSweeper
    from sweepedit.geometry.model import SweepPrimitive, folds_onto_itself, primitive_fold_vectors
    from sweepedit.geometry.sweep import scaling_factor

    rng = np.random.default_rng(5)
    layout = ParamLayout(5, 3)
    sweeper = AnalyticSweeper(stations=256, layout=layout)
    t = torch.linspace(0.0, 1.0, 256, dtype=torch.float64)
    seen = {True: 0, False: 0}
    for _ in range(60):
        cps = np.linspace([-0.3, 0.0, 0.0], [0.3, 0.0, 0.0], 5) + rng.normal(0.0, 0.06, (5, 3))
        p = SweepPrimitive(cps, a=float(rng.uniform(0.02, 0.15)),
                           b=float(rng.uniform(0.02, 0.15)), degree=float(rng.uniform(1.2, 5.0)),
                           scaling=tuple(rng.uniform(-0.3, 0.3, 3)))
        params = layout.from_primitives([p], dtype=torch.float64)
        bend = sweeper._stations(params[None])["bend"]
        scale = scaling_factor(params[:, layout.scaling_slice], t)
        loss = float(fold_loss(bend, scale, params[:, layout.profile_slice], limit=1.0))
        folds = folds_onto_itself(p, samples=256)
        # The support over 64 profile points is a hair below the exact one: skip the
        # primitives within 1% of folding, where the two may disagree.
        q = primitive_fold_vectors(p, np.linspace(0.0, 1.0, 256))
        x, y = np.abs(q[:, 0]) * p.a, np.abs(q[:, 1]) * p.b
        e = p.degree / (p.degree - 1.0)
        margin = np.max((x**e + y**e) ** (1.0 / e))
        if abs(margin - 1.0) < 0.01:
            continue
        assert (loss > 0.0) == folds, (margin, loss)
        seen[folds] += 1
    assert seen[True] >= 5 and seen[False] >= 5


def test_outside_axis_loss_is_the_distance_beyond_the_margin() -> None:
    """A box of cells; points inside it cost nothing, points 10 and 11 cells beyond a face
    cost that distance less the margin, and their gradient points away from the box."""
    from scipy import ndimage as ndi

    res = 64
    occupancy = np.zeros((res, res, res), dtype=bool)
    occupancy[10:30, 20:40, 30:50] = True
    outside = torch.as_tensor(ndi.distance_transform_edt(~occupancy) / res)

    def centre(*index: int) -> list[float]:
        return [(i + 0.5) / res - 0.5 for i in index]

    axes = torch.tensor([[centre(20, 30, 40), centre(39, 30, 40), centre(20, 50, 40),
                          centre(20, 30, 60)]], dtype=torch.float64, requires_grad=True)
    margin = 2.0 / res
    loss = outside_axis_loss(axes, outside, margin)
    beyond = np.array([0.0, 10.0, 11.0, 11.0]) / res
    want = np.mean(np.maximum(beyond - margin, 0.0))
    assert float(loss.detach()) == pytest.approx(want, rel=1e-6)
    loss.backward()
    grad = axes.grad[0].numpy() * 4  # d loss / d point, times the 4 points of the mean
    np.testing.assert_allclose(grad, [[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], atol=1e-9)
    assert float(outside_axis_loss(axes[:, :1], outside, margin).detach()) == 0.0
