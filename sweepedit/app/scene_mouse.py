"""The mouse and keys over the 3D view: a Qt event filter that lets handle drags win over
camera moves, selects on click, constrains, snaps and cancels drags, and opens the
scene's context menu. It acts only through the SweepScene's methods."""

from __future__ import annotations

from typing import Any

import numpy as np
from PySide6.QtCore import QEvent, QObject, Qt
from PySide6.QtGui import QAction
from PySide6.QtWidgets import QMenu

from sweepedit.app.scene import CLICK_SLOP, SweepScene

# X, Y, Z during a drag: the coordinate the drag is held to (or, with Shift, across).
_AXIS_KEYS = {Qt.Key.Key_X: 0, Qt.Key.Key_Y: 1, Qt.Key.Key_Z: 2}


class SceneMouse(QObject):
    """Qt event filter on the interactor widget: handle drags win over camera moves.

    Presses on a handle are swallowed (VTK never starts a rotation); other presses go on
    to VTK, and a press-release without motion selects the primitive under the cursor
    (Ctrl or Shift: adds to or takes from the selection). During a drag, X/Y/Z constrain
    it to that axis, Shift+X/Y/Z to the plane normal to it, Ctrl snaps, Esc cancels. A
    right click without motion opens the context menu (`menu`, with the scene's control
    point entries and then `menu_actions`, which the window fills).
    Other key presses are swallowed too, so VTK's single-letter bindings (q quits, w shows
    wireframes) cannot fire; the window's shortcuts still work (they are handled first).
    """

    def __init__(self, scene: SweepScene, widget: Any) -> None:
        super().__init__(widget)
        self.scene = scene
        self.widget = widget
        self._press: tuple[float, float] | None = None
        self._right_press: tuple[float, float] | None = None
        self._last: tuple[float, float] = (0.0, 0.0)
        self.menu: QMenu | None = None
        self.menu_actions: list[QAction | None] = []  # None: a separator
        widget.installEventFilter(self)

    def _display(self, event: Any) -> tuple[float, float]:
        pos = event.position()
        ratio = self.widget.devicePixelRatioF()
        return pos.x() * ratio, (self.widget.height() - pos.y() - 1) * ratio

    def _drag_key(self, event: Any) -> bool:
        """Handle a key press during a drag; True when it was one of the drag's keys."""
        key = event.key()
        if key == Qt.Key.Key_Escape:
            self.scene.cancel_drag()
            return True
        if key in _AXIS_KEYS:
            plane = bool(event.modifiers() & Qt.KeyboardModifier.ShiftModifier)
            self.scene.set_constraint("plane" if plane else "axis", _AXIS_KEYS[key])
        elif key != Qt.Key.Key_Control:
            return False
        # Re-place the point at once for the new constraint (or snap).
        snap = bool(event.modifiers() & Qt.KeyboardModifier.ControlModifier)
        self.scene.drag_to(*self._last, snap=snap)
        return True

    def show_menu(self, x: float, y: float, global_pos: Any) -> QMenu:
        """The context menu for display point x, y (not blocking: tests trigger its
        actions; `menu` keeps it)."""
        scene = self.scene
        if self.menu is not None:
            self.menu.deleteLater()  # the last one (its actions belong to the window)
        menu = QMenu(self.widget)
        hit = scene.pick_handle(x, y)
        t = scene.axis_hit(x, y)
        prim = scene.doc.selected
        if hit is not None:
            n = scene.doc.primitive(hit[0]).n_control_points
            a = menu.addAction(f"Delete control point {hit[1] + 1}",
                               lambda cp=hit[1]: scene.delete_control_point(cp))
            a.setEnabled(n > 3 and not scene.doc.primitive(hit[0]).locked)
        if t is not None:
            menu.addAction("Insert control point here", lambda: scene.insert_control_point(t))
        elif prim is not None:
            menu.addAction("Insert control point", lambda: scene.insert_control_point(None))
        for action in self.menu_actions:
            if action is None:
                menu.addSeparator()
            else:
                menu.addAction(action)
        self.menu = menu
        menu.popup(global_pos)
        return menu

    def eventFilter(self, obj: QObject, event: QEvent) -> bool:  # noqa: N802 (Qt API)
        t = event.type()
        if (t == QEvent.Type.ShortcutOverride and self.scene.dragging
                and event.key() in (*_AXIS_KEYS, Qt.Key.Key_Escape)):
            event.accept()  # the drag's keys win over the window's shortcuts
            return True
        if t == QEvent.Type.KeyPress and self.scene.dragging and self._drag_key(event):
            return True
        if t == QEvent.Type.KeyRelease and self.scene.dragging \
                and event.key() == Qt.Key.Key_Control:
            self.scene.drag_to(*self._last, snap=False)
            return True
        if t in (QEvent.Type.KeyPress, QEvent.Type.KeyRelease):
            return True
        if t == QEvent.Type.MouseButtonPress and event.button() == Qt.MouseButton.LeftButton:
            x, y = self._display(event)
            hit = self.scene.pick_handle(x, y)
            if hit is not None and self.scene.begin_drag(hit[0], hit[1], x, y):
                self._last = (x, y)
                self.widget.setFocus()  # the drag's keys (X, Y, Z, Esc) come here
                return True
            self._press = (x, y)
            return False
        if t == QEvent.Type.MouseButtonPress and event.button() == Qt.MouseButton.RightButton:
            self._right_press = self._display(event)
            return False
        if t == QEvent.Type.MouseMove:
            x, y = self._display(event)
            if self.scene.dragging:
                self._last = (x, y)
                snap = bool(event.modifiers() & Qt.KeyboardModifier.ControlModifier)
                self.scene.drag_to(x, y, snap=snap)
                return True
            if event.buttons() == Qt.MouseButton.NoButton:
                over = self.scene.hover(x, y)
                self.widget.setCursor(Qt.CursorShape.PointingHandCursor if over
                                      else Qt.CursorShape.ArrowCursor)
            return False
        if t == QEvent.Type.MouseButtonRelease and event.button() == Qt.MouseButton.LeftButton:
            x, y = self._display(event)
            if self.scene.dragging:
                self.scene.end_drag()
                return True
            if self._press is not None and np.hypot(x - self._press[0],
                                                    y - self._press[1]) <= CLICK_SLOP:
                additive = bool(event.modifiers() & (Qt.KeyboardModifier.ControlModifier
                                                     | Qt.KeyboardModifier.ShiftModifier))
                self.scene.click(x, y, additive=additive)
            self._press = None
        if t == QEvent.Type.MouseButtonRelease and event.button() == Qt.MouseButton.RightButton:
            x, y = self._display(event)
            press, self._right_press = self._right_press, None
            if press is not None and np.hypot(x - press[0], y - press[1]) <= CLICK_SLOP:
                self.show_menu(x, y, event.globalPosition().toPoint())
        return False
