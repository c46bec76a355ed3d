"""Control-point insertion and deletion and mirroring, against independent truths: scipy's
B-splines, the old axis sampled densely (brute-force distances), the exact inside test of
mirrored points."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, given, settings
from scipy.interpolate import BSpline
from strategies import primitives

from sweepedit.geometry.axis_edit import (
    bspline_basis,
    delete_control_point,
    insert_control_point,
    is_mirror_pair,
    mirror_primitive,
)
from sweepedit.geometry.inside import inside_primitive
from sweepedit.geometry.model import SweepPrimitive
from sweepedit.geometry.sweep import axis_points, scaling_factor, sweep_surface

DENSE = np.linspace(0.0, 1.0, 3001)
ASYMMETRIC_3 = np.array([[-0.4, -0.1, 0.05], [-0.1, 0.3, 0.2], [0.3, 0.05, -0.1]])


def dense_axis(cp: np.ndarray, t: np.ndarray = DENSE) -> np.ndarray:
    return axis_points(np.asarray(cp)[None], t)[0]


def hausdorff(a: np.ndarray, b: np.ndarray) -> float:
    """Brute-force symmetric Hausdorff distance of two point sets (M, 3), (N, 3)."""
    d = np.sqrt(((a[:, None, :] - b[None, :, :]) ** 2).sum(-1))
    return float(max(d.min(1).max(), d.min(0).max()))


def length(points: np.ndarray) -> float:
    return float(np.linalg.norm(np.diff(points, axis=0), axis=1).sum())


def wiggly(rng: np.random.Generator, n: int) -> SweepPrimitive:
    cps = np.cumsum(rng.normal(size=(n, 3)) * 0.12, axis=0)
    return SweepPrimitive(cps - cps.mean(0), a=0.05, b=0.03, degree=2.5,
                          scaling=(float(rng.uniform(-0.4, 0.4)), float(rng.uniform(-0.3, 0.3))))


def test_basis_is_scipys_clamped_uniform_quadratic_bspline() -> None:
    rng = np.random.default_rng(1)
    t = np.linspace(0.0, 1.0, 777)
    for n in (3, 4, 7):
        cp = rng.uniform(-0.5, 0.5, (n, 3))
        knots = np.concatenate([[0.0, 0.0], np.linspace(0.0, 1.0, n - 1), [1.0, 1.0]])
        spline = BSpline(knots, cp, 2)
        assert np.allclose(bspline_basis(n, t) @ cp, spline(t), atol=1e-13)
        inner = t[(t > 0) & (t < 1) & (np.abs(t * (n - 2) - np.round(t * (n - 2))) > 1e-6)]
        assert np.allclose(bspline_basis(n, inner, 1) @ cp, spline.derivative()(inner),
                           atol=1e-11)
    with pytest.raises(ValueError):
        bspline_basis(2, t)


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.filter_too_much])
@given(primitives)
def test_three_to_four_is_exact_curve_parameter_and_surface(p: SweepPrimitive) -> None:
    p = p.copy()
    p.control_points = p.control_points[:3]
    d0, d1 = np.diff(p.control_points, axis=0)
    # An axis that folds back exactly onto itself has no tangent at the fold, and each
    # version picks some frame there (sweep.py's fold rule): not a question of insertion.
    assume(np.linalg.norm(np.cross(d0, d1)) > 1e-6 * np.linalg.norm(d0) * np.linalg.norm(d1)
           or float(d0 @ d1) > 0.0)
    q = insert_control_point(p, 0.8)  # whatever the click, 3 -> 4 is knot insertion at 1/2
    assert q.n_control_points == 4
    assert q.scaling == p.scaling and q.profile.tolist() == p.profile.tolist()
    # The same curve at the same parameter, sampled densely.
    assert np.max(np.abs(dense_axis(q.control_points) - dense_axis(p.control_points))) < 1e-12
    # And the same swept surface (frames included) away from the folded degenerate cases.
    t = np.linspace(0.0, 1.0, 257)
    theta = np.linspace(0.0, 2 * np.pi, 32, endpoint=False)
    before = sweep_surface(*p.batch_arrays(), t, theta)
    after = sweep_surface(*q.batch_arrays(), t, theta)
    assert np.max(np.abs(after - before)) < 1e-12


def test_an_axis_that_is_one_quadratic_stays_exact_at_any_count() -> None:
    """A fitted 3-point axis is one quadratic: the uniform spline with any number of
    points holds it at the same parameter, so insertions and deletions are exact and the
    scaling stays."""
    p = SweepPrimitive(ASYMMETRIC_3, scaling=(0.4, -0.3))
    q = p
    for n in (4, 5, 6):
        q = insert_control_point(q, 0.37)
        assert q.n_control_points == n and q.scaling == p.scaling
        assert np.max(np.abs(dense_axis(q.control_points) - dense_axis(p.control_points))) \
            < 1e-12
    for index in (3, 1, 2):
        q = delete_control_point(q, index)
    assert q.scaling == p.scaling
    assert np.allclose(q.control_points, p.control_points, atol=1e-12)


def test_other_insertions_stay_within_one_percent_and_the_scaling_follows() -> None:
    rng = np.random.default_rng(7)
    for trial in range(24):
        p = wiggly(rng, int(rng.integers(4, 8)))
        click = float(rng.uniform())
        q = insert_control_point(p, click)
        assert q.n_control_points == p.n_control_points + 1
        old, new = dense_axis(p.control_points, DENSE[::2]), dense_axis(q.control_points,
                                                                        DENSE[::2])
        assert hausdorff(old, new) <= 0.01 * length(dense_axis(p.control_points)), trial
        assert np.array_equal(q.control_points[[0, -1]], p.control_points[[0, -1]])
        # The scaling follows the axis: at each new point, f is (nearly) the old f at the
        # old axis' nearest point (independent of the arclength matching used inside).
        nearest = np.argmin(((new[:, None] - old[None]) ** 2).sum(-1), axis=1)
        f_new = scaling_factor(q.scaling_array, DENSE[::2])[0]
        f_old = scaling_factor(p.scaling_array, DENSE[::2][nearest])[0]
        assert np.max(np.abs(f_new - f_old)) < 0.03, trial
        q.validate()


def test_the_inserted_point_goes_where_the_click_was() -> None:
    p = SweepPrimitive(np.array([[-0.4, 0, 0], [-0.2, 0.1, 0], [0.0, 0.0, 0], [0.2, -0.1, 0],
                                 [0.4, 0.0, 0.0]]))
    q_left, q_right = insert_control_point(p, 0.1), insert_control_point(p, 0.9)
    # More points end up on the clicked side (x < 0 resp. x > 0) than before.
    assert (q_left.control_points[:, 0] < -0.01).sum() > (p.control_points[:, 0] < -0.01).sum()
    assert (q_right.control_points[:, 0] > 0.01).sum() > (p.control_points[:, 0] > 0.01).sum()


def test_delete_keeps_at_least_three_and_recovers_an_exact_insertion() -> None:
    rng = np.random.default_rng(3)
    p = wiggly(rng, 3)
    with pytest.raises(ValueError):
        delete_control_point(p, 1)
    q = insert_control_point(p)
    for index in (1, 2):  # either interior point: the 3-point curve is the exact best fit
        r = delete_control_point(q, index)
        assert r.n_control_points == 3
        assert np.allclose(r.control_points, p.control_points, atol=1e-9)
        assert np.allclose(r.scaling, p.scaling, atol=1e-9)
    # An end point is dropped: the axis now ends at its neighbour.
    five = wiggly(rng, 5)
    r = delete_control_point(five, 0)
    assert np.array_equal(r.control_points, five.control_points[1:])
    with pytest.raises(IndexError):
        delete_control_point(five, 5)


def test_delete_is_the_least_squares_best() -> None:
    """No nearby 3-point curve fits the 4-point axis better (in the mean squared distance
    of dense samples to the other curve) than the deletion's result, up to the 1% that an
    iterative fit leaves; a plain fit at the old parameters is well beyond that."""
    rng = np.random.default_rng(11)
    p = wiggly(rng, 4)
    r = delete_control_point(p, 2)
    old = dense_axis(p.control_points, DENSE[::3])

    def mean_sq(cp: np.ndarray) -> float:
        new = dense_axis(cp, DENSE[::3])
        return float(((old[:, None] - new[None]) ** 2).sum(-1).min(1).mean())

    best = mean_sq(r.control_points)
    for _ in range(30):
        trial = r.control_points.copy()
        trial[1] += rng.normal(size=3) * 0.01
        assert mean_sq(trial) >= 0.99 * best
    basis = bspline_basis(3, DENSE)  # least squares at the old parameters, ends kept
    inner = np.linalg.lstsq(basis[:, 1:2], dense_axis(p.control_points) - basis[:, [0, 2]]
                            @ p.control_points[[0, -1]], rcond=None)[0]
    plain = np.vstack([p.control_points[0], inner, p.control_points[-1]])
    assert mean_sq(plain) > 1.05 * best


def mirror_grid_error(p: SweepPrimitive, q: SweepPrimitive, axis: int) -> float:
    """Max distance between q's surface grid and p's mirrored grid, matching profile
    angles theta -> -theta or pi - theta (the mirror flips U or V)."""
    t = np.linspace(0.0, 1.0, 129)
    k = np.arange(64)
    # Half a step off the axes: where cos or sin is 0 the profile's sgn() meets rounding
    # (sgn(cos(pi/2)) = +1 but sgn(cos(3 pi/2)) = -1), an artefact of the angles, not of
    # the surface. These angles map onto each other under theta -> -theta and pi - theta.
    theta = 2 * np.pi * (k + 0.5) / 64
    mirrored = sweep_surface(*p.batch_arrays(), t, theta)[0].copy()
    mirrored[..., axis] *= -1.0
    surf = sweep_surface(*q.batch_arrays(), t, theta)[0]
    return min(float(np.max(np.abs(surf[:, (63 - k) % 64] - mirrored))),
               float(np.max(np.abs(surf[:, (31 - k) % 64] - mirrored))))


@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.filter_too_much])
@given(primitives)
def test_mirror_is_exact(p: SweepPrimitive) -> None:
    for axis in range(3):
        q = mirror_primitive(p, axis)
        expected = p.control_points.copy()
        expected[:, axis] = -expected[:, axis]
        assert np.array_equal(q.control_points, expected)
        assert mirror_grid_error(p, q, axis) < 1e-12
        assert is_mirror_pair(p, q, axis) and is_mirror_pair(q, p, axis)


def test_mirror_exact_along_z_and_by_the_inside_test() -> None:
    # Tangent along z: the initial frame's fallback branch, mirrored consistently.
    along_z = SweepPrimitive(np.array([[0.1, 0.0, -0.3], [0.1, 0.0, 0.0], [0.2, 0.15, 0.3]]),
                             a=0.12, b=0.04, degree=3.0, scaling=(0.3, -0.2))
    rng = np.random.default_rng(5)
    bent = SweepPrimitive(np.array([[-0.3, -0.1, 0.05], [-0.05, 0.3, 0.2], [0.25, 0.1, -0.1],
                                    [0.3, -0.25, 0.1]]), a=0.09, b=0.03, degree=1.2,
                          scaling=(-0.2, 0.1))
    points = rng.uniform(-0.45, 0.45, (20000, 3))
    for p in (along_z, bent):
        inside = inside_primitive(points, p)
        assert 100 < inside.sum() < 19000
        for axis in range(3):
            q = mirror_primitive(p, axis)
            assert mirror_grid_error(p, q, axis) < 1e-12
            reflected = points.copy()
            reflected[:, axis] *= -1.0
            assert np.array_equal(inside_primitive(reflected, q), inside)
    assert not is_mirror_pair(bent, bent, 0)
