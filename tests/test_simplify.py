"""A primitive in another layout (more or fewer control points and scaling terms): exact
where the spline spaces nest, the simplest layout within a tolerance otherwise, judged
against independent truths (the exact inside test, densely sampled surfaces)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

from sweepedit.geometry.inside import inside_primitive
from sweepedit.geometry.mesher import sweep_mesh
from sweepedit.geometry.model import SweepPrimitive
from sweepedit.geometry.simplify import (
    layout_choices,
    relayout,
    simplify_primitive,
    surface_deviation,
)
from sweepedit.geometry.sweep import axis_points


def _bent() -> SweepPrimitive:
    return SweepPrimitive(np.array([[-0.3, -0.1, 0.0], [0.0, 0.25, 0.05], [0.3, -0.05, 0.1]]),
                          a=0.06, b=0.04, degree=3.0, scaling=(0.3, -0.4))


def _wave(n: int = 8) -> SweepPrimitive:
    """An axis that swings twice: no quadratic Bezier follows it."""
    x = np.linspace(-0.4, 0.4, n)
    cps = np.stack([x, 0.15 * np.sin(2.5 * np.pi * x / 0.4), 0.02 * x], axis=1)
    return SweepPrimitive(cps, a=0.04, b=0.04, degree=2.0, scaling=(0.2, -0.3, 0.1))


def _surface_points(p: SweepPrimitive, stations: int = 160, ring: int = 96) -> np.ndarray:
    return sweep_mesh(p, stations, ring).vertices


@pytest.mark.parametrize("n, k", [(4, 2), (6, 3), (8, 2), (10, 4)])
def test_more_control_points_and_terms_keep_the_solid_exactly(n: int, k: int) -> None:
    p = _bent()
    q = relayout(p, n, k)
    assert q.n_control_points == n and len(q.scaling) == k
    assert surface_deviation(p, q) < 1e-9
    # The exact inside test agrees everywhere but on the surface itself.
    pts = np.random.default_rng(1).uniform(-0.5, 0.5, (40_000, 3))
    assert np.array_equal(inside_primitive(pts, p), inside_primitive(pts, q))


def test_a_promoted_primitive_simplifies_back_to_its_own_layout() -> None:
    p = _bent()
    q = simplify_primitive(relayout(p, 8, 4), tolerance=1e-6)
    assert (q.n_control_points, len(q.scaling)) == (3, 2)
    np.testing.assert_allclose(q.control_points, p.control_points, atol=1e-9)
    np.testing.assert_allclose(q.scaling, p.scaling, atol=1e-9)
    assert (q.a, q.b, q.degree, q.name, q.color) == (p.a, p.b, p.degree, p.name, p.color)


def test_a_wavy_axis_keeps_its_control_points_at_a_tight_tolerance() -> None:
    p = _wave()
    assert simplify_primitive(p, tolerance=0.002).n_control_points >= 6
    # Loose enough, the simplest layout is taken.
    loose = simplify_primitive(p, tolerance=0.5)
    assert (loose.n_control_points, len(loose.scaling)) == (3, 2)


@pytest.mark.parametrize("seed", range(4))
def test_a_simplified_surface_stays_within_the_tolerance(seed: int) -> None:
    """Random curved primitives of 8 control points and 3 scaling terms: the simplified
    one's densely sampled surface lies within the tolerance (plus the samples' spacing)
    of the original's, both ways, and its solid is valid."""
    rng = np.random.default_rng(seed)
    t = np.linspace(0.0, 1.0, 8)
    base = np.stack([0.7 * t - 0.35, 0.1 * np.sin(3 * t + seed), 0.08 * np.cos(2 * t)], axis=1)
    p = SweepPrimitive(base + rng.normal(0.0, 0.01, base.shape), a=0.05, b=0.03, degree=2.5,
                       scaling=tuple(rng.uniform(-0.15, 0.15, 3)))
    tolerance = 0.004
    q = simplify_primitive(p, tolerance)
    q.validate()
    assert q.n_control_points <= p.n_control_points and len(q.scaling) <= len(p.scaling)
    a, b = _surface_points(p), _surface_points(q)
    spacing = 0.006  # the meshes' largest edge here is below this
    assert cKDTree(b).query(a)[0].max() <= tolerance + spacing
    assert cKDTree(a).query(b)[0].max() <= tolerance + spacing


def test_layouts_are_offered_simplest_first_and_never_beyond_the_primitive() -> None:
    choices = layout_choices(_wave())  # 8 control points, 3 terms
    assert choices[0] == (3, 2) and choices[-1] == (8, 3)
    assert all(n <= 8 and k <= 3 for n, k in choices)
    costs = [3 * n + k for n, k in choices[:-1]]
    assert costs == sorted(costs)
    # Only axes that go back into 8 control points exactly: 1, 2 or 3 segments of 6.
    assert {n for n, _ in choices} == {3, 4, 5, 8}
    assert layout_choices(SweepPrimitive(np.eye(3) * 0.2, scaling=()))[-1] == (3, 0)


def test_relayout_keeps_the_axis_place_along_t() -> None:
    """The scaling f(t) stays on the same part of the axis: the axis point at each t
    is kept (the least squares run at the same parameter)."""
    p = _bent()
    q = relayout(p, 6, 2)
    t = np.linspace(0.0, 1.0, 33)
    np.testing.assert_allclose(axis_points(q.control_points[None], t),
                               axis_points(p.control_points[None], t), atol=1e-12)
