"""The 3D view: a pyvista plotter that VTK draws straight into a native child window.

Why not pyvistaqt.QtInteractor: it is a QOpenGLWidget, so VTK renders into Qt's
framebuffer object and Qt then composes that into the window. On software OpenGL (VMs,
Xvfb, remote desktops) the mouse path of a drag measured 14 ms for the render into the
framebuffer object and ~17 ms for Qt's composition, where a native window renders the same
frame in 7-11 ms with nothing to compose (BENCHMARKS.md, issue 16). VTK's own
QVTKRenderWindowInteractor on a plain QWidget is that native window.

A native window needs a windowing system VTK can draw into (X11, Windows, macOS);
`make_view` falls back to pyvistaqt's widget elsewhere (Wayland without XWayland, Qt's
offscreen platform).
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from typing import Any

import numpy as np
import pyvista as pv
from PySide6.QtGui import QGuiApplication, QImage
from PySide6.QtWidgets import QWidget
from pyvista.plotting import BasePlotter
from pyvista.plotting.render_window_interactor import RenderWindowInteractor

# After PySide6: VTK's Qt glue takes the binding already loaded, on a QWidget base.
from vtkmodules.qt.QVTKRenderWindowInteractor import QVTKRenderWindowInteractor

# Qt platforms whose windows VTK's default render window can draw into.
NATIVE_PLATFORMS = ("xcb", "windows", "cocoa")


@contextlib.contextmanager
def _no_base_plotter_init() -> Iterator[None]:
    """PySide6 continues QWidget.__init__'s cooperative super() chain into BasePlotter,
    which would then run with no arguments; it runs once, explicitly, afterwards."""
    original = BasePlotter.__init__
    BasePlotter.__init__ = lambda self, *args, **kwargs: None  # type: ignore[method-assign]
    try:
        yield
    finally:
        BasePlotter.__init__ = original  # type: ignore[method-assign]


class _ClosedInteractor:
    """Stands in for the VTK interactor once the view is closed: Qt may still deliver
    leave or resize events to the widget, and they must not reach a finalized window."""

    def __getattr__(self, _name: str) -> Any:
        return lambda *args, **kwargs: None


class NativeView(QVTKRenderWindowInteractor, BasePlotter):
    """A pyvista plotter drawn by VTK into this widget's own native window."""

    def __init__(self, parent: QWidget | None = None, multi_samples: int = 0,
                 **kwargs: Any) -> None:
        with _no_base_plotter_init():
            QVTKRenderWindowInteractor.__init__(self, parent)
        BasePlotter.__init__(self, **kwargs)
        self.interactor = self
        self.ren_win = self.GetRenderWindow()
        self.ren_win.SetMultiSamples(multi_samples)
        # Colour only to the window: VTK's default also copies the depth buffer into the
        # window's, through a full-screen shader pass that nothing here reads (picking,
        # screenshots and depth reads use VTK's own framebuffers). 4 ms of a drag's frame
        # on software GL (BENCHMARKS.md, issue 16).
        self.ren_win.SetFrameBlitModeToBlitToCurrent()
        for renderer in self.renderers:
            renderer.view_isometric()
            self.ren_win.AddRenderer(renderer)
        self.background_color = pv.global_theme.background
        self._off_screen = False
        self.iren = RenderWindowInteractor(self, interactor=self.ren_win.GetInteractor())
        # pyvista's own move observer re-renders on every move; the scene decides.
        self.iren.interactor.RemoveObservers("MouseMoveEvent")
        self.iren.initialize()
        self.enable_trackball_style()
        self._observers: dict = {}
        self.iren.add_observer("KeyPressEvent", self.key_press_event)
        self.reset_key_events()
        self._first_time = False  # BasePlotter: the window exists and renders

    def render(self) -> None:
        """Render now (nothing once closed: the window is finalized then)."""
        if getattr(self, "_closed", True):
            return
        self._rendered = True
        BasePlotter.render(self)

    def grabFramebuffer(self) -> QImage:  # noqa: N802 (as QOpenGLWidget's)
        """The last rendered frame, as QOpenGLWidget.grabFramebuffer gives it."""
        return frame_image(self.ren_win)

    def close(self) -> None:  # type: ignore[override]
        """Finalize the render window before Qt destroys the native window under it."""
        if getattr(self, "_closed", True):
            return
        BasePlotter.close(self)
        QWidget.close(self)
        self._Iren = _ClosedInteractor()
        self._RenderWindow = None


def frame_image(render_window: Any) -> QImage:
    """The render window's last frame as an RGB QImage (a copy), top row first."""
    from pyvista.plotting.utilities import image_from_window

    rows = np.ascontiguousarray(image_from_window(render_window, ignore_alpha=True))
    h, w, _ = rows.shape
    return QImage(rows.data, w, h, 3 * w, QImage.Format.Format_RGB888).copy()


def make_view(parent: QWidget | None = None, **kwargs: Any) -> Any:
    """The app's 3D view: a NativeView where the windowing system allows one (X11,
    Windows, macOS), pyvistaqt's QtInteractor elsewhere; `kwargs` go to the plotter."""
    if QGuiApplication.platformName() in NATIVE_PLATFORMS:
        return NativeView(parent, **kwargs)
    from pyvistaqt import QtInteractor  # heavy import, only when a window is made

    return QtInteractor(parent, auto_update=False, **kwargs)
