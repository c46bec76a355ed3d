"""The 3D view widget: a native VTK window where the windowing system has one, pyvistaqt's
QOpenGLWidget elsewhere, and safe to close."""

from __future__ import annotations

import numpy as np
import pytest


@pytest.mark.gui
def test_on_x11_the_view_is_a_native_window_that_shows_the_primitives(qtbot, window,
                                                                       small_files) -> None:
    from PySide6.QtCore import Qt
    from PySide6.QtGui import QColor, QGuiApplication, QImage

    from sweepedit.app.view3d import NativeView
    from sweepedit.geometry.model import palette_color

    if QGuiApplication.platformName() != "xcb":
        pytest.skip("X11 only")
    view = window.plotter
    assert isinstance(view, NativeView)
    # VTK draws into the widget's own window; Qt neither paints nor composes it.
    assert view.testAttribute(Qt.WidgetAttribute.WA_PaintOnScreen)
    assert view.testAttribute(Qt.WidgetAttribute.WA_NativeWindow)
    assert view.paintEngine() is None
    assert window.open_path(small_files["json"])
    image = window.view_image()
    w, h = view.render_window.GetSize()
    assert (image.width(), image.height()) == (w, h)
    want = QColor(palette_color(0))
    colours = [image.pixelColor(x, y) for x in range(0, w, 4) for y in range(0, h, 4)]
    bar = [c for c in colours if abs(c.hueF() - want.hueF()) < 0.03 and c.saturationF() > 0.4]
    assert len(bar) > 50, "the bar is not in the view's frame"
    # The frame is the one in VTK's buffer, the right way up: pyvista's own read of it.
    pixels = np.asarray(view.screenshot(return_img=True))[..., :3]
    rgb = image.convertToFormat(QImage.Format.Format_RGB888)
    rows = np.frombuffer(rgb.constBits(), np.uint8).reshape(h, rgb.bytesPerLine())
    assert np.array_equal(rows[:, :3 * w].reshape(h, w, 3), pixels)
    assert not np.array_equal(pixels[::-1], pixels)


@pytest.mark.gui
def test_a_closed_view_neither_renders_nor_reacts(qtbot, window) -> None:
    from PySide6.QtCore import QEvent, QPointF, Qt
    from PySide6.QtGui import QMouseEvent
    from PySide6.QtWidgets import QApplication

    view = window.plotter
    renders: list[int] = []
    view.render_window.AddObserver("EndEvent", lambda *_: renders.append(1))
    view.close()
    view.render()
    view.close()  # twice is harmless
    # Events that Qt may still deliver reach no finalized window.
    QApplication.sendEvent(view, QEvent(QEvent.Type.Leave))
    QApplication.sendEvent(view, QMouseEvent(QEvent.Type.MouseMove, QPointF(5, 5),
                                             QPointF(5, 5), Qt.MouseButton.NoButton,
                                             Qt.MouseButton.NoButton,
                                             Qt.KeyboardModifier.NoModifier))
    qtbot.wait(50)
    assert renders == []


def test_without_a_native_windowing_system_the_view_is_pyvistaqts(qtbot, monkeypatch) -> None:
    from PySide6.QtGui import QGuiApplication
    from PySide6.QtWidgets import QWidget
    from pyvistaqt import QtInteractor

    from sweepedit.app import view3d

    monkeypatch.setattr(view3d.QGuiApplication, "platformName",
                        staticmethod(lambda: "wayland"))
    assert QGuiApplication.platformName() == "wayland"
    parent = QWidget()
    qtbot.addWidget(parent)
    view = view3d.make_view(parent, multi_samples=0, lighting="none")
    try:
        assert isinstance(view, QtInteractor)
        assert not isinstance(view, view3d.NativeView)
    finally:
        view.close()
