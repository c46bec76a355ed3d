"""sweepedit's front door: the functions a user calls, from code, the command line and
the app alike (`import sweepedit` re-exports them, loading this module on first use).

    >>> import sweepedit
    >>> shape = sweepedit.load_shape("cow.obj")          # a path, trimesh, PyVista, array
    >>> abstraction = sweepedit.fit(shape, primitives=8)  # a progress bar; Ctrl-C keeps
    >>> sweepedit.evaluate(abstraction, shape).iou        # the best so far
    >>> abstraction.save("cow.json"); abstraction.export("cow.glb")

Everything here is a thin layer over the packages that do the work (io, analysis,
fitting; docs/architecture.md): it takes the inputs people have at hand, picks the
right reader or writer, and draws progress. Heavy modules (torch, trimesh, PyVista,
OpenCascade) load when a function first needs them.
"""

from __future__ import annotations

import sys
import threading
from collections.abc import Callable
from dataclasses import dataclass, fields
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

import numpy as np

from sweepedit.errors import SweepeditError
from sweepedit.geometry import model

if TYPE_CHECKING:
    import pyvista
    import trimesh

    from sweepedit.fitting.fit import FitProgress, FitSettings
    from sweepedit.io.shapes import Shape

PathLike = str | Path
# What load_shape accepts besides a path: a trimesh.Trimesh (or Scene, or PointCloud), a
# PyVista dataset, an (N, 3) array of points, a 3D voxel array, or a Shape already loaded.
ShapeSource = Any
Progress = bool | Callable[["FitProgress"], None] | None

# Surface samples of the quality protocol (docs/quality.md).
PROTOCOL_SAMPLES = 100_000


# --------------------------------------------------------------------------- shapes


def load_shape(source: ShapeSource, *, resolution: int = 64, n_samples: int = 32_768,
               seed: int = 0) -> Shape:
    """Load and normalise a shape to abstract.

    Parameters
    ----------
    source : path, trimesh.Trimesh, pyvista.DataSet, ndarray or Shape
        A shape file (mesh, voxel grid or point cloud; docs/user-guide.md lists the
        formats); a ``trimesh.Trimesh`` (a ``Scene`` is flattened, a ``PointCloud`` is
        points); a PyVista dataset (its surface, triangulated; points when it has no
        cells); an ``(N, 3)`` float array of points; an ``(X, Y, Z)`` boolean (or 0/1)
        voxel array indexed ``[ix, iy, iz]``; or a ``Shape``, returned as it is.
    resolution : int
        R of the R^3 occupancy grids the fit and the metrics use.
    n_samples : int
        Occupancy-labelled points the fit draws from.
    seed : int
        Seed of every random sample taken while loading.

    Returns
    -------
    Shape
        The shape in the normalised frame (its bounding box centred at the origin, its
        longest side 1); ``shape.normalization`` maps back to the original frame.

    Raises
    ------
    FileFormatError
        The file or data cannot be used; the message names it and the problem.
    """
    from sweepedit.io import shapes

    options = {"resolution": resolution, "n_samples": n_samples, "seed": seed}
    if isinstance(source, shapes.Shape):
        return source
    if isinstance(source, str | Path):
        return shapes.load_shape(source, **options)
    if _is_instance(source, "trimesh", "Scene"):
        source = source.to_geometry()  # one mesh with the scene's transforms applied
    if _is_instance(source, "trimesh", "Trimesh"):
        name = str(source.metadata.get("name") or source.metadata.get("file_name") or "mesh")
        if len(source.faces) == 0:
            return shapes.points_shape(source.vertices, name=name, **options)
        return shapes.mesh_shape(source.vertices, source.faces, name=name, **options)
    if _is_instance(source, "trimesh", "PointCloud"):
        return shapes.points_shape(source.vertices, name="points", **options)
    if _is_instance(source, "pyvista", "DataSet"):
        surface = source.extract_surface(algorithm=None).triangulate()
        if surface.n_cells == 0 or not surface.is_all_triangles:
            return shapes.points_shape(np.asarray(source.points), name="points", **options)
        return shapes.mesh_shape(surface.points, surface.regular_faces, name="mesh", **options)
    if isinstance(source, np.ndarray | list | tuple):
        array = np.asarray(source)
        if array.ndim == 3:
            return shapes.voxels_shape(array, name="voxels", **options)
        if array.ndim == 2 and array.shape[1] == 3:
            return shapes.points_shape(array, name="points", **options)
        raise SweepeditError(f"cannot load an array of shape {array.shape} as a shape: give "
                             "(N, 3) points or an (X, Y, Z) voxel array")
    raise SweepeditError(f"cannot load a {type(source).__name__} as a shape: give a path, a "
                         "trimesh.Trimesh, a PyVista dataset, (N, 3) points or a voxel array")


def example(name: str = "cactus") -> Path:
    """The path of a shape bundled with sweepedit (the benchmark set,
    sweepedit/resources/benchmark, with its licences), by name: "cactus", "spot",
    "knot1", ...; for trying things out without a file of one's own."""
    from sweepedit.io.benchmark_set import BENCHMARK_DIR, benchmark_shapes

    shapes = {Path(s.path).stem: Path(s.path) for s in benchmark_shapes(BENCHMARK_DIR)}
    if name not in shapes:
        raise SweepeditError(f"no bundled shape named {name!r}; there are "
                             f"{', '.join(sorted(shapes))}")
    return shapes[name]


def _is_instance(value: object, module: str, name: str) -> bool:
    """isinstance(value, module.name), without importing `module`: a value of its types
    exists only once the user has imported it."""
    loaded = sys.modules.get(module)
    kind = getattr(loaded, name, None) if loaded is not None else None
    return kind is not None and isinstance(value, kind)


# --------------------------------------------------------------------------- abstractions


class Abstraction(model.Abstraction):
    """Sweep primitives abstracting one shape, in its normalised frame.

    The same plain data as ``sweepedit.geometry.model.Abstraction`` (``primitives``, a
    list of ``SweepPrimitive``; ``normalization``; the ``fit`` record), with methods to
    save, convert, export and look at it. Edit ``primitives`` in place (control points
    ``(n, 3)``, ``a``, ``b``, ``degree``, ``scaling``); ``validate()`` checks the ranges.
    """

    @classmethod
    def of(cls, abstraction: model.Abstraction) -> Abstraction:
        """The same abstraction (sharing its primitives) as this class."""
        if isinstance(abstraction, cls):
            return abstraction
        return cls(**{f.name: getattr(abstraction, f.name) for f in fields(abstraction)})

    def __repr__(self) -> str:
        record = self.fit or {}
        done = f", fitted in {record['seconds']:.1f} s" if "seconds" in record else ""
        return f"<sweepedit.Abstraction: {len(self.primitives)} primitives{done}>"

    def save(self, path: PathLike) -> Path:
        """Write the parameters atomically: JSON (.json, everything) or the official
        SweepNet text (.txt, 14 numbers per primitive). Returns the path."""
        from sweepedit.io.params import write_abstraction

        write_abstraction(self, path)
        return Path(path)

    def to_trimesh(self, *, per_primitive: bool = False,
                   original_frame: bool = False) -> trimesh.Trimesh | trimesh.Scene:
        """The union of the primitives as one watertight ``trimesh.Trimesh`` of the solid;
        with ``per_primitive`` a ``trimesh.Scene`` of one mesh per primitive, named and
        coloured as in the app. Normalised frame unless ``original_frame``."""
        import trimesh

        from sweepedit.io.mesh_export import trimesh_of

        meshes = self._solid_meshes(per_primitive, original_frame)
        if not per_primitive:
            return trimesh_of(meshes[0][1])
        scene = trimesh.Scene()
        for p, mesh in meshes:
            scene.add_geometry(trimesh_of(mesh, p.color), geom_name=p.name, node_name=p.name)
        return scene

    def to_pyvista(self, *, per_primitive: bool = False,
                   original_frame: bool = False) -> pyvista.PolyData | pyvista.MultiBlock:
        """The union as a ``pyvista.PolyData`` of the solid; with ``per_primitive`` a
        ``pyvista.MultiBlock`` with one block per primitive, keyed by its name (its
        colour in the block's ``field_data["color"]``)."""
        import pyvista as pv

        meshes = self._solid_meshes(per_primitive, original_frame)
        if not per_primitive:
            return pv.PolyData.from_regular_faces(meshes[0][1].vertices, meshes[0][1].faces)
        blocks = pv.MultiBlock()
        for p, mesh in meshes:
            poly = pv.PolyData.from_regular_faces(mesh.vertices, mesh.faces)
            poly.field_data["color"] = [p.color]
            blocks[p.name] = poly
        return blocks

    def _solid_meshes(self, per_primitive: bool, original_frame: bool
                      ) -> list[tuple[model.SweepPrimitive | None, Any]]:
        """(primitive, its solid's TriangleMesh) each, or [(None, the union's)], in the
        frame asked for; an error when there are no primitives."""
        from sweepedit.geometry.solid import solid_mesh, solid_union
        from sweepedit.io.mesh_export import in_frame

        if not self.primitives:
            raise SweepeditError("the abstraction has no primitives")
        pairs = ([(p, solid_mesh(p)) for p in self.primitives] if per_primitive
                 else [(None, solid_union(self.primitives))])
        return [(p, in_frame(mesh, self.normalization, original_frame)) for p, mesh in pairs]

    def export(self, path: PathLike, **options: Any) -> list[Path]:
        """Write the abstraction in the format `path` names; see ``sweepedit.export``."""
        return export(self, path, **options)

    def plot(self, shape: ShapeSource | None = None, *, screenshot: PathLike | None = None,
             window_size: tuple[int, int] = (800, 600)) -> Path | None:
        """Show the primitives (each in its colour) over the shape (faint), with PyVista.

        With ``screenshot`` (or without a display) the picture is rendered off screen to
        that PNG and its path returned; in Jupyter, PyVista's notebook backend draws it
        (a static picture, or interactive where its trame backend is installed).
        """
        from sweepedit.analysis import render

        target = None if shape is None else load_shape(shape)
        if screenshot is not None or not _has_display():
            out = screenshot if screenshot is not None else "sweepedit-plot.png"
            return render.render_abstraction(self, target, out, window_size)
        render.show_abstraction(self, target, window_size)
        return None


def _has_display() -> bool:
    import os

    return sys.platform in ("win32", "darwin") or bool(
        os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")) or _in_notebook()


def _in_notebook() -> bool:
    shell = sys.modules.get("IPython")
    ipython = getattr(shell, "get_ipython", lambda: None)() if shell else None
    return ipython is not None and type(ipython).__name__ == "ZMQInteractiveShell"


def load(path: PathLike) -> Abstraction:
    """Read a parameter file: sweepedit JSON, the official SweepNet text (.txt), or a
    .blend that sweepedit wrote (its curves as edited in Blender; docs/blender.md).

    Raises FileFormatError naming the file, the primitive and the field of a bad value.
    """
    if Path(path).suffix.lower() == ".blend":
        from sweepedit.io.blend_export import read_blend

        return Abstraction.of(read_blend(path))
    from sweepedit.io.params import read_abstraction

    return Abstraction.of(read_abstraction(path))


def _abstraction(value: model.Abstraction | PathLike) -> Abstraction:
    return Abstraction.of(value) if isinstance(value, model.Abstraction) else load(value)


# --------------------------------------------------------------------------- fitting


def fit_settings(primitives: int | Literal["auto"] = 8, **settings: Any) -> FitSettings:
    """The fit's settings: ``primitives`` is K, or "auto" to let the shape decide (at most
    ``max_primitives``, 16 by default, within ``tolerance``); any field of
    ``sweepedit.fitting.fit.FitSettings`` by name (``restarts``, ``method``,
    ``control_points``, ...; ``auto=True`` with a count is "auto" with that most).
    Checked: a bad value is a SweepeditError naming it."""
    from sweepedit.fitting.fit import FitSettings

    known = {f.name for f in fields(FitSettings)}
    unknown = sorted(set(settings) - known - {"max_primitives"})
    if unknown:
        raise TypeError(f"unknown fit setting(s) {', '.join(unknown)}; known: "
                        f"max_primitives, {', '.join(sorted(known - {'primitives'}))}")
    most = settings.pop("max_primitives", None)
    if settings.pop("auto", False) and primitives != "auto":  # FitSettings' own spelling
        primitives, most = "auto", primitives
    if primitives == "auto":
        settings["primitives"] = 16 if most is None else most
        settings["auto"] = True
    elif isinstance(primitives, str):
        raise SweepeditError(f"primitives must be a count or 'auto', not {primitives!r}")
    else:
        settings["primitives"] = primitives
    result = FitSettings(**settings)
    result.validate()
    return result


def fit(shape: ShapeSource, primitives: int | Literal["auto"] = 8, *,
        time_limit: float | None = None, seed: int = 0, progress: Progress = True,
        device: str = "auto", cancel: threading.Event | None = None,
        **settings: Any) -> Abstraction:
    """Abstract a shape into sweep primitives.

    Parameters
    ----------
    shape : path, Shape, trimesh.Trimesh, pyvista.DataSet or ndarray
        Anything ``load_shape`` takes.
    primitives : int or "auto"
        How many primitives (K), or "auto" (see ``fit_settings``).
    time_limit : float, optional
        Seconds for the fit; the best abstraction found by then is returned.
    seed : int
        The same shape, settings and seed give the same parameters.
    progress : bool or callable
        True: a progress bar (tqdm; a widget in Jupyter) naming the stage and the time
        left. A callable gets every ``FitProgress`` instead (its ``abstraction`` is the
        live preview). False: quiet.
    device : str
        "auto" (CUDA when there is one), "cpu" or "cuda".
    cancel : threading.Event, optional
        Set it (from another thread) to stop; the best so far is returned.
    **settings
        Any other setting of ``fit_settings``.

    Returns
    -------
    Abstraction
        The primitives; ``abstraction.fit`` records the settings, the seconds, whether
        it was cancelled or timed out, and why an automatic count stopped.

    Ctrl-C (KeyboardInterrupt, also Jupyter's interrupt) stops the fit and returns the
    best abstraction so far, as the command line does.
    """
    from sweepedit.fitting.fit import fit_abstraction

    chosen = fit_settings(primitives, time_limit=time_limit, seed=seed, device=device,
                          **settings)
    loaded = load_shape(shape)
    cancel = cancel or threading.Event()
    bar = FitBar() if progress is True else None
    callback = bar.update if bar is not None else (progress or None)
    try:
        result = run_cancellable(
            lambda: fit_abstraction(loaded, chosen, callback=callback, cancel=cancel), cancel)
    finally:
        if bar is not None:
            bar.close()
    return Abstraction.of(result.abstraction)


class FitBar:
    """A progress bar of a fit (tqdm: a text bar in a terminal, a widget in Jupyter): the
    stage, its share, the primitives and the time left. Call update(FitProgress)."""

    def __init__(self, disable: bool = False) -> None:
        self._bar = ProgressBar("fitting", disable=disable)

    def update(self, p: FitProgress) -> None:
        desc, postfix = fit_progress_text(p)
        self._bar.update(p.iteration / max(p.total, 1), postfix, desc)

    def close(self) -> None:
        self._bar.close(finished=True)


class ProgressBar:
    """A 0-100 % tqdm bar made at its first update (so that an error raised before the
    work starts is printed alone); tqdm.auto picks Jupyter's widget in a notebook."""

    def __init__(self, desc: str, *, disable: bool = False) -> None:
        self._desc, self._disable, self._bar = desc, disable, None

    def update(self, fraction: float, text: str = "", desc: str | None = None) -> None:
        if self._bar is None:
            from tqdm.auto import tqdm

            self._bar = tqdm(total=100, desc=self._desc, dynamic_ncols=True,
                             disable=self._disable,
                             bar_format="{desc}: {percentage:3.0f}%|{bar}| {postfix}")
        self._bar.n = round(100 * min(max(fraction, 0.0), 1.0))
        if desc is not None:
            self._bar.set_description_str(desc, refresh=False)
        self._bar.set_postfix_str(text, refresh=False)
        self._bar.refresh()

    def close(self, finished: bool = False) -> None:
        if self._bar is not None:
            if finished:
                self._bar.n = 100
            self._bar.close()


def fit_progress_text(p: FitProgress) -> tuple[str, str]:
    """(description, postfix) of a progress bar for a FitProgress: the stage, its own
    share, the primitives and the time left."""
    left = "" if p.seconds_left is None else f", ~{p.seconds_left:.0f} s left"
    restart = f" (restart {p.restart + 1})" if p.restart else ""
    return (f"{p.stage}{restart}",
            f"{p.stage_fraction:.0%} of stage, {len(p.abstraction.primitives)} primitives{left}")


def run_cancellable(work: Callable[[], Any], cancel: threading.Event,
                    notice: str = "cancelling, keeping the best result so far...") -> Any:
    """work() with Ctrl-C as a request to stop: on the main thread the work runs in a
    worker thread, and a KeyboardInterrupt sets `cancel` (after printing `notice`), so
    the work returns its best so far (or raises). Elsewhere work() runs directly."""
    if threading.current_thread() is not threading.main_thread():
        return work()
    box: dict[str, Any] = {}
    done = threading.Event()

    def target() -> None:
        try:
            box["value"] = work()
        except BaseException as exc:  # re-raised in the calling thread
            box["error"] = exc
        finally:
            done.set()

    thread = threading.Thread(target=target, daemon=True)
    thread.start()
    # Waiting on our own event, not on join(): a KeyboardInterrupt that lands inside
    # Thread.join can leave is_alive() False while the work still runs (CPython 3.11),
    # and the process then ended mid-fit with no file and an abort.
    while True:
        try:
            if done.wait(0.2):
                break
        except KeyboardInterrupt:
            print(f"\nsweepedit: {notice}", file=sys.stderr)
            cancel.set()
    thread.join()
    if "error" in box:
        raise box["error"]
    return box["value"]


# --------------------------------------------------------------------------- quality


@dataclass(frozen=True)
class Metrics:
    """The quality protocol (docs/quality.md) of an abstraction against its shape.

    iou: volumetric IoU on the 64^3 grid; cd_l1, cd_l2: Chamfer distances between
    surface samples (normalised frame); f1_0_05, f1_0_01: F1 of the surface samples at
    the thresholds 0.05 and 0.01; primitives: how many.
    """

    iou: float
    cd_l1: float
    cd_l2: float
    f1_0_05: float
    f1_0_01: float
    primitives: int

    def to_dict(self) -> dict[str, float]:
        """The keys of `sweepedit eval --json` and of parameter files' fit records."""
        return {"iou": self.iou, "cd_l1": self.cd_l1, "cd_l2": self.cd_l2,
                "f1_0.05": self.f1_0_05, "f1_0.01": self.f1_0_01,
                "n_primitives": self.primitives}

    def __str__(self) -> str:
        return (f"IoU {self.iou:.3f}, CD-L1 {self.cd_l1:.4f}, F1@0.05 {self.f1_0_05:.3f}, "
                f"F1@0.01 {self.f1_0_01:.3f} ({self.primitives} primitives)")


def evaluate(abstraction: model.Abstraction | PathLike, shape: ShapeSource, *,
             n_samples: int = PROTOCOL_SAMPLES, seed: int = 0) -> Metrics:
    """The quality protocol of an abstraction (or a parameter file) against a shape
    (anything ``load_shape`` takes), in the shape's normalised frame. Hidden primitives
    count: the metric is of the abstraction, not of a view."""
    from sweepedit.analysis.metrics import evaluate as protocol

    values = protocol(_abstraction(abstraction), load_shape(shape), n_samples=n_samples,
                      seed=seed)
    return Metrics(values["iou"], values["cd_l1"], values["cd_l2"], values["f1_0.05"],
                   values["f1_0.01"], int(values["n_primitives"]))


def inside(abstraction: model.Abstraction | PathLike, points: np.ndarray, *,
           original_frame: bool = False) -> np.ndarray:
    """(N,) bool: which of the (N, 3) points lie inside the union of the primitives (the
    exact inside test). Points are in the normalised frame, or in the shape's own
    coordinates with ``original_frame``."""
    from sweepedit.geometry.arrays import as_array
    from sweepedit.geometry.inside import inside_union

    chosen = _abstraction(abstraction)
    points = as_array(points, "N, 3", "points")
    if original_frame:
        points = chosen.normalization.to_normalized(points)
    return inside_union(points, chosen.primitives)


# --------------------------------------------------------------------------- export


def export(abstraction: model.Abstraction | PathLike, path: PathLike, *,
           per_primitive: bool = False, original_frame: bool = False, union: bool = False,
           progress: bool = False, cancel: threading.Event | None = None,
           **options: Any) -> list[Path]:
    """Write an abstraction in the format the path's extension names; returns the paths
    written.

    - .json / .txt: the parameters (``Abstraction.save``).
    - .obj .ply .stl .glb: the union as one watertight mesh of the solid, or with
      ``per_primitive`` one file per primitive (STEM_NN.EXT); ``stations`` and
      ``profile_points`` set the least resolution.
    - .step / .stp: one smooth B-rep solid per visible primitive, or with ``union`` one
      fused solid (the ``cad`` extra); ``progress`` draws a bar; Ctrl-C or ``cancel``
      stops it and nothing is written.
    - .blend: one native Blender curve object per primitive (Blender's ``bpy``; see
      docs/blender.md); ``target_mesh`` (a Shape, or (V, 3) vertices and (F, 3) faces in
      the normalised frame) is added beside them.

    ``original_frame`` writes the shape's own coordinates instead of the normalised frame.
    """
    from sweepedit.io.step import is_step_path

    chosen = _abstraction(abstraction)
    suffix = Path(path).suffix.lower()
    if union and not is_step_path(path):
        raise SweepeditError("--union is for STEP files; a mesh export is the union already")
    if suffix in (".json", ".txt"):
        # original_frame is moot: a JSON file carries the normalisation beside the
        # primitives (the official .txt has no frame at all).
        _no_options(path, options, per_primitive)
        return [chosen.save(path)]
    if is_step_path(path):
        if per_primitive:
            raise SweepeditError("a STEP file holds one solid per primitive already; "
                                 "drop --per-primitive (or use --union for one fused solid)")
        _no_options(path, options)
        return [_export_step(chosen, path, union, original_frame, progress, cancel)]
    if suffix == ".blend":
        if per_primitive:
            raise SweepeditError("a .blend file holds one curve object per primitive "
                                 "already; drop --per-primitive")
        return [_export_blend(chosen, path, original_frame, options)]
    from sweepedit.io.mesh_export import export_abstraction

    return export_abstraction(chosen, path, per_primitive=per_primitive,
                              original_frame=original_frame, **options)


def _no_options(path: PathLike, options: dict[str, Any], *flags: bool) -> None:
    if options or any(flags):
        names = sorted(options) or ["per_primitive / original_frame"]
        raise SweepeditError(f"{path}: {', '.join(names)} do not apply to this format")


def _export_step(abstraction: Abstraction, path: PathLike, union: bool, original_frame: bool,
                 progress: bool, cancel: threading.Event | None) -> Path:
    from sweepedit.io.step import export_step

    cancel = cancel or threading.Event()
    bar = ProgressBar("STEP", disable=not progress)
    try:
        report = run_cancellable(lambda: export_step(
            abstraction, path, union=union, original_frame=original_frame,
            progress=bar.update, cancelled=cancel.is_set), cancel,
            "cancelling after the current step; nothing will be written...")
    finally:
        bar.close()
    return Path(report.path)


def _export_blend(abstraction: Abstraction, path: PathLike, original_frame: bool,
                  options: dict[str, Any]) -> Path:
    from sweepedit.io.blend_export import export_blend

    target = options.pop("target_mesh", None)
    if target is not None and _is_instance(target, "sweepedit.io.shapes", "Shape"):
        target = (np.asarray(target.surface.vertices), np.asarray(target.surface.faces))
    report = export_blend(abstraction, path, original_frame=original_frame,
                          target_mesh=target, **options)
    for line in report.lines():  # never silently: what Blender cannot draw exactly
        print(f"sweepedit: {line}", file=sys.stderr)
    return Path(report.path)


__all__ = ["Abstraction", "Metrics", "evaluate", "example", "export", "fit", "fit_settings",
           "inside", "load", "load_shape"]
