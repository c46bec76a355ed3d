"""Issue 16 in a real window under Xvfb: the heat map of the error (View menu, colour bar,
colours against independently computed distances, background refresh), refit of a
selection (the others unchanged to the bit), and one render per mouse move."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from sweepedit.geometry.model import Abstraction, SweepPrimitive, palette_color

pytestmark = pytest.mark.gui


@pytest.fixture
def sphere_files(tmp_path: Path) -> dict[str, Path]:
    """A sphere (radius 0.5 once normalised) and a cylinder along x through it that
    misses its sides and sticks out of it at both ends, plus a small second primitive."""
    trimesh = pytest.importorskip("trimesh")
    from sweepedit.io.params import write_abstraction

    shape = tmp_path / "sphere.obj"
    trimesh.creation.icosphere(subdivisions=3, radius=1.0).export(shape)
    params = tmp_path / "sphere.json"
    write_abstraction(Abstraction([
        SweepPrimitive(control_points=[[-0.6, 0, 0], [0, 0, 0], [0.6, 0, 0]], a=0.3, b=0.3,
                       degree=2.0, name="barrel", color=palette_color(0)),
        SweepPrimitive(control_points=[[0, 0.1, 0.2], [0, 0.2, 0.3], [0, 0.3, 0.35]],
                       a=0.05, b=0.05, degree=2.0, name="knob", color=palette_color(1)),
    ]), params)
    return {"shape": shape, "params": params}


def exact_signed_distance(points: np.ndarray, prims: list[SweepPrimitive]) -> np.ndarray:
    """Independent truth: trimesh's point-triangle distance to the exact solid union
    (manifold3d), signed by the exact inside test."""
    import trimesh

    from sweepedit.geometry.inside import inside_union
    from sweepedit.geometry.solid import solid_union

    union = solid_union(prims, 128, 96)
    _, unsigned, _ = trimesh.proximity.closest_point(
        trimesh.Trimesh(union.vertices, union.faces, process=False), points)
    return np.where(inside_union(points, prims), -unsigned, unsigned)


def test_heat_map_toggles_with_a_colour_bar_and_colours_the_true_distances(
        qtbot, window, sphere_files) -> None:
    assert window.open_path(sphere_files["shape"])
    assert window.open_path(sphere_files["params"])
    view = window.heatmap
    assert not view.scalar_bar.GetVisibility()
    assert window.act_heatmap in window.view_menu.actions()
    window.act_heatmap.trigger()  # View > Heat map of the error
    assert view.visible and view.scalar_bar.GetVisibility()
    assert not window.scene.shape_visible  # the coloured target replaces the grey one
    qtbot.waitUntil(lambda: view.last_distance is not None and not view.running,
                    timeout=60000)
    poly = view._poly
    truth = exact_signed_distance(np.array(poly.points), window.doc.primitives)
    shown = np.array(poly.point_data["distance"])
    # The colours the actor shows: the lookup table over the shown range.
    lut = view._actor.GetMapper().GetLookupTable()
    lo, hi = view._actor.GetMapper().GetScalarRange()
    assert lo == -hi and hi == view.half_range
    def rgb(value: float) -> list[float]:
        out = [0.0, 0.0, 0.0]
        lut.GetColor(float(value), out)
        return out

    colours = np.array([rgb(v) for v in shown])
    expected = np.array([rgb(v) for v in np.clip(truth, lo, hi)])
    assert np.abs(colours - expected).max() < 0.05
    # Both kinds of error are on this target: the barrel misses the sphere's sides (red)
    # and buries it at both ends (blue).
    assert (truth > 0.05).any() and (truth < -0.05).any()
    assert np.array_equal(shown > 0, truth > 0)

    # An edit recomputes it in the background.
    before = view.last_distance
    window.doc.select(0)
    assert window.scene.drag_control_point(0, 1, [0.0, 0.15, 0.0])
    window.scene.end_drag()
    qtbot.waitUntil(lambda: view.last_distance is not before and not view.running,
                    timeout=60000)
    assert not np.array_equal(view.last_distance, before)

    window.act_heatmap.trigger()  # off again
    assert not view.visible and not view.scalar_bar.GetVisibility()
    assert window.scene.shape_visible
    window.stack.undo()
    assert not view.running  # no longer listening to the document


def _camera_state(scene) -> np.ndarray:
    camera = scene.plotter.renderer.GetActiveCamera()
    return np.array([*camera.GetPosition(), *camera.GetFocalPoint(), *camera.GetViewUp(),
                     *camera.GetWindowCenter(), camera.GetParallelScale()])


@pytest.mark.parametrize("orthographic", [False, True])
def test_the_colour_bar_never_covers_the_shape(qtbot, window, sphere_files,
                                               orthographic: bool) -> None:
    # A wide target (a capsule 4 times as long as thick), zoomed in on so that it spans
    # the view's width, where the colour bar sits over the right-most 12 %.
    trimesh = pytest.importorskip("trimesh")
    from sweepedit.app.heatmap_view import BAR_LEFT

    wide = sphere_files["shape"].with_name("capsule.obj")
    trimesh.creation.capsule(height=3.0, radius=0.5).apply_transform(
        trimesh.transformations.rotation_matrix(np.pi / 2, [0, 1, 0])).export(wide)
    assert window.open_path(wide)
    assert window.open_path(sphere_files["params"])
    scene = window.scene
    scene.set_orthographic(orthographic)
    scene.view_preset("front")  # the capsule's length across the view
    scene.plotter.renderer.GetActiveCamera().Zoom(1.5)
    scene.render_now()
    width = scene.plotter.render_window.GetSize()[0]
    points = _shape_points(window)

    def across() -> np.ndarray:
        scene.render_now()
        return scene.world_to_display(points)[:, 0]

    x = across()
    assert x.min() >= 0.0 and x.max() > BAR_LEFT * width  # in view, some under the bar
    before = _camera_state(scene)
    window.act_heatmap.trigger()
    x = across()  # what was in view stays in view, clear of the bar
    assert x.min() >= 0.0 and x.max() < (BAR_LEFT - 0.005) * width
    window.act_heatmap.trigger()  # off: the view as it was, to rounding
    assert np.allclose(_camera_state(scene), before, rtol=1e-9, atol=1e-12)
    assert scene.right_margin == 0.0

    window.act_heatmap.trigger()
    window.doc.select(0)
    for fit in (scene.reset_camera, lambda: scene.view_preset("top"),
                scene.frame_selection):
        fit()
        x = across()
        assert x.min() >= 0.0 and x.max() < (BAR_LEFT - 0.005) * width
    # Picking follows the picture: the barrel's middle is picked where it is drawn.
    middle = scene.world_to_display(np.zeros((1, 3)))[0]
    assert scene.pick_primitive(middle[0], middle[1]) == 0


def _shape_points(window) -> np.ndarray:
    """The target's vertices (V, 3) as the scene draws them."""
    from sweepedit.app.scene import shape_polydata

    return np.array(shape_polydata(window.doc.shape).points, dtype=np.float64)


def test_heat_map_needs_a_shape_and_closes_cleanly(qtbot, window) -> None:
    assert not window.set_heatmap_visible(True)
    assert not window.act_heatmap.isChecked()
    window.heatmap.close()
    assert not window.heatmap.set_visible(True)


def test_refit_selection_changes_only_the_selected_primitive(qtbot, window,
                                                             sphere_files) -> None:
    assert window.open_path(sphere_files["shape"])
    assert window.open_path(sphere_files["params"])
    before = [p.copy() for p in window.doc.primitives]
    window.fit_panel.refine_iterations.setValue(20)
    window.doc.select(1)
    assert window.act_refit.isEnabled()
    from PySide6.QtCore import Qt

    qtbot.mouseClick(window.fit_panel.refit_button, Qt.MouseButton.LeftButton)
    assert window.fitting
    qtbot.waitUntil(lambda: not window.fitting, timeout=180000)
    assert window.errors == []
    after = window.doc.primitives
    assert len(after) == 2
    kept, refit = after[0], after[1]
    assert kept.control_points.tobytes() == before[0].control_points.tobytes()
    assert (kept.a, kept.b, kept.degree, kept.scaling, kept.name, kept.color) == (
        before[0].a, before[0].b, before[0].degree, before[0].scaling, before[0].name,
        before[0].color)
    assert refit.name == "knob"
    assert not np.array_equal(refit.control_points, before[1].control_points)
    window.stack.undo()  # one step back to the start
    assert window.doc.primitive(1).control_points.tobytes() == \
        before[1].control_points.tobytes()


def test_refit_refuses_nothing_selected_and_locked(qtbot, window, sphere_files) -> None:
    assert window.open_path(sphere_files["shape"])
    assert window.open_path(sphere_files["params"])
    assert not window.refit_selection()
    window.doc.primitive(0).locked = True
    window.doc.set_selection([0, 1])  # primary 1, with the locked 0 also selected
    assert not window.refit_selection()
    assert "locked" in window.statusBar().currentMessage()
    assert not window.fitting


def test_a_mouse_move_renders_exactly_once(qtbot, window, sphere_files) -> None:
    from PySide6.QtCore import QPoint, Qt

    assert window.open_path(sphere_files["shape"])
    assert window.open_path(sphere_files["params"])
    window.doc.select(0)
    qtbot.wait(100)
    plotter = window.plotter
    renders: list[int] = []
    tag = plotter.render_window.AddObserver("EndEvent", lambda *_: renders.append(1))
    try:
        ratio = plotter.devicePixelRatioF()
        d = window.scene.world_to_display(window.doc.primitive(0).control_points[1:2])[0]
        start = QPoint(round(d[0] / ratio), round(plotter.height() - 1 - d[1] / ratio))
        qtbot.mousePress(plotter, Qt.MouseButton.LeftButton, pos=start)
        assert window.scene.dragging
        qtbot.wait(50)
        counts = []
        for k in range(1, 9):
            renders.clear()
            qtbot.mouseMove(plotter, start + QPoint(4 * k, -3 * k))
            qtbot.wait(40)  # the paint that follows the move, and anything after it
            counts.append(len(renders))
        qtbot.mouseRelease(plotter, Qt.MouseButton.LeftButton, pos=start + QPoint(32, -24))
    finally:
        plotter.render_window.RemoveObserver(tag)
    assert counts == [1] * 8
    assert len(window.stack) == 1


def test_gui_screenshot_of_the_heat_map(qtbot, sphere_files, tmp_path: Path) -> None:
    from PySide6.QtGui import QImage

    from sweepedit.app.main import has_display, screenshot

    if not has_display():
        pytest.skip("needs a display (run under xvfb-run)")
    out = tmp_path / "heat.png"
    # As `sweepedit gui SHAPE PARAMS --heatmap --screenshot PNG` calls it.
    assert screenshot(str(sphere_files["shape"]), str(out), full_window=False,
                      size=(1400, 900), also=str(sphere_files["params"]), heatmap=True) == 0
    image = QImage(str(out))
    assert not image.isNull()
    pixels = [image.pixelColor(x, y) for x in range(0, image.width(), 7)
              for y in range(0, image.height(), 7)]
    # Both ends of the diverging map are on screen: missed (red) and excess (blue).
    assert any(c.red() > c.green() + 60 and c.red() > c.blue() + 60 for c in pixels)
    assert any(c.blue() > c.red() + 30 and c.blue() > c.green() + 20 for c in pixels)
    # A parameter file alone (no shape beside it) has no target to colour: an error.
    assert screenshot(str(sphere_files["params"]), str(tmp_path / "no.png"),
                      size=(900, 600), heatmap=True) == 1


def test_gui_command_takes_at_most_two_files(capsys) -> None:
    from sweepedit.cli import main

    assert main(["gui", "a.obj", "b.json", "c.json", "--screenshot", "x.png"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "at most two files" in err[0]


def test_gui_select_counts_primitives_from_1_as_their_names_do(capsys, monkeypatch) -> None:
    import sweepedit.app.main as app_main
    from sweepedit.cli import main

    asked: list = []
    monkeypatch.setattr(app_main, "screenshot",
                        lambda *args, **kwargs: asked.append(kwargs["select"]) or 0)
    assert main(["gui", "a.json", "--screenshot", "x.png", "--select", "1"]) == 0
    assert main(["gui", "a.json", "--screenshot", "x.png"]) == 0
    assert asked == [0, None]  # "primitive 1" is the first, index 0
    assert main(["gui", "a.json", "--screenshot", "x.png", "--select", "0"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "counted from 1" in err[0]
