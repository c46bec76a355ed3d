"""Skeleton branches of analytic occupancy grids, shared shapes, and the render."""

from __future__ import annotations

import numpy as np
import pytest

from sweepedit.analysis.skeleton import Skeleton, compute_skeleton
from sweepedit.io.occupancy import cell_centers

R = 64
H = 1.0 / R
P = cell_centers(R)


def _grid(inside: np.ndarray) -> np.ndarray:
    return inside.reshape(R, R, R)


def _capsule(a, b, radius: float) -> np.ndarray:
    """(R^3,) bool: cell centres within `radius` of the segment a-b."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    t = np.clip((P - a) @ (b - a) / np.dot(b - a, b - a), 0.0, 1.0)
    return np.linalg.norm(P - (a + t[:, None] * (b - a)), axis=1) <= radius


def _cylinder_x(radius: float = 0.1, half: float = 0.4) -> np.ndarray:
    return _grid((np.hypot(P[:, 1], P[:, 2]) <= radius) & (np.abs(P[:, 0]) <= half))


def test_cylinder_gives_one_branch_along_its_axis():
    sk = compute_skeleton(_cylinder_x(0.1, 0.4))
    assert isinstance(sk, Skeleton) and len(sk) == 1
    b = sk.branches[0]
    assert not b.is_loop and {b.start_kind, b.end_kind} == {"tip"}
    assert len(sk.junctions) == 0 and len(sk.tips) == 2
    assert np.all(np.hypot(b.points[:, 1], b.points[:, 2]) < 1.5 * H)
    assert b.length > 0.55
    middle = np.abs(b.points[:, 0]) < 0.25
    assert np.median(b.radii[middle]) == pytest.approx(0.1, abs=1.0 * H)
    assert b.points.shape == (b.radii.shape[0], 3)


def test_y_shape_gives_three_branches_and_one_junction():
    centre = np.array([0.0, 0.0, 0.0])
    arms = [0.4 * np.array([np.cos(t), np.sin(t), 0.0])
            for t in (np.pi / 2, np.pi / 2 + 2 * np.pi / 3, np.pi / 2 + 4 * np.pi / 3)]
    occ = _grid(np.any([_capsule(centre, end, 0.06) for end in arms], axis=0))
    sk = compute_skeleton(occ)
    assert len(sk) == 3 and len(sk.junctions) == 1 and len(sk.tips) == 3
    assert np.linalg.norm(sk.junctions[0] - centre) < 3 * H
    for b in sk.branches:
        assert sorted([b.start_kind, b.end_kind]) == ["junction", "tip"]
        tip = b.points[-1] if b.end_kind == "tip" else b.points[0]
        assert min(np.linalg.norm(tip - end) for end in arms) < 0.06 + 2 * H
        assert np.median(b.radii) == pytest.approx(0.06, abs=1.5 * H)


def test_torus_gives_one_loop():
    ring = np.hypot(P[:, 0], P[:, 1]) - 0.3
    sk = compute_skeleton(_grid(ring**2 + P[:, 2] ** 2 <= 0.08**2))
    assert len(sk) == 1 and sk.n_loops == 1
    b = sk.branches[0]
    assert b.is_loop and b.start == b.end and b.start_kind == "loop"
    assert np.allclose(b.points[0], b.points[-1])
    assert b.length == pytest.approx(2 * np.pi * 0.3, rel=0.1)
    assert np.all(np.abs(np.hypot(b.points[:, 0], b.points[:, 1]) - 0.3) < 2 * H)
    assert np.median(b.radii) == pytest.approx(0.08, abs=1.0 * H)


def test_ball_gets_a_usable_branch():
    sk = compute_skeleton(_grid(np.linalg.norm(P, axis=1) <= 0.3))
    assert len(sk) >= 1
    b = max(sk.branches, key=lambda b: b.length)
    assert b.length > 0.3
    assert np.max(b.radii) == pytest.approx(0.3, abs=2 * H)
    assert np.all(b.radii > 0)


def test_single_voxel_and_empty_grid():
    occ = np.zeros((R, R, R), dtype=bool)
    assert len(compute_skeleton(occ)) == 0
    occ[10, 20, 30] = True
    sk = compute_skeleton(occ)
    assert len(sk) == 1 and sk.is_fallback
    assert np.allclose(sk.branches[0].points.mean(axis=0), P.reshape(R, R, R, 3)[10, 20, 30])


def test_tiny_bits_are_dropped_and_separate_parts_kept():
    occ = _cylinder_x(0.08, 0.35)
    occ[2:4, 2:4, 2:4] = True  # 8 voxels of noise in a corner
    assert len(compute_skeleton(occ)) == 1
    occ |= _grid(_capsule((-0.3, 0.0, 0.3), (0.3, 0.0, 0.3), 0.05))
    sk = compute_skeleton(occ)
    assert len(sk) == 2 and len(sk.junctions) == 0


def test_bumpy_surface_leaves_no_spurs():
    # A thick cylinder with small bumps: thinning grows spurs towards each bump.
    occ = _cylinder_x(0.12, 0.4)
    for x in np.linspace(-0.3, 0.3, 5):
        occ |= _grid(np.linalg.norm(P - (x, 0.12, 0.0), axis=1) <= 0.03)
    sk = compute_skeleton(occ)
    assert len(sk) == 1


def test_resample_and_totals():
    sk = compute_skeleton(_cylinder_x(0.1, 0.4))
    b = sk.branches[0]
    pts, radii = b.resample(7)
    assert pts.shape == (7, 3) and radii.shape == (7,)
    assert np.allclose(pts[0], b.points[0]) and np.allclose(pts[-1], b.points[-1])
    steps = np.linalg.norm(np.diff(pts, axis=0), axis=1)
    assert np.allclose(steps, steps.mean(), rtol=0.2)
    assert sk.total_length == pytest.approx(b.length)
    assert sk.all_points().shape == (len(b.points), 3)
    assert sk.all_radii().shape == (len(b.points),)


def test_rejects_non_cubic_grid():
    with pytest.raises(ValueError):
        compute_skeleton(np.zeros((4, 5, 6), dtype=bool))


# --------------------------------------------------------------------------- shared shapes


def _shared_skeleton(shapes_dir, name):
    from sweepedit.io.shapes import load_shape

    shape = load_shape(shapes_dir / name, n_samples=500)
    return shape, compute_skeleton(shape.occupancy)


def test_knot_is_one_loop(shapes_dir):
    _, sk = _shared_skeleton(shapes_dir, "knot1.off")
    assert len(sk) == 1 and sk.n_loops == 1 and len(sk.junctions) == 0


def test_hand_has_five_fingers(shapes_dir):
    _, sk = _shared_skeleton(shapes_dir, "hand.obj")
    tips = sk.tips
    assert len(tips) >= 6  # five fingertips and the wrist
    long_tip_branches = [b for b in sk.branches if "tip" in (b.start_kind, b.end_kind)
                         and b.length > 0.15]
    assert len(long_tip_branches) >= 5


def test_ant_legs_and_antennae_are_branches(shapes_dir):
    _, sk = _shared_skeleton(shapes_dir, "ant.ply")
    thin_long = [b for b in sk.branches if b.length > 0.3 and b.mean_radius < 2 * H]
    assert len(thin_long) >= 8  # six legs, two antennae


# --------------------------------------------------------------------------- render


def test_render_writes_a_png(tmp_path):
    pytest.importorskip("pyvista")
    import trimesh

    from sweepedit.analysis.render import render_shape

    mesh = trimesh.creation.cylinder(radius=0.1, height=0.8)
    path = tmp_path / "cyl.stl"
    mesh.export(path)
    from sweepedit.io.shapes import load_shape

    shape = load_shape(path, n_samples=200)
    out = render_shape(shape, compute_skeleton(shape.occupancy), tmp_path / "sub" / "c.png",
                       window_size=(200, 150))
    data = out.read_bytes()
    assert out == tmp_path / "sub" / "c.png" and data[:8] == b"\x89PNG\r\n\x1a\n"
    assert [p.name for p in out.parent.iterdir()] == ["c.png"]  # no temporary left behind


def test_render_abstraction_and_contact_sheet(tmp_path):
    pytest.importorskip("pyvista")
    import trimesh

    from sweepedit.analysis.render import render_abstraction, render_contact_sheet
    from sweepedit.geometry.model import Abstraction, SweepPrimitive
    from sweepedit.io.shapes import load_shape

    path = tmp_path / "cyl.off"
    trimesh.creation.cylinder(radius=0.1, height=0.8).export(path)
    shape = load_shape(path, n_samples=200)
    prim = SweepPrimitive(control_points=[[0, 0, -0.4], [0, 0, 0], [0, 0, 0.4]], a=0.12, b=0.12)
    abstraction = Abstraction(primitives=[prim])
    one = render_abstraction(abstraction, shape, tmp_path / "a.png", window_size=(200, 150))
    sheet = render_contact_sheet([("a", shape, abstraction), ("b", None, abstraction)],
                                 tmp_path / "sheet.png", tile_size=(120, 90))
    for out in (one, sheet):
        assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.png", "cyl.off", "sheet.png"]


def test_contact_sheet_draws_a_shape_thinner_than_its_coarse_grid(tmp_path):
    """bench's sheet loads shapes on a coarse grid; a blade 0.03 thick (fitted on the
    64^3 grid) has no coarse cell inside it, and the sheet must still be drawn."""
    pytest.importorskip("pyvista")
    import trimesh

    from sweepedit.errors import DegenerateShapeError
    from sweepedit.fitting.bench import _SHEET_RESOLUTION, contact_sheet
    from sweepedit.geometry.model import Abstraction, SweepPrimitive
    from sweepedit.io.params import write_abstraction
    from sweepedit.io.shapes import load_shape

    path = tmp_path / "blade.stl"
    trimesh.creation.box(extents=(1.0, 0.2, 0.03)).export(path)
    with pytest.raises(DegenerateShapeError):
        load_shape(path, resolution=_SHEET_RESOLUTION, n_samples=200)
    params = tmp_path / "blade.json"
    write_abstraction(Abstraction([SweepPrimitive([[-0.45, 0, 0], [0, 0, 0], [0.45, 0, 0]],
                                                  a=0.1, b=0.015)]), params)
    out, tiles = contact_sheet([("blade", path, params)], tmp_path / "sheet.png")
    assert tiles == 1 and out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
