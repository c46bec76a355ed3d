"""The heat map's signed distances against independent truths: a capped cylinder's
analytic distance, and the exact solid union mesh (manifold3d) with trimesh's
point-triangle distances."""

from __future__ import annotations

import numpy as np
import pytest

from sweepedit.analysis.heatmap import HeatMapper, boundary_samples, signed_distances
from sweepedit.geometry.inside import inside_union
from sweepedit.geometry.model import SweepPrimitive

L, R = 0.3, 0.1  # half length and radius of the test cylinder along x


def cylinder() -> SweepPrimitive:
    # A straight axis, a circular profile (degree 2, a = b) and no scaling: a capped
    # cylinder from x = -L to L.
    return SweepPrimitive(control_points=[[-L, 0, 0], [0, 0, 0], [L, 0, 0]], a=R, b=R,
                          degree=2.0)


def cylinder_distance(points: np.ndarray) -> np.ndarray:
    """Analytic signed distance to the capped cylinder (> 0 outside)."""
    x = np.abs(points[:, 0])
    rho = np.hypot(points[:, 1], points[:, 2])
    inside = (x <= L) & (rho <= R)
    outside = np.hypot(np.maximum(x - L, 0.0), np.maximum(rho - R, 0.0))
    return np.where(inside, -np.minimum(L - x, R - rho), outside)


def query_points(rng: np.random.Generator) -> np.ndarray:
    """Points all over the cube and many within 0.02 of the cylinder's surface."""
    far = rng.uniform(-0.5, 0.5, (4000, 3))
    theta = rng.uniform(0, 2 * np.pi, 4000)
    x = rng.uniform(-L - 0.02, L + 0.02, 4000)
    rho = R + rng.uniform(-0.02, 0.02, 4000)
    near = np.stack([x, rho * np.cos(theta), rho * np.sin(theta)], axis=1)
    return np.concatenate([far, near])


def test_cylinder_matches_the_analytic_distance() -> None:
    points = query_points(np.random.default_rng(0))
    truth = cylinder_distance(points)
    got = signed_distances(points, [cylinder()])
    assert np.array_equal(got > 0, truth > 0)  # missed vs excess: the exact inside test
    err = np.abs(got - truth)
    near = np.abs(truth) < 0.02
    # Near the surface the tangent planes leave ~1e-3 at most (at the rims); far away
    # the nearest-sample search may be up to 10 % off.
    assert err[near].max() < 1.5e-3
    assert np.median(err[near]) < 1e-4
    assert np.all(err <= 0.1 * np.abs(truth) + 1.5e-3)


def test_overlapping_primitives_match_the_exact_union_mesh() -> None:
    trimesh = pytest.importorskip("trimesh")
    from sweepedit.geometry.solid import solid_union

    prims = [cylinder(),
             SweepPrimitive(control_points=[[0.1, -0.35, 0.0], [0.15, 0.0, 0.05],
                                            [0.1, 0.35, 0.0]], a=0.08, b=0.05, degree=3.0,
                            scaling=(0.2, -0.1))]
    rng = np.random.default_rng(1)
    union = solid_union(prims, 128, 96)
    # Points near the union's surface (inside and out) and some far away.
    on, _ = trimesh.sample.sample_surface(union.to_trimesh(), 1500, seed=2)
    points = np.concatenate([on + rng.normal(0, 0.015, on.shape),
                             rng.uniform(-0.5, 0.5, (500, 3))])
    _, unsigned, _ = trimesh.proximity.closest_point(union.to_trimesh(), points)
    truth = np.where(inside_union(points, prims), -unsigned, unsigned)
    got = signed_distances(points, prims)
    assert np.array_equal(got > 0, truth > 0)
    err = np.abs(got - truth)
    # Where the two primitives cross, the boundary's crease lies between samples: up to
    # a sample spacing (~0.01) off there; elsewhere as on the cylinder.
    assert np.all(err <= 0.1 * np.abs(truth) + 0.01)
    assert np.mean(err <= 0.1 * np.abs(truth) + 2e-3) > 0.98
    assert np.median(err) < 2e-4


def test_reuse_after_edits_gives_exactly_a_fresh_computation() -> None:
    rng = np.random.default_rng(3)
    points = rng.uniform(-0.5, 0.5, (3000, 3))
    prims = [cylinder(), SweepPrimitive(control_points=[[0, -0.3, 0], [0, 0, 0.02],
                                                         [0, 0.3, 0]], a=0.07, b=0.07)]
    mapper = HeatMapper(points)
    first = mapper.compute(prims)
    assert mapper.searched == len(points)
    # Small moves, a move that buries the second primitive in the first and one that
    # brings it out again, an undo: each time what a fresh mapper computes.
    for shift in ([0.01, 0.0, 0.0], [0.0, 0.005, 0.01], [0.0, 0.0, -0.03], [0.3, 0.0, 0.0],
                  [-0.3, 0.0, 0.0], [0.0, 0.0, 0.0]):
        moved = prims[1].copy()
        moved.control_points = moved.control_points + np.array(shift)
        again = mapper.compute([prims[0], moved])
        fresh = HeatMapper(points).compute([prims[0], moved])
        assert np.array_equal(again.distance, fresh.distance)
        assert np.array_equal(again.inside, fresh.inside)
        if shift == [0.01, 0.0, 0.0]:
            assert mapper.searched < len(points) / 2  # only the vertices near the edit
    assert np.array_equal(mapper.compute(prims).distance, first.distance)


def test_duplicates_empty_input_and_bad_shapes() -> None:
    points = query_points(np.random.default_rng(4))[:500]
    single = signed_distances(points, [cylinder()])
    # An exact duplicate adds no boundary and hides none.
    assert np.array_equal(signed_distances(points, [cylinder(), cylinder()]), single)
    empty = HeatMapper(points).compute([])
    assert np.all(np.isinf(empty.distance)) and not empty.inside.any()
    with pytest.raises(ValueError, match=r"\(N, 3\)"):
        HeatMapper(np.zeros((4, 2)))
    s = boundary_samples(cylinder())
    assert s.points.shape[1] == 3 and s.normals.shape == (len(s.points), 2, 3)
    assert np.allclose(np.linalg.norm(s.normals, axis=2), 1.0)
