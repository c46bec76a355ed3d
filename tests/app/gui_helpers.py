"""Helpers for the window tests: real mouse events at world points, the box scene."""

from __future__ import annotations

import numpy as np


def qpoint(window, world: np.ndarray):
    """The widget position (logical pixels) of a world point."""
    from PySide6.QtCore import QPoint

    plotter = window.plotter
    ratio = plotter.devicePixelRatioF()
    d = window.scene.world_to_display(np.asarray(world, float)[None])[0]
    return QPoint(round(d[0] / ratio), round(plotter.height() - 1 - d[1] / ratio))


def move(window, pos, modifiers=None) -> None:
    """A real mouse move with the left button held (and modifiers, e.g. Ctrl)."""
    from PySide6.QtCore import QPointF, Qt
    from PySide6.QtGui import QMouseEvent
    from PySide6.QtWidgets import QApplication

    plotter = window.plotter
    event = QMouseEvent(QMouseEvent.Type.MouseMove, QPointF(pos),
                        QPointF(plotter.mapToGlobal(pos)), Qt.MouseButton.NoButton,
                        Qt.MouseButton.LeftButton,
                        modifiers if modifiers is not None else Qt.KeyboardModifier.NoModifier)
    QApplication.sendEvent(plotter, event)


def open_box(qtbot, window, small_files) -> None:
    window.open_path(small_files["obj"])
    window.open_path(small_files["json"])
    # Shortcuts reach an active window only.
    window.activateWindow()
    window.plotter.setFocus()
    qtbot.waitUntil(window.isActiveWindow, timeout=5000)
