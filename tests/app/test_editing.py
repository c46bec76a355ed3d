"""Editing like a 3D tool, in a real window under Xvfb with real mouse and key events:
control points inserted and deleted from the context menu and shortcuts, mirror and
symmetric editing, constrained / snapped / cancelled drags, multi-select edits as one
undo step, camera presets."""

from __future__ import annotations

import numpy as np
import pytest
from gui_helpers import move, open_box, qpoint

from sweepedit.app.commands import (
    SetControlPoints,
    insert_control_point,
    move_control_point,
    set_field,
    transform_primitive,
)
from sweepedit.geometry.axis_edit import mirror_points
from sweepedit.geometry.sweep import axis_points

pytestmark = pytest.mark.gui

DENSE = np.linspace(0.0, 1.0, 4001)
ASYMMETRIC = np.array([[-0.4, -0.1, 0.05], [-0.2, 0.15, 0.1], [0.05, 0.05, -0.08]])


def menu_action(window, text: str):
    menu = window.mouse.menu
    assert menu is not None
    for action in menu.actions():
        if action.text().startswith(text):
            return action
    raise AssertionError(f"no '{text}' in {[a.text() for a in menu.actions()]}")


def test_insert_and_delete_control_points_from_the_context_menu_and_keys(
        qtbot, window, small_files) -> None:
    from PySide6.QtCore import QPoint, Qt

    open_box(qtbot, window, small_files)
    window.doc.select(0)
    window.scene.view_preset("top")  # the bar's axis lies in the view plane
    qtbot.wait(50)
    before = window.doc.primitive(0).copy()
    old_axis = axis_points(before.control_points[None], DENSE)[0]

    # Right-click on the axis (no motion): "Insert control point here".
    at = axis_points(before.control_points[None], np.array([0.3]))[0, 0]
    qtbot.mouseClick(window.plotter, Qt.MouseButton.RightButton, pos=qpoint(window, at))
    menu_action(window, "Insert control point here").trigger()
    window.mouse.menu.close()
    after = window.doc.primitive(0)
    assert after.n_control_points == 4 and len(window.stack) == 1
    # 3 -> 4 is exact: the same axis at the same parameter, densely.
    assert np.max(np.abs(axis_points(after.control_points[None], DENSE)[0] - old_axis)) < 1e-12
    assert after.scaling == before.scaling

    # I (the shortcut) inserts again: 4 -> 5 stays within 1% of the axis length.
    qtbot.keyClick(window.plotter, Qt.Key.Key_I)
    five = window.doc.primitive(0).control_points.copy()
    assert len(five) == 5 and len(window.stack) == 2
    new_axis = axis_points(five[None], DENSE[::4])[0]
    gap = np.sqrt(((new_axis[:, None] - old_axis[None, ::4]) ** 2).sum(-1))
    length = np.linalg.norm(np.diff(old_axis, axis=0), axis=1).sum()
    assert max(gap.min(0).max(), gap.min(1).max()) <= 0.01 * length

    # Right-click on a handle: "Delete control point 2"; and Shift+Del under the cursor.
    qtbot.mouseClick(window.plotter, Qt.MouseButton.RightButton, pos=qpoint(window, five[1]))
    menu_action(window, "Delete control point 2").trigger()
    window.mouse.menu.close()
    assert window.doc.primitive(0).n_control_points == 4
    handle = qpoint(window, window.doc.primitive(0).control_points[2])
    qtbot.mouseMove(window.plotter, handle + QPoint(1, 0))
    qtbot.mouseMove(window.plotter, handle)
    qtbot.keyClick(window.plotter, Qt.Key.Key_Delete, Qt.KeyboardModifier.ShiftModifier)
    assert window.doc.primitive(0).n_control_points == 3
    # Never below 3: the menu entry is disabled and the key refuses.
    qtbot.mouseClick(window.plotter, Qt.MouseButton.RightButton,
                     pos=qpoint(window, window.doc.primitive(0).control_points[0]))
    assert not menu_action(window, "Delete control point 1").isEnabled()
    window.mouse.menu.close()
    assert len(window.stack) == 4
    for _ in range(4):
        window.stack.undo()
    assert np.array_equal(window.doc.primitive(0).control_points, before.control_points)
    assert window.doc.primitive(0).scaling == before.scaling


def assert_mirrored(doc, i: int, j: int, axis: int) -> None:
    p, q = doc.primitive(i), doc.primitive(j)
    assert np.array_equal(mirror_points(p.control_points, axis), q.control_points)
    assert (p.a, p.b, p.degree, p.scaling) == (q.a, q.b, q.degree, q.scaling)


def test_mirror_and_symmetric_editing_keep_the_pair_mirrored(qtbot, window,
                                                             small_files) -> None:
    from PySide6.QtCore import QPoint, Qt

    open_box(qtbot, window, small_files)
    window.stack.push(SetControlPoints(0, ASYMMETRIC))
    window.doc.select(0)
    qtbot.keyClick(window.plotter, Qt.Key.Key_X, Qt.KeyboardModifier.ControlModifier
                   | Qt.KeyboardModifier.AltModifier)  # Mirror X
    assert len(window.doc) == 3 and window.doc.selected_indices == [2]
    assert_mirrored(window.doc, 0, 2, 0)
    assert window.doc.primitive(2).name == "bar mirror X"
    steps = len(window.stack)

    qtbot.keyClick(window.plotter, Qt.Key.Key_M, Qt.KeyboardModifier.ShiftModifier)
    assert window.act_symmetric.isChecked() and window.stack.symmetric

    rng = np.random.default_rng(16)
    doc, stack = window.doc, window.stack
    for k in range(100):
        i = int(rng.choice([0, 2]))
        prim = doc.primitive(i)
        kind = k % 5
        if kind == 0:  # the mouse path's method
            cp = int(rng.integers(prim.n_control_points))
            window.scene.drag_control_point(i, cp, prim.control_points[cp]
                                            + rng.normal(size=3) * 0.02)
            window.scene.end_drag()
        elif kind == 1:
            name = str(rng.choice(["a", "b", "degree"]))
            value = {"a": rng.uniform(0.03, 0.12), "b": rng.uniform(0.03, 0.12),
                     "degree": rng.uniform(1.0, 4.0)}[name]
            window._push(set_field(doc, i, name, value, merge=False))
        elif kind == 2:
            window._push(set_field(doc, i, "scaling", tuple(rng.uniform(-0.2, 0.2, 2)),
                                   merge=False))
        elif kind == 3:
            m = np.eye(4)
            m[:3, 3] = rng.normal(size=3) * 0.02
            window._push(transform_primitive(doc, i, m))
        elif prim.n_control_points < 5 and k % 10 == 4:
            window._push(insert_control_point(doc, i, float(rng.uniform())))
        else:
            window._push(move_control_point(doc, i, 0, prim.control_points[0]
                                            + rng.normal(size=3) * 0.01))
        assert_mirrored(doc, 0, 2, 0)
    assert doc.primitive(0).n_control_points > 3  # insertions were mirrored too

    # A real drag of a handle of the copy moves the original, mirrored, in one step.
    doc.select(2)
    qtbot.wait(20)
    n = len(stack)
    start = qpoint(window, doc.primitive(2).control_points[1])
    qtbot.mousePress(window.plotter, Qt.MouseButton.LeftButton, pos=start)
    assert window.scene.dragging
    for k in range(1, 5):
        move(window, start + QPoint(6 * k, -5 * k))
    qtbot.mouseRelease(window.plotter, Qt.MouseButton.LeftButton, pos=start + QPoint(24, -20))
    assert len(stack) == n + 1
    assert_mirrored(doc, 0, 2, 0)
    # A locked partner stays as it is.
    window._push(set_field(doc, 2, "locked", True, merge=False))
    held = doc.primitive(2).control_points.copy()
    window._push(move_control_point(doc, 0, 1, doc.primitive(0).control_points[1] + 0.01))
    assert np.array_equal(doc.primitive(2).control_points, held)
    stack.undo()
    other = doc.primitive(1).copy()
    while len(stack) > steps:
        stack.undo()
        assert_mirrored(doc, 0, 2, 0)
    assert np.array_equal(doc.primitive(0).control_points, ASYMMETRIC)
    assert np.array_equal(doc.primitive(1).control_points, other.control_points)


def drag_handle(qtbot, window, prim: int, cp: int):
    from PySide6.QtCore import Qt

    start = qpoint(window, window.doc.primitive(prim).control_points[cp])
    qtbot.mousePress(window.plotter, Qt.MouseButton.LeftButton, pos=start)
    assert window.scene.dragging
    return start


def test_constrained_snapped_and_cancelled_drags(qtbot, window, small_files) -> None:
    from PySide6.QtCore import QPoint, Qt

    open_box(qtbot, window, small_files)
    window.doc.select(0)
    window.scene.view_preset("isometric")
    qtbot.wait(50)
    plotter = window.plotter
    before = window.doc.primitive(0).control_points.copy()

    # X during the drag: only x changes, y and z keep their exact values.
    start = drag_handle(qtbot, window, 0, 2)
    qtbot.keyClick(plotter, Qt.Key.Key_X)
    assert window.scene.constraint == ("axis", 0)
    for k in range(1, 6):
        move(window, start + QPoint(7 * k, -4 * k))
    assert "along X" in window.scene.drag_text and "offset" in window.scene.drag_text
    qtbot.mouseRelease(plotter, Qt.MouseButton.LeftButton, pos=start + QPoint(35, -20))
    after = window.doc.primitive(0).control_points
    assert after[2, 0] != before[2, 0]
    assert np.array_equal(after[2, 1:], before[2, 1:])
    assert np.array_equal(after[:2], before[:2]) and len(window.stack) == 1

    # Shift+Z: in the XY plane, z exact; with Ctrl the offset is on the 0.01 grid.
    mid = window.doc.primitive(0).control_points.copy()
    start = drag_handle(qtbot, window, 0, 1)
    qtbot.keyClick(plotter, Qt.Key.Key_Z, Qt.KeyboardModifier.ShiftModifier)
    assert window.scene.constraint == ("plane", 2)
    for k in range(1, 6):
        move(window, start + QPoint(9 * k, 5 * k), Qt.KeyboardModifier.ControlModifier)
    qtbot.mouseRelease(plotter, Qt.MouseButton.LeftButton, pos=start + QPoint(45, 25))
    moved = window.doc.primitive(0).control_points[1]
    offset = (moved - mid[1]) / 0.01
    assert moved[2] == mid[1, 2]
    assert np.allclose(offset, np.round(offset), atol=1e-9) and np.any(offset != 0)
    assert len(window.stack) == 2

    # Esc: the point goes back exactly, and nothing is left to undo or redo.
    start = drag_handle(qtbot, window, 0, 0)
    for k in range(1, 6):
        move(window, start + QPoint(-6 * k, 8 * k))
    assert not np.array_equal(window.doc.primitive(0).control_points[0], mid[0])
    qtbot.keyClick(plotter, Qt.Key.Key_Escape)
    assert not window.scene.dragging
    qtbot.mouseRelease(plotter, Qt.MouseButton.LeftButton, pos=start + QPoint(-30, 40))
    final = window.doc.primitive(0).control_points
    assert np.array_equal(final[0], mid[0]) and np.array_equal(final[2:], mid[2:])
    assert len(window.stack) == 2 and not window.stack.can_redo


def test_multi_select_edits_are_one_undo_step(qtbot, window, small_files) -> None:
    from PySide6.QtCore import QPoint, Qt

    open_box(qtbot, window, small_files)
    window.scene.view_preset("top")
    window.set_shape_visible(False)
    qtbot.wait(50)
    doc, stack = window.doc, window.stack
    # The cross lies inside the bar: lift it above the bar's right half first.
    stack.push(SetControlPoints(1, [[0.3, -0.2, 0.4], [0.3, 0.0, 0.41], [0.3, 0.2, 0.4]]))
    stack.clear()
    before = [p.copy() for p in doc.primitives]
    # Click the bar, then Ctrl+click the cross: both selected, the cross the primary.
    bar = qpoint(window, [-0.35, 0.0, 0.0])
    cross = qpoint(window, [0.3, 0.1, 0.4])
    qtbot.mouseClick(window.plotter, Qt.MouseButton.LeftButton, pos=bar)
    assert doc.selected_indices == [0]
    qtbot.mouseClick(window.plotter, Qt.MouseButton.LeftButton,
                     Qt.KeyboardModifier.ControlModifier, pos=cross)
    assert doc.selected_indices == [0, 1] and doc.selection == 1
    assert {window.list_panel.tree.indexOfTopLevelItem(it)
            for it in window.list_panel.tree.selectedItems()} == {0, 1}

    # Move both with the transform section: one undo step restores both exactly.
    panel = window.props_panel
    panel.translate_spins[2].setValue(0.05)
    panel.apply_transform()
    assert len(stack) == 1
    for p, q in zip(doc.primitives, before, strict=True):
        assert np.allclose(p.control_points - q.control_points, [0, 0, 0.05])
    # Hide both (H), mirror both (Ctrl+Alt+Y), delete all (Ctrl+A, Delete): a step each.
    qtbot.keyClick(window.plotter, Qt.Key.Key_H)
    assert not any(p.visible for p in doc.primitives) and len(stack) == 2
    qtbot.keyClick(window.plotter, Qt.Key.Key_Y, Qt.KeyboardModifier.ControlModifier
                   | Qt.KeyboardModifier.AltModifier)
    assert len(doc) == 4 and doc.selected_indices == [2, 3] and len(stack) == 3
    qtbot.keyClick(window.plotter, Qt.Key.Key_A, Qt.KeyboardModifier.ControlModifier)
    assert doc.selected_indices == [0, 1, 2, 3]
    qtbot.keyClick(window.plotter, Qt.Key.Key_Delete)
    assert len(doc) == 0 and len(stack) == 4
    for expected in (4, 2, 2, 2):
        stack.undo()
        assert len(doc) == expected
    for p, q in zip(doc.primitives, before, strict=True):
        assert np.array_equal(p.control_points, q.control_points) and p.visible
    # Ctrl+click on a selected primitive takes it out of the selection.
    doc.set_selection([0, 1])
    qtbot.mouseClick(window.plotter, Qt.MouseButton.LeftButton,
                     Qt.KeyboardModifier.ControlModifier, pos=cross + QPoint(0, 0))
    assert doc.selected_indices == [0]


def test_camera_presets_look_along_the_expected_direction(qtbot, window, small_files) -> None:
    from PySide6.QtCore import Qt

    open_box(qtbot, window, small_files)
    camera = window.plotter.renderer.GetActiveCamera
    pad, ctrl = Qt.KeyboardModifier.KeypadModifier, Qt.KeyboardModifier.ControlModifier
    expected = [(Qt.Key.Key_1, pad, (0, 1, 0), (0, 0, 1)),  # front: looking along +y
                (Qt.Key.Key_1, pad | ctrl, (0, -1, 0), (0, 0, 1)),  # back
                (Qt.Key.Key_3, pad, (-1, 0, 0), (0, 0, 1)),  # right
                (Qt.Key.Key_3, pad | ctrl, (1, 0, 0), (0, 0, 1)),  # left
                (Qt.Key.Key_7, pad, (0, 0, -1), (0, 1, 0)),  # top
                (Qt.Key.Key_7, pad | ctrl, (0, 0, 1), (0, -1, 0)),  # bottom
                (Qt.Key.Key_9, pad, -np.ones(3) / np.sqrt(3), None)]  # isometric
    for key, modifiers, direction, up in expected:
        qtbot.keyClick(window.plotter, key, modifiers)
        assert np.allclose(camera().GetDirectionOfProjection(), direction, atol=1e-9), key
        if up is not None:
            assert np.allclose(camera().GetViewUp(), up, atol=1e-9)
    assert not window.scene.orthographic
    qtbot.keyClick(window.plotter, Qt.Key.Key_5, pad)
    assert window.scene.orthographic and camera().GetParallelProjection()
    qtbot.keyClick(window.plotter, Qt.Key.Key_5, pad)
    assert not window.scene.orthographic
    # Numpad . frames the selection: the focal point goes to the selected primitive.
    window.doc.select(1)
    qtbot.keyClick(window.plotter, Qt.Key.Key_Period, pad)
    b = np.array(window.scene.primitive_actor(1).GetBounds())
    assert np.allclose(camera().GetFocalPoint(), (b[0::2] + b[1::2]) / 2, atol=1e-9)
    whole = np.array(window.plotter.renderer.ComputeVisiblePropBounds())
    assert not np.allclose((b[0::2] + b[1::2]) / 2, (whole[0::2] + whole[1::2]) / 2)


def test_dragging_a_control_point_leaves_the_primitive_list_unpainted(qtbot, window,
                                                                      small_files) -> None:
    """A drag changes nothing the list shows: its rows are not repainted on every move
    (on software GL each repaint is recomposed into the window); a colour change still
    shows in the row's swatch."""
    from PySide6.QtCore import QEvent, QObject, Qt

    class PaintCounter(QObject):
        def __init__(self) -> None:
            super().__init__()
            self.count = 0

        def eventFilter(self, _obj, event) -> bool:  # noqa: N802 (Qt API)
            self.count += event.type() == QEvent.Type.Paint
            return False

    window.open_path(small_files["obj"])
    window.open_path(small_files["json"])
    window.doc.select(0)
    tree = window.list_panel.tree
    counter = PaintCounter()
    tree.viewport().installEventFilter(counter)
    qtbot.wait(100)
    counter.count = 0
    start = window.doc.primitive(0).control_points[1].copy()
    for k in range(20):
        assert window.scene.drag_control_point(0, 1, start + np.array([0, 0.002 * k, 0]))
        qtbot.wait(5)
    window.scene.end_drag()
    qtbot.wait(50)
    assert counter.count == 0
    # A tooltip still tells the current profile.
    assert "a=0.220" in tree.topLevelItem(0).toolTip(0)

    def swatch_centre() -> tuple[int, int, int]:
        icon = tree.topLevelItem(0).icon(0)
        colour = icon.pixmap(14, 14).toImage().pixelColor(7, 7)
        return colour.red(), colour.green(), colour.blue()

    window.stack.push(set_field(window.doc, 0, "color", "#00ff00"))
    qtbot.wait(50)
    assert counter.count > 0
    assert swatch_centre() == (0, 255, 0)
    window.stack.undo()
    assert tree.topLevelItem(0).data(0, Qt.ItemDataRole.UserRole) != "#00ff00"
    assert swatch_centre() != (0, 255, 0)
