"""The 3D view: the target shape, one actor per primitive, and the selected primitive's
axis with draggable control-point handles.

The scene listens to the Document and keeps one VTK actor per primitive; an edit
re-sweeps only the primitive that changed and writes its points into the existing
PolyData in place (no new actor), which keeps dragging interactive. The axis, the
control polygon and the handles live in an overlay renderer (a layer above, sharing the
camera) so they stay visible although the axis runs inside the solid. Between the two,
the frame reuse (sweepedit.app.frame_reuse) redraws only the actors an edit changed.

Mouse dragging (sweepedit.app.scene_mouse) goes through `begin_drag` / `drag_to` /
`end_drag`, which call `drag_control_point` - the same method the tests and benchmarks
call.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import pyvista as pv
import vtk
from PySide6.QtGui import QColor

from sweepedit.app.commands import (
    CommandStack,
    delete_control_point,
    insert_control_point,
    move_control_point,
)
from sweepedit.app.document import DISPLAY, GEOMETRY, Connections, Document
from sweepedit.app.frame_reuse import FrameReuse
from sweepedit.errors import InvalidPrimitiveError, SweepeditError
from sweepedit.geometry.mesher import TriangleMesh, sweep_mesh, sweep_meshes
from sweepedit.geometry.model import SweepPrimitive
from sweepedit.geometry.sweep import axis_points

# A plain background: a gradient is a full-screen shader pass (~8 ms on software GL).
BACKGROUND = "#eef1f4"
SHAPE_COLOR = "#9aa3ad"
AXIS_COLOR = "#111111"
POLYGON_COLOR = "#7a7a7a"
HANDLE_COLOR = (255, 255, 255)
HANDLE_HOVER_COLOR = (255, 209, 102)
HANDLE_LOCKED_COLOR = (150, 150, 150)
HANDLE_PIXELS = 16  # diameter on screen
PICK_PIXELS = 11  # how close (in device pixels) a click must be to a handle
AXIS_SAMPLES = 128
CLICK_SLOP = 4  # pixels a press may move and still count as a click
GRID_STEP = 0.01  # Ctrl-drag snaps the offset to this (normalised frame: the shape is ~1)
DRAG_KEYS = "(X/Y/Z axis, Shift plane, Ctrl snap, Esc cancel)"  # shown during a drag
AXIS_PICK_SAMPLES = 256
# While a primitive is selected (its handles shown), the view keeps the camera's clipping
# range while the range it needs lies inside and is at least CLIP_SLACK of it at either
# end; a new range is widened by CLIP_MARGIN.
CLIP_SLACK = 0.5
CLIP_MARGIN = 0.9
# Camera presets (Blender's numpad views, z up): the direction from the focal point to
# the camera, and the view-up vector.
VIEW_PRESETS: dict[str, tuple[tuple[float, float, float], tuple[float, float, float]]] = {
    "front": ((0.0, -1.0, 0.0), (0.0, 0.0, 1.0)),
    "back": ((0.0, 1.0, 0.0), (0.0, 0.0, 1.0)),
    "right": ((1.0, 0.0, 0.0), (0.0, 0.0, 1.0)),
    "left": ((-1.0, 0.0, 0.0), (0.0, 0.0, 1.0)),
    "top": ((0.0, 0.0, 1.0), (0.0, 1.0, 0.0)),
    "bottom": ((0.0, 0.0, -1.0), (0.0, -1.0, 0.0)),
    "isometric": ((1.0, 1.0, 1.0), (0.0, 0.0, 1.0)),
}


@dataclass
class _PrimitiveActor:
    poly: pv.PolyData
    actor: vtk.vtkActor


def _polydata(mesh: TriangleMesh) -> pv.PolyData:
    poly = pv.PolyData.from_regular_faces(np.array(mesh.vertices), mesh.faces)
    poly.point_data.set_array(np.array(mesh.normals), "Normals")
    poly.GetPointData().SetActiveNormals("Normals")
    return poly


def _rgb(color: str) -> tuple[float, float, float]:
    c = QColor(color)
    if not c.isValid():
        c = QColor("#888888")
    return c.redF(), c.greenF(), c.blueF()


def _mapped_actor(poly: pv.PolyData) -> vtk.vtkActor:
    """A plain actor showing `poly` in its property's single colour."""
    mapper = vtk.vtkPolyDataMapper()
    mapper.SetInputData(poly)
    mapper.ScalarVisibilityOff()
    actor = vtk.vtkActor()
    actor.SetMapper(mapper)
    return actor


def _surface_actor(poly: pv.PolyData, color: str) -> vtk.vtkActor:
    """An actor for a closed, outward-oriented surface: back faces are culled, which
    halves the rasterisation on software GL and is invisible from outside."""
    actor = _mapped_actor(poly)
    prop = actor.GetProperty()
    prop.SetInterpolationToPhong()
    prop.SetColor(*_rgb(color))
    prop.SetAmbient(0.12)
    prop.SetDiffuse(0.85)
    prop.SetSpecular(0.25)
    prop.SetSpecularPower(25.0)
    prop.BackfaceCullingOn()
    return actor


def _polyline(points: np.ndarray) -> pv.PolyData:
    n = len(points)
    poly = pv.PolyData(np.array(points, dtype=np.float64))
    poly.lines = np.concatenate([[n], np.arange(n)]).astype(np.int64)
    return poly


def _line_actor(poly: pv.PolyData, color: str, width: float, opacity: float = 1.0) -> vtk.vtkActor:
    actor = _mapped_actor(poly)
    prop = actor.GetProperty()
    prop.SetColor(*_rgb(color))
    prop.SetLineWidth(width)
    prop.SetOpacity(opacity)
    prop.SetLighting(False)
    actor.PickableOff()
    return actor


class SweepScene:
    """Shows a Document in a PyVista plotter (a pyvistaqt.QtInteractor in the app, any
    pyvista Plotter otherwise) and turns handle drags into undoable commands."""

    def __init__(self, plotter: Any, document: Document, stack: CommandStack | None = None,
                 deferred_render: bool = True) -> None:
        self.plotter = plotter
        self.doc = document
        self.stack = stack
        # In the app, renders happen in the widget's paint, coalesced by Qt.
        self._deferred = deferred_render
        self._actors: list[_PrimitiveActor] = []
        self._preview: list[SweepPrimitive] | None = None
        self._shape_actor: vtk.vtkActor | None = None
        self._shape_visible = True
        self._shape_opacity = 0.3
        self._right_margin = 0.0  # share of the view's width kept for an overlay
        self._hover: int | None = None
        self._drag: tuple[int, int] | None = None
        self._drag_depth = 0.0
        self._drag_offset = np.zeros(2)
        self._drag_start = np.zeros(3)
        # ("axis" | "plane", 0..2) while X/Y/Z (Shift+X/Y/Z) constrains a drag.
        self._constraint: tuple[str, int] | None = None
        self._drag_delta = np.zeros(3)
        self._handle_points = np.zeros((0, 3))
        self._clipping_range: tuple[float, float] | None = None
        # Where refusals are told (the window's status bar); None: silently.
        self.report: Any = None

        plotter.set_background(BACKGROUND)
        # Plain alpha blending for the translucent target (drawn front faces only): VTK's
        # default order-independent translucency costs ~15 ms a frame on software GL.
        plotter.renderer.SetUseOIT(False)
        ren_win = plotter.render_window
        layer = ren_win.GetNumberOfLayers()
        ren_win.SetNumberOfLayers(layer + 1)
        # Between the main renderer and the overlay: a drag redraws only what it changes.
        self.frame_reuse = FrameReuse(ren_win, plotter.renderer, layer)
        self._init_overlay()
        self._primitive_picker = vtk.vtkCellPicker()
        self._primitive_picker.SetTolerance(0.0005)
        self._primitive_picker.PickFromListOn()

        self._links = Connections()
        self._links.connect(document.primitive_changed, self._on_primitive_changed)
        self._links.connect(document.primitives_reset, self._on_reset)
        self._links.connect(document.selection_changed, self._on_selection_changed)
        self._links.connect(document.shape_changed, self._on_shape_changed)
        self._on_shape_changed()
        self._on_reset()

    def close(self) -> None:
        """Stop showing the Document, which may outlive this view: disconnect from its
        signals and from the render window's frames. Call before the view's window is
        finalized."""
        self._links.disconnect_all()
        ren_win = self.plotter.render_window  # None once the view itself has closed
        if self._render_observer is not None and ren_win is not None:
            ren_win.RemoveObserver(self._render_observer)
            self.frame_reuse.close()
        self._render_observer = None

    # -- overlay --------------------------------------------------------------------------
    def _init_overlay(self) -> None:
        ren_win = self.plotter.render_window
        main = self.plotter.renderer
        layer = ren_win.GetNumberOfLayers()
        ren_win.SetNumberOfLayers(layer + 1)
        overlay = vtk.vtkRenderer()
        overlay.SetLayer(layer)
        overlay.InteractiveOff()
        overlay.SetUseOIT(False)
        overlay.SetViewport(main.GetViewport())
        overlay.SetActiveCamera(main.GetActiveCamera())
        ren_win.AddRenderer(overlay)
        self._overlay = overlay
        # Before every frame: share the (possibly replaced) camera and widen the clipping
        # range to the handles, which may lie outside the meshes the main renderer sees.
        self._render_observer = ren_win.AddObserver("StartEvent", self._before_render)

        self._axis_poly = _polyline(np.zeros((AXIS_SAMPLES, 3)))
        self._axis_actor = _line_actor(self._axis_poly, AXIS_COLOR, 3.0)
        self._polygon_poly = _polyline(np.zeros((3, 3)))
        # Opaque lines only: anything translucent here would add a translucency pass.
        self._polygon_actor = _line_actor(self._polygon_poly, POLYGON_COLOR, 1.5)
        self._handles_poly = pv.PolyData(np.zeros((3, 3)))
        self._handles_poly.point_data.set_array(np.zeros((3, 3), np.uint8), "rgb")
        mapper = vtk.vtkPolyDataMapper()
        mapper.SetInputData(self._handles_poly)
        mapper.SetScalarModeToUsePointFieldData()
        mapper.SelectColorArray("rgb")
        mapper.SetColorModeToDirectScalars()
        mapper.ScalarVisibilityOn()
        self._handles_actor = vtk.vtkActor()
        self._handles_actor.SetMapper(mapper)
        prop = self._handles_actor.GetProperty()
        prop.SetRenderPointsAsSpheres(True)
        prop.SetPointSize(HANDLE_PIXELS)
        prop.SetSpecular(0.4)
        for actor in (self._polygon_actor, self._axis_actor, self._handles_actor):
            actor.VisibilityOff()
            overlay.AddActor(actor)
        # The offset of a drag in progress (and its constraint), bottom left, with the keys
        # above it: a text of its own, rasterised once, as the offset's is on every move.
        self._offset_actor = vtk.vtkTextActor()
        self._keys_actor = vtk.vtkTextActor()
        self._keys_actor.SetInput(DRAG_KEYS)
        for position, actor in ((12, self._offset_actor), (36, self._keys_actor)):
            actor.GetTextProperty().SetFontSize(16)
            actor.GetTextProperty().SetColor(0.1, 0.1, 0.1)
            actor.SetPosition(12, position)
            actor.VisibilityOff()
            overlay.AddViewProp(actor)

    def _before_render(self, *_: Any) -> None:
        main = self.plotter.renderer
        camera = main.GetActiveCamera()
        if self._overlay.GetActiveCamera() is not camera:
            self._overlay.SetActiveCamera(camera)
        if self._handles_actor.GetVisibility() and len(self._handle_points):
            b = np.array(main.ComputeVisiblePropBounds())
            lo, hi = self._handle_points.min(0), self._handle_points.max(0)
            if b[0] > b[1]:  # nothing visible in the main renderer
                b = np.array([lo[0], hi[0], lo[1], hi[1], lo[2], hi[2]])
            b[0::2] = np.minimum(b[0::2], lo - 0.05)
            b[1::2] = np.maximum(b[1::2], hi + 0.05)
            main.ResetCameraClippingRange(*b)
            self._steady_clipping_range(camera)
        self.frame_reuse.begin_frame()

    def _steady_clipping_range(self, camera: vtk.vtkCamera) -> None:
        """Keep the last clipping range while it still holds the camera's new one and is
        not much looser: the frames of a drag then share one depth mapping, which lets
        them reuse the picture of what did not move (FrameReuse). When it must change,
        the new range gets a margin, so that the next moves fit in it too."""
        near, far = camera.GetClippingRange()
        last = self._clipping_range
        if (last is not None and last[0] <= near and far <= last[1]
                and last[0] >= CLIP_SLACK * near and last[1] <= far / CLIP_SLACK):
            camera.SetClippingRange(*last)
            return
        self._clipping_range = (near * CLIP_MARGIN, far / CLIP_MARGIN)
        camera.SetClippingRange(*self._clipping_range)

    # -- rendering ------------------------------------------------------------------------
    def request_render(self) -> None:
        """Render soon. In the app this asks the widget for a repaint, which renders once
        and shows the frame (Qt merges repeated requests); plotter.render() would render
        now and then again in the paint that follows. Otherwise render at once."""
        if not self._deferred:
            self.plotter.render()
        elif not getattr(self.plotter, "_closed", False):
            self.plotter.update()

    def render_now(self) -> None:
        """Render synchronously (screenshots, benchmarks)."""
        if not getattr(self.plotter, "_closed", False):
            self.plotter.render()

    def reset_camera(self) -> None:
        """Fit the view to the shape and the primitives (the unit cube when empty)."""
        self.plotter.view_isometric()
        main = self.plotter.renderer
        b = main.ComputeVisiblePropBounds()
        if b[0] > b[1]:
            b = (-0.5, 0.5, -0.5, 0.5, -0.5, 0.5)
        self._fit(b)

    # -- target shape ---------------------------------------------------------------------
    @property
    def shape_visible(self) -> bool:
        return self._shape_visible

    def set_shape_visible(self, visible: bool) -> None:
        self._shape_visible = bool(visible)
        if self._shape_actor is not None:
            self._shape_actor.SetVisibility(self._shape_visible)
        self.request_render()

    @property
    def shape_opacity(self) -> float:
        return self._shape_opacity

    def set_shape_opacity(self, opacity: float) -> None:
        self._shape_opacity = float(np.clip(opacity, 0.0, 1.0))
        if self._shape_actor is not None:
            self._shape_actor.GetProperty().SetOpacity(self._shape_opacity)
        self.request_render()

    def _on_shape_changed(self) -> None:
        if self._shape_actor is not None:
            self.plotter.renderer.RemoveActor(self._shape_actor)
            self._shape_actor = None
        shape = self.doc.shape
        if shape is None:
            self.request_render()
            return
        poly = shape_polydata(shape)
        if poly is None:
            return
        actor = _surface_actor(poly, SHAPE_COLOR)
        prop = actor.GetProperty()
        prop.SetOpacity(self._shape_opacity)
        prop.SetSpecular(0.1)
        # Translucent without depth peeling (slow on software GL): drawing only the front
        # faces (culling is on) keeps the blend order-independent enough to look clean.
        if poly.n_cells and poly.n_cells == poly.n_verts:  # a point cloud
            prop.SetRepresentationToPoints()
            prop.SetPointSize(3)
            prop.SetRenderPointsAsSpheres(True)
        actor.SetVisibility(self._shape_visible)
        actor.PickableOff()
        self.plotter.renderer.AddActor(actor)
        self._shape_actor = actor
        self.reset_camera()

    # -- primitives -----------------------------------------------------------------------
    @property
    def shown_primitives(self) -> list[SweepPrimitive]:
        """What the view shows: the fit preview while a fit runs, else the document's."""
        return self._preview if self._preview is not None else self.doc.primitives

    def primitive_polydata(self, index: int) -> pv.PolyData:
        """The PolyData of the index-th primitive actor (updated in place on edits)."""
        return self._actors[index].poly

    def primitive_actor(self, index: int) -> vtk.vtkActor:
        return self._actors[index].actor

    @property
    def n_actors(self) -> int:
        return len(self._actors)

    def _write_mesh(self, index: int, mesh: TriangleMesh) -> None:
        poly = self._actors[index].poly
        # In place: the actor, mapper and array objects stay; VTK sees Modified().
        poly.points[:] = mesh.vertices
        poly.point_data["Normals"][:] = mesh.normals

    def _style(self, index: int, prim: SweepPrimitive) -> None:
        actor = self._actors[index].actor
        actor.GetProperty().SetColor(*_rgb(prim.color))
        actor.SetVisibility(bool(prim.visible))
        selected = self._preview is None and index in self.doc.selected_indices
        # A lighter ambient term marks the selection without hiding its colour.
        actor.GetProperty().SetAmbient(0.35 if selected else 0.12)

    def _sync(self, primitives: Sequence[SweepPrimitive]) -> None:
        """Make the actors show `primitives`, reusing existing actors (same topology)."""
        meshes = sweep_meshes(list(primitives), split_caps=True) if primitives else []
        renderer = self.plotter.renderer
        for i, (prim, mesh) in enumerate(zip(primitives, meshes, strict=True)):
            if i < len(self._actors):
                self._write_mesh(i, mesh)
            else:
                poly = _polydata(mesh)
                actor = _surface_actor(poly, prim.color)
                renderer.AddActor(actor)
                self._actors.append(_PrimitiveActor(poly, actor))
            self._style(i, prim)
        for extra in self._actors[len(primitives):]:
            renderer.RemoveActor(extra.actor)
        del self._actors[len(primitives):]
        self._primitive_picker.InitializePickList()
        for a in self._actors:
            self._primitive_picker.AddPickList(a.actor)

    def _on_reset(self) -> None:
        if self._preview is None:
            had_none = not self._actors
            self._sync(self.doc.primitives)
            self._update_overlay()
            if had_none and self._actors and self._shape_actor is None:
                self.reset_camera()
        self.request_render()

    def _on_primitive_changed(self, index: int, kind: str) -> None:
        if self._preview is not None or index >= len(self._actors):
            return
        prim = self.doc.primitive(index)
        if kind == GEOMETRY:
            self._write_mesh(index, sweep_mesh(prim, split_caps=True))
        if kind in (GEOMETRY, DISPLAY):
            self._style(index, prim)
            if index == self.doc.selection:
                self._update_overlay()
            self.request_render()

    def _on_selection_changed(self, _index: int | None) -> None:
        if self._preview is None:
            for i, prim in enumerate(self.doc.primitives[: len(self._actors)]):
                self._style(i, prim)
        self._hover = None
        self._update_overlay()
        self.request_render()

    # -- fit preview ----------------------------------------------------------------------
    def show_preview(self, primitives: Sequence[SweepPrimitive]) -> None:
        """Show primitives that are not (yet) the document's: the fit in progress."""
        self._preview = [p for p in primitives]
        self._sync(self._preview)
        self._update_overlay()
        self.request_render()

    def end_preview(self) -> None:
        """Back to showing the document."""
        self._preview = None
        self._sync(self.doc.primitives)
        self._update_overlay()
        self.request_render()

    @property
    def previewing(self) -> bool:
        return self._preview is not None

    # -- axis and handles -----------------------------------------------------------------
    def _update_overlay(self) -> None:
        sel = self.doc.selection
        prim = self.doc.primitive(sel) if sel is not None and self._preview is None else None
        if prim is None or not prim.visible:
            self._handle_points = np.zeros((0, 3))
            for actor in (self._axis_actor, self._polygon_actor, self._handles_actor):
                actor.VisibilityOff()
            return
        cps = prim.control_points
        axis = axis_points(cps[None], np.linspace(0.0, 1.0, AXIS_SAMPLES))[0]
        self._axis_poly.points[:] = axis
        if self._polygon_poly.n_points == len(cps):
            self._polygon_poly.points[:] = cps
            self._handles_poly.points[:] = cps
        else:
            self._polygon_poly.copy_from(_polyline(cps))
            handles = pv.PolyData(np.array(cps))
            handles.point_data.set_array(np.zeros((len(cps), 3), np.uint8), "rgb")
            self._handles_poly.copy_from(handles)
        colors = np.tile(np.array(HANDLE_LOCKED_COLOR if prim.locked else HANDLE_COLOR,
                                  np.uint8), (len(cps), 1))
        active = self._drag[1] if self._drag is not None else self._hover
        if active is not None and active < len(cps) and not prim.locked:
            colors[active] = HANDLE_HOVER_COLOR
        self._handles_poly.point_data["rgb"][:] = colors
        self._handle_points = cps.copy()
        for actor in (self._axis_actor, self._polygon_actor, self._handles_actor):
            actor.VisibilityOn()

    # -- coordinates ----------------------------------------------------------------------
    def world_to_display(self, points: np.ndarray) -> np.ndarray:
        """(n, 3) world points -> (n, 3) display x, y (device pixels, y up) and depth."""
        ren = self.plotter.renderer
        out = np.empty((len(points), 3))
        for i, p in enumerate(np.asarray(points, dtype=np.float64)):
            ren.SetWorldPoint(p[0], p[1], p[2], 1.0)
            ren.WorldToDisplay()
            out[i] = ren.GetDisplayPoint()
        return out

    def display_to_world(self, x: float, y: float, depth: float) -> np.ndarray:
        """Display x, y (device pixels, y up) at a depth (0..1) -> (3,) world point."""
        ren = self.plotter.renderer
        ren.SetDisplayPoint(float(x), float(y), float(depth))
        ren.DisplayToWorld()
        w = np.array(ren.GetWorldPoint())
        return w[:3] / w[3]

    def pick_handle(self, x: float, y: float) -> tuple[int, int] | None:
        """The (primitive, control point) whose handle is under display point x, y."""
        sel = self.doc.selection
        if sel is None or self._preview is not None or not len(self._handle_points):
            return None
        d = self.world_to_display(self._handle_points)
        dist = np.hypot(d[:, 0] - x, d[:, 1] - y)
        near = np.flatnonzero(dist <= PICK_PIXELS)
        if not len(near):
            return None
        return sel, int(near[np.argmin(d[near, 2])])  # the one closest to the eye

    def pick_primitive(self, x: float, y: float) -> int | None:
        """Index of the visible primitive under display point x, y, if any."""
        if not self._actors or self._preview is not None:
            return None
        if not self._primitive_picker.Pick(float(x), float(y), 0.0, self.plotter.renderer):
            return None
        actor = self._primitive_picker.GetActor()
        for i, a in enumerate(self._actors):
            if a.actor is actor:
                return i
        return None

    # -- editing --------------------------------------------------------------------------
    def drag_control_point(self, prim_index: int, cp_index: int,
                           new_position: Sequence[float]) -> bool:
        """Move a control point (undoable; consecutive moves merge until `end_drag`).

        This is what the mouse path calls on every move; returns False when the move
        was refused (locked primitive, invalid result, no stack)."""
        if self.stack is None or self._preview is not None:
            return False
        prim = self.doc.primitive(prim_index)
        if prim.locked:
            return False
        try:
            self.stack.push(move_control_point(self.doc, prim_index, cp_index, new_position))
        except InvalidPrimitiveError:
            return False
        return True

    @property
    def dragging(self) -> bool:
        return self._drag is not None

    def begin_drag(self, prim_index: int, cp_index: int, x: float, y: float) -> bool:
        """Start dragging a handle grabbed at display point x, y."""
        if self.doc.primitive(prim_index).locked:
            return False
        p = self.doc.primitive(prim_index).control_points[cp_index]
        d = self.world_to_display(p[None])[0]
        self._drag = (prim_index, cp_index)
        self._drag_depth = float(d[2])
        self._drag_offset = d[:2] - np.array([x, y])  # no jump to the cursor
        self._drag_start = p.copy()
        self._constraint = None
        self._drag_delta = np.zeros(3)
        if self.stack is not None:
            self.stack.close_merge()
        self._update_overlay()
        self._show_offset()
        self.request_render()
        return True

    @property
    def constraint(self) -> tuple[str, int] | None:
        """("axis", i) or ("plane", i) (the plane normal to axis i) during a drag, or None."""
        return self._constraint

    def set_constraint(self, kind: str | None, axis: int = 0) -> None:
        """Constrain the drag to an axis or to the plane normal to it; the same key again
        (or kind None) frees it, as in Blender."""
        if kind not in (None, "axis", "plane"):
            raise ValueError(f"constraint kind must be 'axis', 'plane' or None, got {kind!r}")
        new = None if kind is None else (kind, int(axis))
        self._constraint = None if new == self._constraint else new
        self._show_offset()

    def constrained_position(self, x: float, y: float, snap: bool = False) -> np.ndarray:
        """(3,) where the dragged point goes for the cursor at display x, y: in the view
        plane, or on the constraint's line or plane through the drag's start point (the
        point of it nearest to the cursor's ray); snap rounds the offset to GRID_STEP.
        Coordinates a constraint holds keep the start's exact value."""
        start = self._drag_start
        tx, ty = np.array([x, y]) + self._drag_offset
        free = np.ones(3, dtype=bool)
        if self._constraint is None:
            offset = self.display_to_world(tx, ty, self._drag_depth) - start
        else:
            kind, a = self._constraint
            near = self.display_to_world(tx, ty, 0.0)
            ray = self.display_to_world(tx, ty, 1.0) - near
            offset = np.zeros(3)
            if kind == "axis":
                free[:] = False
                free[a] = True
                # Closest point of the line start + s e_a to the ray near + r ray.
                w0 = start - near
                b, c = ray[a], float(ray @ ray)
                denom = c - b * b
                if denom > 1e-12 * c:
                    offset[a] = (b * float(ray @ w0) - c * w0[a]) / denom
            else:
                free[a] = False
                if abs(ray[a]) > 1e-6 * np.linalg.norm(ray):  # the ray meets the plane
                    hit = near + ray * ((start[a] - near[a]) / ray[a])
                else:  # seen edge-on: the view-plane point, projected into it
                    hit = self.display_to_world(tx, ty, self._drag_depth)
                offset = hit - start
        if snap:
            offset = np.round(offset / GRID_STEP) * GRID_STEP
        position = start.copy()
        position[free] = start[free] + offset[free]
        return position

    @property
    def drag_offset(self) -> np.ndarray:
        """(3,) the dragged point's offset from where the drag started."""
        return self._drag_delta.copy()

    @property
    def drag_text(self) -> str:
        """What the view shows during a drag: the offset and the constraint, and the keys."""
        return f"{self._offset_text()}   {DRAG_KEYS}" if self._drag is not None else ""

    def _offset_text(self) -> str:
        dx, dy, dz = self._drag_delta
        text = f"offset  x {dx:+.4f}  y {dy:+.4f}  z {dz:+.4f}"
        if self._constraint is not None:
            kind, a = self._constraint
            text += (f"   along {'XYZ'[a]}" if kind == "axis"
                     else f"   in the {''.join(c for i, c in enumerate('XYZ') if i != a)} plane")
        return text

    def _show_offset(self) -> None:
        dragging = self._drag is not None
        if dragging:
            self._offset_actor.SetInput(self._offset_text())
        self._offset_actor.SetVisibility(dragging)
        self._keys_actor.SetVisibility(dragging)

    def drag_to(self, x: float, y: float, snap: bool = False) -> bool:
        """Move the dragged handle under display point x, y: in the view plane, or along
        the constraint; snap (Ctrl) rounds the offset to GRID_STEP."""
        if self._drag is None:
            return False
        position = self.constrained_position(x, y, snap)
        moved = self.drag_control_point(self._drag[0], self._drag[1], position)
        if moved:
            self._drag_delta = position - self._drag_start
            self._show_offset()
        return moved

    def cancel_drag(self) -> None:
        """Esc: end the drag and put the point back exactly (the drag's undo step is
        reverted and forgotten)."""
        if self._drag is None:
            return
        if self.stack is not None:
            self.stack.revert_open()
        self.end_drag()

    def end_drag(self) -> None:
        self._drag = None
        self._constraint = None
        if self.stack is not None:
            self.stack.close_merge()
        self._show_offset()
        self._update_overlay()
        self.request_render()

    def hover(self, x: float, y: float) -> bool:
        """Highlight the handle under the cursor; True when there is one."""
        hit = self.pick_handle(x, y)
        index = hit[1] if hit is not None else None
        if index != self._hover:
            self._hover = index
            self._update_overlay()
            self.request_render()
        return hit is not None

    def click(self, x: float, y: float, additive: bool = False) -> None:
        """A click without a drag selects the primitive under the cursor (or none); with
        additive (Ctrl or Shift held) it is added to, or taken from, the selection."""
        hit = self.pick_primitive(x, y)
        if not additive:
            self.doc.select(hit)
        elif hit is not None:
            chosen = list(self.doc.selected_indices)
            if hit in chosen:
                chosen.remove(hit)
                self.doc.set_selection(chosen)
            else:
                self.doc.set_selection([*chosen, hit])

    # -- control points -------------------------------------------------------------------
    def axis_hit(self, x: float, y: float) -> float | None:
        """The axis parameter t of the selected primitive's axis point under display x, y
        (within the pick distance), or None."""
        sel = self.doc.selection
        if sel is None or self._preview is not None or not self.doc.primitive(sel).visible:
            return None
        t = np.linspace(0.0, 1.0, AXIS_PICK_SAMPLES)
        d = self.world_to_display(axis_points(self.doc.primitive(sel).control_points[None], t)[0])
        dist = np.hypot(d[:, 0] - x, d[:, 1] - y)
        k = int(np.argmin(dist))
        return float(t[k]) if dist[k] <= PICK_PIXELS else None

    def _push_or_report(self, make: Any) -> bool:
        if self.stack is None or self._preview is not None:
            return False
        try:
            self.stack.push(make())
        except SweepeditError as exc:
            if self.report is not None:
                self.report(str(exc))
            return False
        return True

    def insert_control_point(self, t: float | None = None) -> bool:
        """Insert a control point into the selected primitive's axis at parameter t (None:
        split its longest leg); one undo step."""
        sel = self.doc.selection
        if sel is None:
            return False
        self.stack.close_merge() if self.stack is not None else None
        return self._push_or_report(lambda: insert_control_point(self.doc, sel, t))

    def delete_control_point(self, cp_index: int | None = None) -> bool:
        """Delete a control point of the selected primitive (default: the one under the
        cursor); at least 3 stay."""
        sel = self.doc.selection
        cp_index = self._hover if cp_index is None else cp_index
        if sel is None or cp_index is None:
            if self.report is not None:
                self.report("Point at a control point (its handle) to delete it.")
            return False
        self.stack.close_merge() if self.stack is not None else None
        return self._push_or_report(lambda: delete_control_point(self.doc, sel, cp_index))

    # -- camera ---------------------------------------------------------------------------
    def _bounds(self, indices: Sequence[int] | None = None) -> tuple[float, ...]:
        main = self.plotter.renderer
        if indices:
            boxes = np.array([self._actors[i].actor.GetBounds() for i in indices
                              if i < len(self._actors) and self._actors[i].actor.GetVisibility()])
            if len(boxes):
                return (boxes[:, 0].min(), boxes[:, 1].max(), boxes[:, 2].min(),
                        boxes[:, 3].max(), boxes[:, 4].min(), boxes[:, 5].max())
        b = main.ComputeVisiblePropBounds()
        return tuple(b) if b[0] <= b[1] else (-0.5, 0.5, -0.5, 0.5, -0.5, 0.5)

    def view_preset(self, name: str) -> None:
        """Look at everything from one of VIEW_PRESETS (front, back, left, right, top,
        bottom, isometric), keeping the projection (perspective or orthographic)."""
        if name not in VIEW_PRESETS:
            raise ValueError(f"unknown view {name!r}; one of {', '.join(VIEW_PRESETS)}")
        direction, up = (np.asarray(v, dtype=np.float64) for v in VIEW_PRESETS[name])
        b = self._bounds()
        center = np.array([(b[0] + b[1]) / 2, (b[2] + b[3]) / 2, (b[4] + b[5]) / 2])
        camera = self.plotter.renderer.GetActiveCamera()
        camera.SetFocalPoint(*center)
        camera.SetPosition(*(center + direction / np.linalg.norm(direction)))
        camera.SetViewUp(*up)
        self._fit(b)

    @property
    def orthographic(self) -> bool:
        return bool(self.plotter.renderer.GetActiveCamera().GetParallelProjection())

    def set_orthographic(self, on: bool) -> None:
        """Orthographic or perspective projection, keeping the apparent size at the focal
        point."""
        camera = self.plotter.renderer.GetActiveCamera()
        if on:
            half = np.radians(camera.GetViewAngle()) / 2.0
            camera.SetParallelScale(camera.GetDistance() * np.tan(half))
        camera.SetParallelProjection(bool(on))
        self.plotter.renderer.ResetCameraClippingRange()
        self.request_render()

    def frame_selection(self) -> None:
        """Fit the view to the selected primitives (everything when none is selected)."""
        self._fit(self._bounds(self.doc.selected_indices))

    def _fit(self, bounds: Sequence[float]) -> None:
        """Fit the camera to bounds (6,) in the part of the view left of the margin."""
        self.plotter.renderer.ResetCamera(tuple(bounds))
        if self._right_margin:
            self._shrink_view(1.0 - self._right_margin)
        self.request_render()

    @property
    def right_margin(self) -> float:
        return self._right_margin

    def set_right_margin(self, share: float) -> None:
        """Keep the right `share` of the view's width (0 <= share < 0.5) clear for an
        overlay, such as the heat map's colour bar: the picture shrinks by 1 - share
        towards the view's left edge, so that what was in view stays in view, none of
        it under the overlay, and camera fits use what is left. 0 undoes it exactly."""
        if not 0.0 <= share < 0.5:
            raise ValueError(f"a right margin is a share of the width in [0, 0.5), got {share}")
        if share == self._right_margin:
            return
        self._shrink_view((1.0 - share) / (1.0 - self._right_margin))
        # The projection's centre moves by the share: x -> x - share in the view's
        # [-1, 1] coordinates, which takes the shrunk picture from [share - 1, 1 - share]
        # to [-1, 1 - 2 share]: from the left edge to 1 - share of the width.
        self.plotter.renderer.GetActiveCamera().SetWindowCenter(share, 0.0)
        self._right_margin = share
        self.request_render()

    def _shrink_view(self, factor: float) -> None:
        """Scale the picture about the projection's centre by `factor` (< 1: smaller)."""
        camera = self.plotter.renderer.GetActiveCamera()
        if camera.GetParallelProjection():
            camera.SetParallelScale(camera.GetParallelScale() / factor)
        else:
            camera.Dolly(factor)  # the distance divided by it
        self.plotter.renderer.ResetCameraClippingRange()


def shape_polydata(shape: Any) -> pv.PolyData | None:
    """A displayable PolyData of a Shape: its mesh, else its points, else its voxels."""
    mesh = getattr(shape, "mesh", None)
    if mesh is not None and len(getattr(mesh, "faces", ())):
        poly = pv.PolyData.from_regular_faces(np.asarray(mesh.vertices, dtype=np.float64),
                                              np.asarray(mesh.faces, dtype=np.int64))
        return poly.compute_normals(split_vertices=True, feature_angle=50.0,
                                    auto_orient_normals=False, consistent_normals=False)
    points = getattr(shape, "points", None)
    if points is None and mesh is not None:
        points = getattr(mesh, "vertices", None)
    if points is not None and len(points):
        return pv.PolyData(np.asarray(points, dtype=np.float64))
    occupancy = getattr(shape, "occupancy", None)
    if occupancy is not None and np.any(occupancy):
        occ = np.asarray(occupancy, dtype=bool)
        n = occ.shape[0]
        grid = pv.ImageData(dimensions=np.array(occ.shape) + 1, spacing=(1.0 / n,) * 3,
                            origin=(-0.5, -0.5, -0.5))
        grid.cell_data["occupied"] = occ.ravel(order="F").astype(np.uint8)
        surface = grid.threshold(0.5, scalars="occupied").extract_surface()
        return surface.compute_normals(split_vertices=True)
    return None
