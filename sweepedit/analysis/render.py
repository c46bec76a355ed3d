"""PyVista pictures: a shape with its skeleton, an abstraction over its shape (off screen,
or shown), and a contact sheet of many. Every PNG is written atomically (temporary file, rename)."""

from __future__ import annotations

import io
import math
import os
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from PIL import Image

from sweepedit.analysis.skeleton import Skeleton
from sweepedit.geometry.model import palette_color

if TYPE_CHECKING:
    from sweepedit.geometry.model import Abstraction
    from sweepedit.io.shapes import Shape

SURFACE_COLOR = "#b0b8c8"


def _offscreen_plotter(window_size: Sequence[int], **kwargs: Any) -> Any:
    """An off-screen plotter (its X-server warning silenced)."""
    import pyvista as pv

    _quiet_without_display()
    return pv.Plotter(off_screen=True, window_size=list(window_size), **kwargs)


def _quiet_without_display() -> None:
    """Without an X display VTK falls back on its off-screen context by itself, after
    warning about the missing X server: that warning says nothing to a user."""
    import vtk

    if not os.environ.get("DISPLAY"):
        vtk.vtkLogger.SetStderrVerbosity(vtk.vtkLogger.VERBOSITY_ERROR)


def render_shape(shape: Shape, skeleton: Skeleton | None, path_png: str | Path,
                 window_size: tuple[int, int] = (800, 600), *,
                 camera_position: str | None = None, title: str | None = None) -> Path:
    """Render `shape` (semi-transparent surface; points for point clouds) and `skeleton`
    (one coloured tube per branch, white spheres at junctions, small dark ones at tips)
    off screen to a PNG.

    camera_position: a PyVista camera position name ("iso", "xy", "xz", ...); by default
        the view looks along the shape's thinnest extent, tilted a little, so the largest
        silhouette faces the camera.
    title: a caption in the corner (default: the shape's name and branch count).
    Returns the path of the PNG.
    """

    plotter = _offscreen_plotter(window_size)
    try:
        plotter.set_background("white")
        _add_shape(plotter, shape, opacity=0.3)
        if skeleton is not None:
            _add_skeleton(plotter, skeleton, 1.0 / shape.resolution)
        caption = title
        if caption is None:
            caption = shape.name
            if skeleton is not None:
                caption += (f"  {len(skeleton.branches)} branches, "
                            f"{len(skeleton.junctions)} junctions, {skeleton.n_loops} loops")
        _finish_view(plotter, shape, caption, camera_position)
        return _screenshot(plotter, path_png)
    finally:
        plotter.close()


def render_abstraction(abstraction: Abstraction, shape: Shape | None, path_png: str | Path,
                       window_size: tuple[int, int] = (800, 600), *,
                       camera_position: str | None = None, title: str | None = None) -> Path:
    """Render the visible primitives (opaque, each in its own colour) over the shape's
    surface (faint) off screen to a PNG; `shape` may be None. Returns the path."""

    plotter = _offscreen_plotter(window_size)
    try:
        _draw_abstraction(plotter, abstraction, shape)
        caption = title
        if caption is None:
            caption = f"{shape.name}  " if shape is not None else ""
            caption += f"{len(abstraction.visible())} primitives"
        _finish_view(plotter, shape, caption, camera_position)
        return _screenshot(plotter, path_png)
    finally:
        plotter.close()


def show_abstraction(abstraction: Abstraction, shape: Shape | None,
                     window_size: tuple[int, int] = (800, 600)) -> None:
    """The picture of render_abstraction in a PyVista window (or, in Jupyter, PyVista's
    notebook backend), for a user to turn around."""
    import pyvista as pv

    _quiet_without_display()  # a notebook's static picture is rendered off screen
    plotter = pv.Plotter(window_size=list(window_size))
    _draw_abstraction(plotter, abstraction, shape)
    _finish_view(plotter, shape, f"{len(abstraction.visible())} primitives", None)
    plotter.show()


def render_contact_sheet(items: Sequence[tuple[str, Shape | None, Abstraction]],
                         path_png: str | Path, tile_size: tuple[int, int] = (320, 240),
                         columns: int | None = None) -> Path:
    """One tile per (name, shape, abstraction): the abstraction over its shape, captioned
    with the name, in a grid (about square unless `columns` is given). Returns the path."""
    n = max(1, len(items))
    cols = columns or math.ceil(math.sqrt(n))
    rows = math.ceil(n / cols)
    plotter = _offscreen_plotter([cols * tile_size[0], rows * tile_size[1]],
                                 shape=(rows, cols), border=False)
    try:
        for i, (name, shape, abstraction) in enumerate(items):
            plotter.subplot(i // cols, i % cols)
            plotter.set_background("white")
            if shape is not None:
                _add_shape(plotter, shape, opacity=0.15)
            _add_primitives(plotter, abstraction)
            _finish_view(plotter, shape, f"{name} ({len(abstraction.visible())})", None,
                         font_size=8, frame=False)
        for i in range(len(items), rows * cols):
            plotter.subplot(i // cols, i % cols)
            plotter.set_background("white")
        return _screenshot(plotter, path_png)
    finally:
        plotter.close()


# --------------------------------------------------------------------------- helpers


def _draw_abstraction(plotter: Any, abstraction: Abstraction, shape: Shape | None) -> None:
    """The visible primitives over the shape's faint surface, on white."""
    plotter.set_background("white")
    if shape is not None:
        _add_shape(plotter, shape, opacity=0.15)
    _add_primitives(plotter, abstraction)


def _add_shape(plotter: Any, shape: Shape, opacity: float) -> None:
    import pyvista as pv

    surface = shape.surface
    if surface is not None and len(surface.faces):
        poly = pv.PolyData.from_regular_faces(np.asarray(surface.vertices),
                                              np.asarray(surface.faces, dtype=np.int64))
        plotter.add_mesh(poly, color=SURFACE_COLOR, opacity=opacity, smooth_shading=True)
    if shape.cloud is not None:
        cloud = shape.cloud
        if cloud.shape[0] > 50_000:  # enough to see the shape, cheap to draw
            cloud = cloud[np.random.default_rng(0).choice(cloud.shape[0], 50_000, False)]
        plotter.add_points(cloud, color="#555555", point_size=2.0)


def _add_skeleton(plotter: Any, skeleton: Skeleton, h: float) -> None:
    import pyvista as pv

    for i, branch in enumerate(skeleton.branches):
        line = pv.lines_from_points(branch.points)
        # Thin tubes: the skeleton should not hide the shape around it.
        radius = float(np.clip(0.35 * np.median(branch.radii), 0.3 * h, 1.5 * h))
        plotter.add_mesh(line.tube(radius=radius, n_sides=12), color=palette_color(i))
    for pos in skeleton.junctions:
        plotter.add_mesh(pv.Sphere(radius=1.6 * h, center=pos), color="white")
    for pos in skeleton.tips:
        plotter.add_mesh(pv.Sphere(radius=1.2 * h, center=pos), color="#222222")


def _add_primitives(plotter: Any, abstraction: Abstraction) -> None:
    import pyvista as pv

    from sweepedit.geometry.mesher import sweep_meshes

    visible = abstraction.visible()
    for primitive, mesh in zip(visible, sweep_meshes(visible), strict=True):
        poly = pv.PolyData.from_regular_faces(mesh.vertices, mesh.faces)
        poly.point_data["Normals"] = mesh.normals
        plotter.add_mesh(poly, color=primitive.color, smooth_shading=True)


def _finish_view(plotter: Any, shape: Shape | None, caption: str,
                 camera_position: str | None, font_size: int = 10, frame: bool = True) -> None:
    import pyvista as pv

    if caption:
        plotter.add_text(caption, font_size=font_size, color="black")
    if frame:
        plotter.add_mesh(pv.Box(bounds=(-0.5, 0.5, -0.5, 0.5, -0.5, 0.5)).extract_all_edges(),
                         color="#cccccc", line_width=1)
    if camera_position:
        plotter.camera_position = camera_position
    else:
        _auto_camera(plotter, shape)
    plotter.reset_camera()


def _auto_camera(plotter: Any, shape: Shape | None) -> None:
    """Look along the axis of the smallest bounding-box extent, tilted by ~17 degrees."""
    thin = 0
    if shape is not None:
        points = shape.cloud if shape.cloud is not None else np.asarray(shape.surface.vertices)
        thin = int(np.argmin(np.ptp(points, axis=0)))
    direction = np.full(3, 0.3)
    direction[thin] = 1.0
    up = np.zeros(3)
    up[2 if thin != 2 else 1] = 1.0
    plotter.camera_position = [tuple(2.5 * direction), (0.0, 0.0, 0.0), tuple(up)]


def _screenshot(plotter: Any, path_png: str | Path) -> Path:
    """Save the plotter's image atomically (the shared temporary-file-and-rename writer)."""
    from sweepedit.io.params import atomic_write_bytes

    path_png = Path(path_png)
    path_png.parent.mkdir(parents=True, exist_ok=True)
    image = plotter.screenshot(None, return_img=True)  # (H, W, 3) uint8
    buffer = io.BytesIO()
    Image.fromarray(image).save(buffer, format="PNG")
    atomic_write_bytes(path_png, buffer.getvalue())
    return path_png
