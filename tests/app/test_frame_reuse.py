"""Frame reuse (sweepedit.app.frame_reuse), in a real window under Xvfb: while a drag
changes one primitive, the frames reuse the picture of what did not change, and every
such frame is the plain frame pixel for pixel - the independent truth is the same scene
drawn with reuse switched off."""

from __future__ import annotations

import numpy as np
import pytest
from gui_helpers import move, open_box, qpoint
from pyvista.plotting.utilities import image_from_window

from sweepedit.app.commands import set_field
from sweepedit.app.frame_reuse import CAPTURE, PLAIN, REUSE
from sweepedit.geometry.model import Abstraction, SweepPrimitive, palette_color

pytestmark = pytest.mark.gui


def primitives() -> list[SweepPrimitive]:
    """Five tubes inside and around the box of `small_files` (normalised frame)."""
    out = []
    for k, (y, z) in enumerate([(-0.15, -0.1), (0.15, -0.1), (-0.15, 0.1), (0.15, 0.1),
                                (0.0, 0.0)]):
        out.append(SweepPrimitive(
            control_points=[[-0.4, y, z], [0.0, y + 0.05, z], [0.4, y, z]],
            a=0.06, b=0.05, name=f"tube {k + 1}", color=palette_color(k)))
    return out


@pytest.fixture
def tubes(qtbot, window, small_files):
    """The box (translucent target) and five tubes, the first selected, all drawn."""
    open_box(qtbot, window, small_files)
    window.doc.set_abstraction(Abstraction(primitives()))
    window.doc.select(0)
    window.scene.render_now()
    return window


class Frames:
    """The frame reuse's mode of each frame the window renders."""

    def __init__(self, window) -> None:
        self.window = window
        self.modes: list[str] = []
        self.render_window = window.plotter.render_window
        self.tag = self.render_window.AddObserver(
            "EndEvent", lambda *_: self.modes.append(window.scene.frame_reuse.mode))

    def after(self, qtbot, action) -> str:
        """Do `action`, wait for the frame it causes, and give that frame's mode."""
        n = len(self.modes)
        action()
        qtbot.waitUntil(lambda: len(self.modes) > n, timeout=5000)
        return self.modes[-1]

    def close(self) -> None:
        self.render_window.RemoveObserver(self.tag)


def shown(window) -> np.ndarray:
    """(h, w, 3) the last frame, as the window shows it (what view3d.frame_image reads)."""
    return np.array(image_from_window(window.plotter.render_window, ignore_alpha=True))


def plain(window) -> np.ndarray:
    """The same scene drawn in full, with frame reuse switched off for one frame."""
    reuse = window.scene.frame_reuse
    reuse.enabled = False
    try:
        window.scene.render_now()
        assert reuse.mode == PLAIN
        return shown(window)
    finally:
        reuse.enabled = True


def assert_same_picture(window) -> None:
    got = shown(window)
    want = plain(window)
    differ = np.any(got != want, axis=-1)
    assert not differ.any(), f"{int(differ.sum())} pixels differ from the plain frame"


def test_a_drag_draws_only_the_moving_primitive_and_shows_the_plain_frame(qtbot,
                                                                           tubes) -> None:
    from PySide6.QtCore import QPoint, Qt

    window, scene = tubes, tubes.scene
    before = shown(window)
    frames = Frames(window)
    start = qpoint(window, window.doc.primitive(0).control_points[1])
    qtbot.mousePress(window.plotter, Qt.MouseButton.LeftButton, pos=start)
    assert scene.dragging
    modes = [frames.after(qtbot, lambda k=k: move(window, start + QPoint(3 * k, -2 * k)))
             for k in range(1, 13)]
    # The first move takes the picture; the others reuse it.
    assert modes[0] == CAPTURE and modes[1:] == [REUSE] * 11, modes
    assert_same_picture(window)
    assert np.any(shown(window) != before)  # the drag did change the picture

    # Between frames the main renderer holds every actor, visible, as before: picking
    # and bounds see the scene as it is.
    assert all(scene.primitive_actor(i).GetVisibility() for i in range(scene.n_actors))
    centre = qpoint(window, window.doc.primitive(3).control_points[0] * 0.5
                    + window.doc.primitive(3).control_points[1] * 0.5)
    ratio = window.plotter.devicePixelRatioF()
    assert scene.pick_primitive(centre.x() * ratio,
                                (window.plotter.height() - 1 - centre.y()) * ratio) == 3
    qtbot.mouseRelease(window.plotter, Qt.MouseButton.LeftButton, pos=start + QPoint(36, -24))
    frames.close()


def test_a_primitive_dragged_out_of_the_scene_s_bounds_still_reuses_the_picture(
        qtbot, tubes) -> None:
    """The handle leaves the box: the camera's clipping range (which sets the depth
    mapping) must not change on every move, or no frame could reuse the picture."""
    window, scene, doc = tubes, tubes.scene, tubes.doc
    frames = Frames(window)
    modes = []
    for _ in range(12):
        end = doc.primitive(0).control_points[2] + np.array([0.02, 0.0, 0.01])
        modes.append(frames.after(qtbot, lambda end=end: scene.drag_control_point(0, 2, end)))
    assert doc.primitive(0).control_points[2][0] > 0.6  # well out of the box (x <= 0.5)
    assert modes.count(REUSE) >= 8, modes
    assert_same_picture(window)
    frames.close()


def test_changes_outside_the_live_set_and_view_changes_are_drawn_in_full(qtbot,
                                                                          tubes) -> None:
    window, scene, doc = tubes, tubes.scene, tubes.doc
    frames = Frames(window)

    def edit_first(dz: float) -> str:
        cps = doc.primitive(0).control_points
        return frames.after(qtbot, lambda: scene.drag_control_point(
            0, 1, cps[1] + np.array([0.0, 0.0, dz])))

    def edit_second(dz: float) -> str:
        cps = doc.primitive(1).control_points
        return frames.after(qtbot, lambda: scene.drag_control_point(
            1, 1, cps[1] + np.array([0.0, 0.0, dz])))

    assert [edit_first(0.01 * k) for k in range(1, 4)] == [CAPTURE, REUSE, REUSE]
    assert_same_picture(window)

    # Another primitive's colour: a new picture, with the right colour in it.
    def colour_fourth(color: str) -> str:
        return frames.after(qtbot, lambda: window._push(
            set_field(doc, 3, "color", color, merge=False)))

    assert colour_fourth("#ff00ff") == CAPTURE
    # The first primitive stays among those drawn live, with the fourth now: edits of
    # either reuse the picture.
    assert [edit_first(0.04), colour_fourth("#00ffff"), edit_first(0.05)] == [REUSE] * 3
    # Hiding a live primitive needs no new picture either; it is gone from the frame.
    assert frames.after(qtbot, lambda: window._push(
        set_field(doc, 0, "visible", False, merge=False))) == REUSE
    assert_same_picture(window)
    # Hiding a primitive kept in the picture takes a new one; edits of a hidden primitive
    # change nothing in it.
    assert frames.after(qtbot, lambda: window._push(
        set_field(doc, 2, "visible", False, merge=False))) == CAPTURE
    assert_same_picture(window)
    assert edit_first(0.06) == REUSE
    cps = doc.primitive(2).control_points
    assert frames.after(qtbot, lambda: scene.drag_control_point(
        2, 1, cps[1] + np.array([0.0, 0.0, 0.05]))) == REUSE
    assert_same_picture(window)
    assert frames.after(qtbot, lambda: window._push(
        set_field(doc, 2, "visible", True, merge=False))) == CAPTURE
    assert_same_picture(window)
    # The target made opaque, and the camera turned: drawn in full or anew, as plain.
    window.scene.set_shape_opacity(1.0)
    scene.render_now()
    assert_same_picture(window)
    camera = window.plotter.renderer.GetActiveCamera()
    assert frames.after(qtbot, lambda: (camera.Azimuth(20), scene.request_render())) == PLAIN
    assert_same_picture(window)
    assert edit_second(0.01) == CAPTURE
    light = window.plotter.renderer.GetLights().GetItemAsObject(0)
    assert frames.after(qtbot, lambda: (light.SetIntensity(0.6), scene.request_render())) \
        == PLAIN
    assert_same_picture(window)
    # The orientation axes (a renderer of their own under the live layer, kept in the
    # picture): a change there alone makes the next frame draw in full.
    axes = window.plotter.renderer.axes_actor
    assert edit_second(0.02) == CAPTURE
    for visible in (False, True):
        assert frames.after(qtbot, lambda v=visible: (axes.SetVisibility(v),
                                                      scene.request_render())) == PLAIN
        assert_same_picture(window)
    # A change in the picture first drawn by a full frame (reuse off) is not forgotten
    # when reuse is back on.
    assert [edit_second(0.03), edit_second(0.04)] == [CAPTURE, REUSE]
    window._push(set_field(doc, 2, "color", "#123456", merge=False))
    want = plain(window)
    assert frames.after(qtbot, scene.request_render) != REUSE
    assert np.array_equal(shown(window), want)
    frames.close()


def test_the_heat_map_and_its_colour_bar_look_the_same_during_a_drag(qtbot, tubes) -> None:
    window, scene, doc = tubes, tubes.scene, tubes.doc
    view = window.heatmap
    assert view.set_visible(True)
    qtbot.waitUntil(lambda: view.last_distance is not None and not view.running,
                    timeout=20000)
    scene.render_now()
    frames = Frames(window)
    modes = []
    for _ in range(4):
        cps = doc.primitive(0).control_points
        modes.append(frames.after(qtbot, lambda cps=cps: scene.drag_control_point(
            0, 2, cps[2] + np.array([0.01, 0.0, 0.01]))))
    assert modes[0] == CAPTURE and REUSE in modes, modes
    assert_same_picture(window)
    # The map recoloured after the edits (an opaque surface, kept in the picture).
    qtbot.waitUntil(lambda: not view.running, timeout=20000)
    scene.render_now()
    assert_same_picture(window)
    frames.close()


@pytest.fixture
def no_native_window(monkeypatch):
    """Windows made from here on use pyvistaqt's QOpenGLWidget view (as on Wayland)."""
    from sweepedit.app import view3d

    monkeypatch.setattr(view3d.QGuiApplication, "platformName",
                        staticmethod(lambda: "wayland"))


def test_pyvistaqts_view_reuses_the_picture_too(qtbot, no_native_window, window,
                                                 small_files) -> None:
    from pyvistaqt import QtInteractor

    assert isinstance(window.plotter, QtInteractor)
    open_box(qtbot, window, small_files)
    window.doc.set_abstraction(Abstraction(primitives()))
    window.doc.select(0)
    frames = Frames(window)
    modes = []
    for _ in range(4):
        cp = window.doc.primitive(0).control_points[1] + np.array([0.0, 0.01, 0.01])
        modes.append(frames.after(qtbot, lambda cp=cp: window.scene.drag_control_point(
            0, 1, cp)))
    assert modes[-2:] == [REUSE, REUSE], modes
    assert_same_picture(window)
    frames.close()


def test_every_frame_of_a_random_editing_session_is_the_plain_frame(qtbot, tubes) -> None:
    """Drags (most steps, as in use) mixed with every other kind of change the view
    shows; after each step the frame is compared with the plain one."""
    from sweepedit.app.commands import DeletePrimitive, duplicate_primitive

    window, scene, doc, stack = tubes, tubes.scene, tubes.doc, tubes.stack
    camera = window.plotter.renderer.GetActiveCamera()
    rng = np.random.default_rng(27)

    def pick() -> int:
        return int(rng.integers(len(doc)))

    def drag() -> None:
        i = int(rng.choice([0, 0, 0, pick()]))  # mostly one primitive, as a drag does
        cp = int(rng.integers(3))
        scene.drag_control_point(i, cp, doc.primitive(i).control_points[cp]
                                 + rng.normal(size=3) * 0.015)

    def field(name: str, value) -> None:
        window._push(set_field(doc, pick(), name, value, merge=False))

    actions = {
        "drag": (0.45, drag),
        "end drag": (0.05, scene.end_drag),
        "colour": (0.05, lambda: field("color", f"#{int(rng.integers(1 << 24)):06x}")),
        "visible": (0.04, lambda: field("visible", bool(rng.integers(2)))),
        "profile": (0.05, lambda: field("a", float(rng.uniform(0.04, 0.08)))),
        "select": (0.05, lambda: doc.select(int(rng.integers(-1, len(doc))) % (len(doc) + 1)
                                            if rng.integers(4) else None)),
        "camera": (0.05, lambda: camera.Azimuth(float(rng.uniform(-8.0, 8.0)))),
        "target opacity": (0.04, lambda: scene.set_shape_opacity(
            float(rng.choice([0.3, 0.6, 1.0])))),
        "duplicate": (0.03, lambda: window._push(duplicate_primitive(doc, pick()))),
        "delete": (0.03, lambda: window._push(DeletePrimitive(pick())) if len(doc) > 3
                   else None),
        "undo": (0.04, lambda: stack.undo() if stack.can_undo else None),
        "heat map": (0.04, lambda: window.heatmap.set_visible(not window.heatmap.visible)),
        "events": (0.08, lambda: qtbot.wait(80)),  # heat map results arrive, etc.
    }
    names = list(actions)
    weights = np.array([actions[n][0] for n in names])
    modes, done = [], []
    for _ in range(90):
        name = str(rng.choice(names, p=weights / weights.sum()))
        actions[name][1]()
        done.append(name)
        scene.render_now()
        modes.append(scene.frame_reuse.mode)
        got = shown(window)
        want = plain(window)
        differ = np.any(got != want, axis=-1)
        assert not differ.any(), (f"after {done[-3:]}: {int(differ.sum())} pixels differ "
                                  f"from the plain frame ({modes[-1]})")
    assert modes.count(REUSE) >= 20 and CAPTURE in modes and PLAIN in modes, modes
