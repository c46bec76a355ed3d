"""The sweep math, the mesher and the exact inside test against independent truths."""

from __future__ import annotations

import igl
import numpy as np
import pytest
import torch
from hypothesis import HealthCheck, example, given, settings
from scipy.interpolate import BSpline
from scipy.special import gamma
from strategies import is_valid, primitives

from sweepedit.errors import InvalidPrimitiveError
from sweepedit.geometry.inside import grid_points, inside_primitive, inside_union
from sweepedit.geometry.mesher import sweep_mesh, sweep_meshes, union_mesh
from sweepedit.geometry.model import SweepPrimitive, folds_onto_itself
from sweepedit.geometry.sweep import axis_frames, axis_points, initial_frame


def superellipse_area(a: float, b: float, d: float) -> float:
    return 4.0 * a * b * gamma(1.0 + 1.0 / d) ** 2 / gamma(1.0 + 2.0 / d)


def straight(n: int = 3, length: float = 0.6, a: float = 0.1, b: float = 0.05, d: float = 2.0,
             direction=(0.3, -0.2, 0.9)) -> SweepPrimitive:
    u = np.asarray(direction, float) / np.linalg.norm(direction)
    cps = (np.linspace(-0.5, 0.5, n)[:, None] * length) * u
    return SweepPrimitive(cps, a=a, b=b, degree=d, scaling=(0.0, 0.0))


@pytest.mark.parametrize("d", [0.3, 0.5, 1.0, 2.0, 3.3, 5.0])
@pytest.mark.parametrize("n", [3, 5])
def test_straight_sweep_volume_is_length_times_profile_area(d: float, n: int) -> None:
    p = straight(n=n, d=d)
    mesh = sweep_mesh(p, stations=3, profile_points=1024).to_trimesh()
    assert mesh.is_watertight and mesh.is_winding_consistent
    expected = 0.6 * superellipse_area(0.1, 0.05, d)
    assert mesh.volume == pytest.approx(expected, rel=0.01)


def test_volume_with_linear_scaling_is_integral_of_scaled_area() -> None:
    # f(t) = 1 + s1 t: volume = L * A * ∫ f^2 dt = L * A * (1 + s1 + s1^2 / 3)
    p = straight(d=2.0)
    p.scaling = (0.4,)
    mesh = sweep_mesh(p, stations=200, profile_points=512).to_trimesh()
    expected = 0.6 * np.pi * 0.1 * 0.05 * (1 + 0.4 + 0.16 / 3)
    assert mesh.volume == pytest.approx(expected, rel=0.01)


@pytest.mark.parametrize("n", [3, 4, 5, 8])
def test_axis_matches_scipy_clamped_bspline(n: int) -> None:
    rng = np.random.default_rng(n)
    cps = rng.uniform(-0.5, 0.5, (1, n, 3))
    knots = np.concatenate([[0, 0], np.linspace(0, 1, n - 1), [1, 1]])
    ref = BSpline(knots, cps[0], 2)
    t = np.linspace(0, 1, 301)
    np.testing.assert_allclose(axis_points(cps, t)[0], ref(t), atol=1e-12)
    tangent = ref.derivative()(t)
    tangent /= np.linalg.norm(tangent, axis=1, keepdims=True)
    np.testing.assert_allclose(axis_frames(cps, t).T[0], tangent, atol=1e-9)


def test_initial_frame_follows_the_official_convention() -> None:
    T0 = np.array([[0.6, 0.0, 0.8]])
    U0, V0 = initial_frame(T0)
    W = np.array([-T0[0, 1], T0[0, 0], 0.0])
    V = np.cross(T0[0], W)
    V /= np.linalg.norm(V)
    np.testing.assert_allclose(V0[0], V, atol=1e-12)
    np.testing.assert_allclose(U0[0], np.cross(V, T0[0]), atol=1e-12)
    # tangent along z: W falls back to (0, 1, 0)
    U0, V0 = initial_frame(np.array([[0.0, 0.0, 1.0]]))
    np.testing.assert_allclose(V0[0], [-1.0, 0.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(U0[0], [0.0, 1.0, 0.0], atol=1e-12)


def test_numpy_and_torch_give_the_same_frames() -> None:
    rng = np.random.default_rng(7)
    cps = rng.uniform(-0.5, 0.5, (4, 5, 3))
    t = np.linspace(0, 1, 50)
    ref = axis_frames(cps, t)
    got = axis_frames(torch.tensor(cps), torch.tensor(t))
    for r, g in zip(ref, got, strict=True):
        np.testing.assert_allclose(g.numpy(), r, atol=1e-12)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.filter_too_much])
@given(primitives)
def test_random_sweep_meshes_are_closed_outward_solids(p: SweepPrimitive) -> None:
    mesh = sweep_mesh(p, stations=48, profile_points=32).to_trimesh()
    assert mesh.is_watertight
    assert mesh.is_winding_consistent
    assert mesh.volume > 0.0


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.filter_too_much])
@given(primitives)
# An axis that runs out and almost exactly back (found by hypothesis): the tangent turns
# by nearly pi inside one segment, where the plain Rodrigues rotation loses precision.
@example(SweepPrimitive([[0.0, 0.25139703452548523, 0.0], [0.0, 0.0, 0.0625],
                         [0.0, 0.25, 0.0]], a=0.5, b=0.5, degree=1.0))
# Up and straight back down, a hair off in x: the frame turns about z at the tip.
@example(SweepPrimitive([[6.103515625e-05, 0.0, 0.0], [0.0, 0.5, 0.0], [0.0, 0.0, 0.0]],
                        a=0.5, b=0.5, degree=1.0))
# Up and exactly back: the derivative at the cusp is tiny but its tangent must be unit.
@example(SweepPrimitive([[0.0, 0.0, 1.192092896e-07], [0.0, 0.0, 0.5], [0.0, 0.0, 0.0]],
                        a=0.5, b=0.5, degree=1.0))
# Out and exactly back along a line: past the cusp the turn's axis is rounding noise.
@example(SweepPrimitive([[0.0, 0.0, 0.0], [0.5, 0.375, 0.0], [0.0, 0.0, 0.0]],
                        a=0.5, b=0.5, degree=1.0))
# Within 1e-6 of an exact fold: the fold's frame must still be orthonormal.
@example(SweepPrimitive([[0.0, 0.0, 5.960464477539063e-08], [0.0, 0.5, 0.0], [0.0, 0.0, 0.0]],
                        a=0.5, b=0.5, degree=1.0))
# A hairpin whose plane's normal is 1e-12 long: still the exact axis of the turn.
@example(SweepPrimitive([[0.5, 0.0, 0.0], [0.0, 0.0, 0.0], [0.5, 1e-12, 0.0]],
                        a=0.5, b=0.5, degree=1.0))
# Out and back 2e-11 off in x: d0 x d1 cancels to noise (frames 1e-6 off orthonormal);
# d0 x chord does not.
@example(SweepPrimitive([[2.393817354209163e-11, 0.5, 0.0], [0.5, 0.0, 0.451171875],
                         [0.0, 0.5, 0.0]], a=0.5, b=0.5, degree=1.0))
def test_frames_are_orthonormal_and_do_not_twist(p: SweepPrimitive) -> None:
    t = np.linspace(0, 1, 401)
    U, V, T = (x[0] for x in axis_frames(p.control_points[None], t)[1:])
    eye = np.stack([U, V, T], axis=1) @ np.stack([U, V, T], axis=2)
    np.testing.assert_allclose(eye, np.broadcast_to(np.eye(3), eye.shape), atol=1e-9)
    np.testing.assert_allclose(np.cross(U, V), T, atol=1e-9)
    # Rotation-minimising: the same frames as an independent double-reflection
    # transport (Wang et al. 2008) along a dense sampling of the axis. A step over which
    # the tangent turns by more than pi/2 is a hairpin sharper than the sampling, which
    # the transport cannot resolve: it restarts from our frame after it (the hairpin
    # itself is checked exactly by the planar invariant below and by the test after).
    dense = np.linspace(0, 1, 4001)
    pts = axis_points(p.control_points[None], dense)[0]
    dense_frames = axis_frames(p.control_points[None], dense)
    tangents, ours = dense_frames.T[0], dense_frames.U[0]
    u = ours[0]
    ref = [u]
    for i in range(len(dense) - 1):
        v1 = pts[i + 1] - pts[i]
        c1 = v1 @ v1
        if tangents[i] @ tangents[i + 1] < 0.0:
            u = ours[i + 1]
        elif c1 > 1e-20:
            u_l = u - (2 / c1) * (v1 @ u) * v1
            t_l = tangents[i] - (2 / c1) * (v1 @ tangents[i]) * v1
            v2 = tangents[i + 1] - t_l
            c2 = v2 @ v2
            u = u_l - (2 / c2) * (v2 @ u_l) * v2 if c2 > 1e-20 else u_l
        ref.append(u)
    assert np.abs(np.einsum("ij,ij->i", np.asarray(ref), ours) - 1.0).max() < 1e-3
    # Three control points make one planar segment: its rotation-minimising frame turns
    # about the plane's normal only, so the frame's components along it stay constant,
    # however sharp the hairpin.
    if len(p.control_points) == 3:
        c = p.control_points
        normal = np.cross(c[1] - c[0], c[2] - c[1])
        scale = np.linalg.norm(c[1] - c[0]) * np.linalg.norm(c[2] - c[1])
        if np.linalg.norm(normal) > 1e-9 * scale:
            normal /= np.linalg.norm(normal)
            np.testing.assert_allclose(U @ normal, U[0] @ normal, atol=1e-6)
            np.testing.assert_allclose(V @ normal, V[0] @ normal, atol=1e-6)


@pytest.mark.parametrize("offset", [1e-3, 1e-6, 1e-9, 1e-12])
def test_hairpin_frame_turns_about_the_plane_normal(offset: float) -> None:
    # Out along -x and back to (0.5, offset, 0): the frame turns by nearly pi about z, so
    # V = z stays (the initial frame of docs/primitive.md for a start along -x) and U = V x T.
    cps = np.array([[[0.5, 0.0, 0.0], [0.0, 0.0, 0.0], [0.5, offset, 0.0]]])
    frames = axis_frames(cps, np.array([0.0, 1.0]))
    end_tangent = np.array([0.5, offset, 0.0]) / np.hypot(0.5, offset)
    np.testing.assert_allclose(frames.V[0], [[0.0, 0.0, 1.0], [0.0, 0.0, 1.0]], atol=1e-12)
    np.testing.assert_allclose(frames.U[0, 1], np.cross([0.0, 0.0, 1.0], end_tangent),
                               atol=1e-12)


def test_exact_fold_keeps_u_and_flips_v() -> None:
    # Out and exactly back along a line: every rotation by pi about an axis normal to
    # the tangent is minimal; sweep.py takes the one about U.
    cps = np.array([[[0.0, 0.0, 0.0], [0.5, 0.375, 0.0], [0.0, 0.0, 0.0]]])
    frames = axis_frames(cps, np.linspace(0.0, 1.0, 101))
    np.testing.assert_allclose(frames.U[0], np.broadcast_to(frames.U[0, 0], (101, 3)), atol=1e-12)
    np.testing.assert_allclose(frames.V[0, -1], -frames.V[0, 0], atol=1e-12)


def _random_unfolded(rng: np.random.Generator) -> SweepPrimitive:
    while True:
        p = SweepPrimitive(rng.uniform(-0.5, 0.5, (rng.integers(3, 6), 3)),
                           a=rng.uniform(0.01, 0.3), b=rng.uniform(0.01, 0.3),
                           degree=rng.uniform(0.3, 5.0),
                           scaling=tuple(rng.uniform(-0.5, 0.5, 2)))
        if is_valid(p) and not folds_onto_itself(p):
            return p


def test_mesh_agrees_with_exact_inside_test() -> None:
    rng = np.random.default_rng(11)
    for _ in range(8):
        p = _random_unfolded(rng)
        mesh = sweep_mesh(p, stations=256, profile_points=256)
        lo, hi = mesh.vertices.min(0), mesh.vertices.max(0)
        q = rng.uniform(lo, hi, (30000, 3))
        by_mesh = igl.fast_winding_number(mesh.vertices, mesh.faces, q) > 0.5
        exact = inside_primitive(q, p)
        iou = (by_mesh & exact).sum() / max((by_mesh | exact).sum(), 1)
        assert iou >= 0.99, (p, iou)


def test_exact_inside_on_a_straight_box_sweep() -> None:
    # d large is close to a rectangle; points well inside / outside the box are exact.
    p = SweepPrimitive([[0, 0, -0.3], [0, 0, 0], [0, 0, 0.3]], a=0.2, b=0.1, degree=5.0,
                       scaling=())
    # axis along z: U = (0, 1, 0), V = (-1, 0, 0) (the official convention)
    inside = np.array([[0.0, 0.15, 0.0], [0.08, 0.0, 0.29], [0.0, -0.1, -0.29]])
    outside = np.array([[0.0, 0.21, 0.0], [0.11, 0.0, 0.0], [0.0, 0.0, 0.31],
                        [0.0, 0.0, -0.31], [0.15, 0.05, 0.0]])
    assert inside_primitive(inside, p).all()
    assert not inside_primitive(outside, p).any()


def test_exact_inside_follows_a_primitive_edited_in_place() -> None:
    # The inside test keeps tables of the primitives it has seen (by their values): an
    # edit in place, as the app makes, must be seen at once, and undone, give the same
    # answer as before.
    p = SweepPrimitive([[0, 0, -0.3], [0, 0, 0], [0, 0, 0.3]], a=0.2, b=0.1, degree=5.0,
                       scaling=())
    point = np.array([[0.0, 0.0, 0.35]])  # past the end cap at z = 0.3
    assert not inside_primitive(point, p).any()
    p.control_points[2, 2] = 0.4
    assert inside_primitive(point, p).all()
    p.a = 0.01
    assert not inside_primitive(np.array([[0.0, 0.15, 0.0]]), p).any()
    p.control_points[2, 2], p.a = 0.3, 0.2
    assert not inside_primitive(point, p).any()
    assert inside_primitive(np.array([[0.0, 0.15, 0.0]]), p).all()


def test_inside_union_is_the_or_of_primitives() -> None:
    rng = np.random.default_rng(3)
    prims = [_random_unfolded(rng) for _ in range(3)]
    q = grid_points(24)
    each = np.stack([inside_primitive(q, p) for p in prims])
    np.testing.assert_array_equal(inside_union(q, prims), each.any(axis=0))


def test_union_mesh_is_watertight_and_has_the_union_volume() -> None:
    a = straight(direction=(0, 0, 1), a=0.1, b=0.1)
    b = straight(direction=(1, 0, 0), a=0.1, b=0.1)
    u = union_mesh(sweep_meshes([a, b], stations=8, profile_points=128)).to_trimesh()
    assert u.is_watertight and u.is_winding_consistent
    va, vb = (sweep_mesh(p, 8, 128).to_trimesh().volume for p in (a, b))
    # two perpendicular cylinders of radius r overlap in a Steinmetz solid, 16 r^3 / 3
    assert u.volume == pytest.approx(va + vb - 16 * 0.1**3 / 3, rel=0.02)


@pytest.mark.parametrize(
    ("kwargs", "field"),
    [
        ({"a": 0.6}, "profile.a"),
        ({"b": float("nan")}, "profile.b"),
        ({"degree": 0.1}, "profile.degree"),
        ({"scaling": (0.7,)}, "scaling[0]"),
        ({"scaling": (-0.5, -0.5)}, "scaling"),
        ({"control_points": [[0, 0, 0], [1, 0, 0]]}, "control_points"),
        ({"control_points": [[0.1, 0, 0]] * 3}, "control_points"),
        ({"control_points": [[0, 0, 0], [np.inf, 0, 0], [1, 0, 0]]}, "control_points"),
    ],
)
def test_invalid_parameters_name_the_field(kwargs: dict, field: str) -> None:
    base = {"control_points": [[0, 0, 0], [0.1, 0, 0], [0.2, 0.1, 0]], "a": 0.1, "b": 0.1,
            "degree": 2.0, "scaling": (0.0, 0.0)}
    base.update(kwargs)
    with pytest.raises(InvalidPrimitiveError) as err:
        SweepPrimitive(**base).validate(index=4)
    assert err.value.field == field
    assert "primitive 5" in str(err.value) and field in str(err.value)  # index 4, counted from 1


def test_axis_that_folds_back_keeps_a_right_handed_frame() -> None:
    # up and straight back down: the tangent reverses at the cusp
    cps = np.array([[[0.0, 0.0, 0.0], [0.0, 0.0, 0.5], [0.0, 0.0, 0.0]]])
    U, V, T = axis_frames(cps, np.linspace(0, 1, 101))[1:]
    np.testing.assert_allclose(np.cross(U[0], V[0]), T[0], atol=1e-9)
    np.testing.assert_allclose(U[0], U[0, :1].repeat(101, 0), atol=1e-9)  # no twist
    p = SweepPrimitive(cps[0], a=0.1, b=0.1, degree=2.0)
    mesh = sweep_mesh(p, 64, 32).to_trimesh()
    assert mesh.is_watertight and mesh.is_winding_consistent and mesh.volume > 0


def test_the_inside_kernel_holds_the_plane_offset_of_the_sweep_math() -> None:
    # inside_kernel.py writes the axis point and unit tangent at t out for one point; it
    # must give sweep.py's h(t) = (p - s(t)).T(t), at joints between segments, at the
    # ends, and where the derivative vanishes (a cusp: the chord, then the first leg).
    from sweepedit.geometry.inside_kernel import _plane_offset_at
    from sweepedit.geometry.sweep import axis_points_tangents, bezier_segments

    rng = np.random.default_rng(7)
    axes = [rng.normal(0.0, 0.2, (n, 3)) for n in (3, 4, 6)]
    axes.append(np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.3, 0.1, 0.0]]))  # s'(0) = 0
    axes.append(np.array([[0.0, 0.0, 0.0], [0.3, 0.0, 0.0], [0.0, 0.0, 0.0]]))  # folds back
    for cps in axes:
        m = len(cps) - 2
        t = np.concatenate([[0.0, 1.0], np.arange(1, m) / m, rng.uniform(0.0, 1.0, 40)])
        points = rng.normal(0.0, 0.3, (len(t), 3))
        centres, tangents = (a[0] for a in axis_points_tangents(cps[None], t))
        expected = np.einsum("ij,ij->i", points - centres, tangents)
        p0, p1, p2 = (np.ascontiguousarray(a[0]) for a in bezier_segments(cps[None]))
        got = np.array([_plane_offset_at(*p, p0, p1, p2, tk) for p, tk in zip(points, t,
                                                                              strict=True)])
        assert np.allclose(got, expected, rtol=0.0, atol=1e-12)


def test_the_inside_kernel_holds_the_frames_and_profile_level_of_the_sweep_math() -> None:
    # inside_kernel.py turns each segment's start frame (sweep.segment_frames) to the
    # tangent at t for one point, and computes the profile's level there: it must give
    # axis_frames' U, V and superellipse_level's level, on curved axes of several
    # segments, a cusp, a hairpin that turns by nearly pi (the rotation about the
    # plane's normal) and an exact fold back along a line (U kept, V flipped).
    from sweepedit.geometry.inside_kernel import _frame_at, _profile_level_at
    from sweepedit.geometry.sweep import (
        bezier_segments,
        scaling_factor,
        segment_frames,
        superellipse_level,
    )

    rng = np.random.default_rng(8)
    axes = [rng.normal(0.0, 0.2, (n, 3)) for n in (3, 4, 6)]
    axes.append(np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.3, 0.1, 0.0]]))  # s'(0) = 0
    axes.append(np.array([[0.5, 0.0, 0.0], [0.0, 0.0, 0.0], [0.5, 1e-6, 0.0]]))  # hairpin
    axes.append(np.array([[0.0, 0.0, 0.0], [0.5, 0.375, 0.0], [0.0, 0.0, 0.0]]))  # exact fold
    profile = np.array([[0.07, 0.04, 0.8]])
    scaling = np.array([[0.3, -0.2]])
    turned = 0
    for cps in axes:
        m = len(cps) - 2
        t = np.concatenate([[0.0, 1.0], np.arange(1, m) / m, rng.uniform(0.0, 1.0, 60)])
        frames = axis_frames(cps[None], t)
        start = np.ascontiguousarray(np.concatenate(
            [np.asarray(a[0], dtype=np.float64) for a in segment_frames(cps[None])], axis=1))
        for k, tk in enumerate(t):
            j = min(int(tk * m), m - 1)
            got = np.array(_frame_at(start, j, *frames.T[0, k]))
            np.testing.assert_allclose(got[:3], frames.U[0, k], rtol=0.0, atol=1e-12)
            np.testing.assert_allclose(got[3:], frames.V[0, k], rtol=0.0, atol=1e-12)
            turned += frames.T[0, k] @ start[j, :3] < 0.0
        points = frames.points[0] + rng.normal(0.0, 0.05, (len(t), 3))
        rel = points - frames.points[0]
        f = scaling_factor(scaling, t)[0]
        x = np.einsum("ij,ij->i", rel, frames.U[0]) / f
        y = np.einsum("ij,ij->i", rel, frames.V[0]) / f
        expected = superellipse_level(x[None], y[None], profile)[0]
        p0, p1, p2 = (np.ascontiguousarray(a[0]) for a in bezier_segments(cps[None]))
        got = np.array([_profile_level_at(*p, p0, p1, p2, start, scaling[0], profile[0], tk)
                        for p, tk in zip(points, t, strict=True)])
        np.testing.assert_allclose(got, expected, rtol=1e-10)
    assert turned > 10  # tangents beyond pi/2 from their segment's start were checked


def test_the_inside_kernel_holds_the_segment_start_frames_of_the_sweep_math() -> None:
    # inside_kernel.segment_start_frames writes sweep.segment_frames out for one axis:
    # the same tangents, frames, normals and planar flags on curved axes of several
    # segments, a cusp (a vanishing first leg), a hairpin, an exact fold back, axes
    # along z and within 1e-7 of it (the initial frame's fixed W) and a straight one.
    from sweepedit.geometry.inside_kernel import segment_start_frames
    from sweepedit.geometry.sweep import bezier_segments, segment_frames

    rng = np.random.default_rng(9)
    axes = [rng.normal(0.0, 0.2, (n, 3)) for n in (3, 4, 6, 8, 8)]
    axes.append(np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.3, 0.1, 0.0]]))  # cusp
    axes.append(np.array([[0.5, 0.0, 0.0], [0.0, 0.0, 0.0], [0.5, 1e-6, 0.0],
                          [0.2, 0.3, 0.1]]))  # hairpin, then on
    axes.append(np.array([[0.0, 0.0, 0.0], [0.5, 0.375, 0.0], [0.0, 0.0, 0.0]]))  # exact fold
    axes.append(np.array([[0.0, 0.0, -0.4], [0.0, 0.0, 0.0], [0.0, 0.0, 0.2],
                          [0.0, 0.0, 0.4]]))  # straight along z
    axes.append(np.array([[0.0, 0.0, -0.4], [0.0, 1e-8, 0.0], [0.0, 0.0, 0.4]]))  # nearly
    axes.append(np.array([[-0.3, 0.1, 0.0], [0.0, 0.2, 0.1], [0.3, 0.3, 0.2]]))  # straight
    for cps in axes:
        expected = np.concatenate([np.asarray(a[0], dtype=np.float64)
                                   for a in segment_frames(cps[None])], axis=1)
        p0, p1, p2 = (np.ascontiguousarray(a[0]) for a in bezier_segments(cps[None]))
        got = np.full_like(expected, np.nan)
        segment_start_frames(p0, p1, p2, got)
        np.testing.assert_allclose(got, expected, rtol=0.0, atol=1e-12)


def test_the_inside_test_wants_points_as_rows_of_three() -> None:
    p = SweepPrimitive([[0, 0, -0.3], [0, 0, 0], [0, 0, 0.3]], a=0.2, b=0.1, degree=2.0)
    with pytest.raises(ValueError, match=r"\(N, 3\)"):
        inside_primitive(np.zeros((4, 2)), p)
    with pytest.raises(ValueError, match=r"\(N, 3\)"):
        inside_union(np.zeros(3), [p])
    assert inside_primitive(np.zeros((0, 3)), p).shape == (0,)


@pytest.mark.parametrize("degree", [0.3, 0.7, 1.0, 1.9, 2.0, 2.6, 5.0])
def test_the_profiles_inscribed_and_circumscribed_circles_hold_it(degree: float) -> None:
    # profile_radii2: every point of the superellipse lies between the two circles, and
    # for a = b the profile touches both (at its axes and its diagonals), but for what
    # the inner one keeps to spare for superellipse_level's clip (0.3 % at d = 0.3).
    from sweepedit.geometry.inside import profile_radii2
    from sweepedit.geometry.sweep import superellipse

    theta = np.linspace(0.0, 2.0 * np.pi, 4001)
    for a, b in ((0.05, 0.05), (0.03, 0.08), (0.1, 0.02)):
        inside, outside = profile_radii2(a, b, degree)
        x, y = superellipse(theta, np.array([[a, b, degree]]))
        r2 = x[0] ** 2 + y[0] ** 2
        assert inside < r2.min() and r2.max() < outside
        if a == b:
            assert r2.min() == pytest.approx(inside, rel=5e-3)
            assert r2.max() == pytest.approx(outside, rel=1e-6)
    assert profile_radii2(0.05, 0.05, float("nan")) == (-1.0, np.inf)


def test_the_inside_test_decides_by_radius_as_the_profile_test_would(
        monkeypatch: pytest.MonkeyPatch) -> None:
    # The root search settles a point by its radius in the plane alone where that is
    # inside the inscribed circle or outside the circumscribed one; the same points with
    # every root left to the profile test (sweep.py's frames) must come out the same,
    # near the boundary too, for round, pinched and boxy profiles, folding or not.
    from sweepedit.geometry import inside

    rng = np.random.default_rng(11)
    cps = np.array([[0.0, 0.0, -0.2], [0.25, 0.0, 0.0], [0.0, 0.05, 0.2], [0.1, 0.2, 0.3]])
    prims = [SweepPrimitive(cps, a=a, b=b, degree=d, scaling=(0.3, -0.4))
             for a, b, d in ((0.05, 0.05, 2.0), (0.04, 0.09, 0.3), (0.08, 0.03, 5.0),
                             (0.2, 0.12, 1.3))]
    assert folds_onto_itself(prims[-1]) and not folds_onto_itself(prims[0])
    points = rng.uniform(-0.35, 0.45, (60_000, 3))
    near = np.concatenate([sweep_mesh(p).vertices for p in prims])  # on the boundaries
    points = np.concatenate([points, near, near * (1 + 1e-7), near * (1 - 1e-7)])
    by_radius = [inside_primitive(points, p) for p in prims]
    inside._make_axis_table.cache_clear()
    monkeypatch.setattr(inside, "profile_radii2", lambda a, b, d: (-1.0, np.inf))
    try:
        for p, got in zip(prims, by_radius, strict=True):
            assert np.array_equal(inside_primitive(points, p), got)
            assert 0.01 < got.mean() < 0.5
    finally:
        inside._make_axis_table.cache_clear()
