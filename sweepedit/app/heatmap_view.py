"""The heat map view: the target's surface coloured by its signed distance to the
abstraction (sweepedit.analysis.heatmap), with a colour bar.

Red is missed (the target's surface outside every primitive), blue is excess (the
target's surface buried inside the abstraction), white is on the abstraction's surface.
While it shows, the grey target is hidden and the primitives are drawn translucent, so
that the buried (blue) parts can be seen through them.

The distances are computed in a worker thread (a HeatMapper per shape, which reuses all
but the edited primitive's share) after each edit; only the newest result is applied,
on the GUI thread. The view listens to the Document only while it is shown, and
`close()` disconnects it for good.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np
import pyvista as pv
import vtk
from PySide6.QtCore import QObject, Signal

from sweepedit.app.background import DebouncedJob
from sweepedit.app.document import Connections, Document
from sweepedit.app.scene import SweepScene, shape_polydata
from sweepedit.geometry.model import SweepPrimitive

# The colour bar spans +-(this quantile of |distance|), rounded up, at least MIN_RANGE:
# a few far-off vertices must not wash the rest out.
RANGE_QUANTILE = 0.98
MIN_RANGE = 0.01
DELAY_MS = 60  # edits pause this long before a recomputation starts
PRIMITIVE_OPACITY = 0.2
# The colour bar's left edge and width as shares of the view's width; while it shows,
# the scene keeps the share right of its title and labels clear (SweepScene's margin).
BAR_LEFT, BAR_WIDTH = 0.88, 0.09
BAR_MARGIN = 1.0 - BAR_LEFT + 0.01
TITLE = "distance\n+ missed\n- excess"


def diverging_lut(n: int = 256) -> vtk.vtkLookupTable:
    """Blue (excess) - white (0) - red (missed), Moreland's diverging map."""
    ctf = vtk.vtkColorTransferFunction()
    ctf.SetColorSpaceToDiverging()
    ctf.AddRGBPoint(0.0, 0.230, 0.299, 0.754)
    ctf.AddRGBPoint(0.5, 0.865, 0.865, 0.865)
    ctf.AddRGBPoint(1.0, 0.706, 0.016, 0.150)
    lut = vtk.vtkLookupTable()
    lut.SetNumberOfTableValues(n)
    lut.Build()
    for i in range(n):
        r, g, b = ctf.GetColor(i / (n - 1))
        lut.SetTableValue(i, r, g, b, 1.0)
    return lut


def color_range(distance: np.ndarray) -> float:
    """Half the colour bar's span for distances (N,): a robust maximum, rounded up to
    two significant digits, at least MIN_RANGE."""
    finite = np.abs(distance[np.isfinite(distance)])
    if not finite.size:
        return MIN_RANGE
    top = float(np.quantile(finite, RANGE_QUANTILE))
    if top <= MIN_RANGE:
        return MIN_RANGE
    scale = 10.0 ** (np.floor(np.log10(top)) - 1)
    return float(np.ceil(top / scale) * scale)


class _HeatMapperCache:
    """One HeatMapper for the current target; used in the heat map's thread only."""

    def __init__(self) -> None:
        self._mapper: Any = None
        self._vertices: np.ndarray | None = None

    def compute(self, payload: tuple[np.ndarray, list[SweepPrimitive]]
                ) -> tuple[np.ndarray, float]:
        """(target vertices (V, 3), primitives) -> (signed distance (V,), seconds)."""
        from sweepedit.analysis.heatmap import HeatMapper

        vertices, primitives = payload
        started = time.perf_counter()
        if self._vertices is not vertices:
            self._mapper, self._vertices = None, None  # the old target's caches go
            self._mapper, self._vertices = HeatMapper(vertices), vertices
        heat = self._mapper.compute(primitives)
        return heat.distance, time.perf_counter() - started


class HeatMapView(QObject):
    """Shows and refreshes the heat map in a SweepScene. Signals: updated(seconds) after
    a result is shown; failed(message)."""

    updated = Signal(float)
    failed = Signal(str)

    def __init__(self, scene: SweepScene, document: Document,
                 parent: QObject | None = None) -> None:
        super().__init__(parent)
        self.scene = scene
        self.doc = document
        self.visible = False
        self.last_distance: np.ndarray | None = None
        self.last_seconds: float | None = None
        self.half_range = MIN_RANGE
        self._poly: pv.PolyData | None = None
        self._vertices: np.ndarray | None = None
        self._actor: vtk.vtkActor | None = None
        self._closed = False
        self._links = Connections()  # to the Document, while the map is shown

        self.lut = diverging_lut()
        self.scalar_bar = vtk.vtkScalarBarActor()
        self.scalar_bar.SetLookupTable(self.lut)
        self.scalar_bar.SetTitle(TITLE)
        self.scalar_bar.SetNumberOfLabels(5)
        self.scalar_bar.SetLabelFormat("%+.3f")
        self.scalar_bar.SetPosition(BAR_LEFT, 0.1)
        self.scalar_bar.SetWidth(BAR_WIDTH)
        self.scalar_bar.SetHeight(0.8)
        for prop in (self.scalar_bar.GetTitleTextProperty(),
                     self.scalar_bar.GetLabelTextProperty()):
            prop.SetColor(0.1, 0.1, 0.1)
            prop.ShadowOff()
            prop.ItalicOff()
            prop.BoldOff()
        self.scalar_bar.VisibilityOff()
        scene.plotter.renderer.AddViewProp(self.scalar_bar)

        self._job = DebouncedJob(_HeatMapperCache().compute, DELAY_MS, "sweepedit-heatmap",
                                 self)
        self._job.finished.connect(self._on_finished)
        self._job.failed.connect(self.failed)

    # -- showing --------------------------------------------------------------------------
    def set_visible(self, visible: bool) -> bool:
        """Show or hide the heat map; False (and nothing shown) without a target shape."""
        if self._closed:
            return not visible
        visible = bool(visible)
        if visible == self.visible:
            return True
        if visible:
            if self.doc.shape is None or not self._make_actor():
                return False
            self.visible = True
            self._links.connect(self.doc.edited, self.request)
            self._links.connect(self.doc.shape_changed, self._on_shape_changed)
            self._links.connect(self.doc.primitives_reset, self._style_primitives)
            self.scalar_bar.VisibilityOn()
            self.scene.set_right_margin(BAR_MARGIN)
            self._style_primitives()
            self.request(delay=False)
        else:
            self.visible = False
            self._links.disconnect_all()
            self._remove_actor()
            self.scalar_bar.VisibilityOff()
            self.scene.set_right_margin(0.0)
            self._style_primitives()
        self.scene.request_render()
        return True

    def _make_actor(self) -> bool:
        poly = shape_polydata(self.doc.shape)
        if poly is None or not poly.n_points:
            return False
        # Wait for the first result before colouring: grey until then.
        poly.point_data.set_array(np.zeros(poly.n_points), "distance")
        poly.point_data.active_scalars_name = "distance"
        mapper = vtk.vtkPolyDataMapper()
        mapper.SetInputData(poly)
        mapper.SetLookupTable(self.lut)
        mapper.SetScalarModeToUsePointData()
        mapper.SetColorModeToMapScalars()
        mapper.SetScalarRange(-self.half_range, self.half_range)
        mapper.ScalarVisibilityOff()
        actor = vtk.vtkActor()
        actor.SetMapper(mapper)
        prop = actor.GetProperty()
        prop.SetColor(0.8, 0.8, 0.8)
        prop.SetAmbient(0.15)
        prop.SetDiffuse(0.85)
        if poly.n_cells and poly.n_cells == poly.n_verts:  # a point cloud
            prop.SetRepresentationToPoints()
            prop.SetPointSize(4)
            prop.SetRenderPointsAsSpheres(True)
        actor.PickableOff()
        self.scene.plotter.renderer.AddActor(actor)
        self._poly, self._actor = poly, actor
        # A fresh array each time the target changes: the job keys its caches on it.
        self._vertices = np.array(poly.points, dtype=np.float64)
        self.scene.set_shape_visible(False)
        return True

    def _remove_actor(self) -> None:
        if self._actor is not None:
            self.scene.plotter.renderer.RemoveActor(self._actor)
        self._actor = self._poly = self._vertices = None
        self.last_distance = None
        self.scene.set_shape_visible(True)

    def _style_primitives(self) -> None:
        opacity = PRIMITIVE_OPACITY if self.visible else 1.0
        for i in range(self.scene.n_actors):
            self.scene.primitive_actor(i).GetProperty().SetOpacity(opacity)

    def _on_shape_changed(self) -> None:
        self._remove_actor()
        if self.doc.shape is None or not self._make_actor():
            self.set_visible(False)
            return
        self.request(delay=False)

    # -- computing ------------------------------------------------------------------------
    def request(self, delay: bool = True) -> None:
        """Recompute once edits pause (at once with delay=False)."""
        if not self.visible or self._vertices is None:
            return
        vertices = self._vertices
        # The primitives are read when the computation starts: the newest edit's.
        self._job.request(lambda: (vertices, [p.copy() for p in self.doc.primitives]),
                          delay=delay)

    @property
    def running(self) -> bool:
        """Whether a result is still to come."""
        return self._job.running

    def _on_finished(self, result: tuple[np.ndarray, float]) -> None:
        distance, seconds = result
        if self._poly is None or len(distance) != self._poly.n_points:
            return  # from a target that has been replaced meanwhile
        self.last_distance = distance
        self.last_seconds = seconds
        self.half_range = color_range(distance)
        # Infinite (no primitives): the far end of the bar.
        self._poly.point_data["distance"][:] = np.clip(distance, -self.half_range,
                                                       self.half_range)
        self._poly.Modified()
        mapper = self._actor.GetMapper()
        mapper.SetScalarRange(-self.half_range, self.half_range)
        mapper.ScalarVisibilityOn()
        self.lut.SetRange(-self.half_range, self.half_range)
        self.scene.request_render()
        self.updated.emit(seconds)

    # -- closing --------------------------------------------------------------------------
    def close(self, wait_ms: int = 5000) -> None:
        """Disconnect from the Document and stop the thread (when the window closes)."""
        if self._closed:
            return
        self.visible = False
        self._links.disconnect_all()
        self._closed = True
        self._job.shutdown(wait_ms)
