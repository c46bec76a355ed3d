"""Blender .blend files: the primitives as native, editable curve objects (docs/blender.md).

Blender's Python module (bpy) pins numpy < 2 and sweepedit needs numpy >= 2, so the
Blender side runs in a subprocess: a Python that has bpy (`scripts/setup.sh` makes one in
.venv-blender) or a Blender executable, running the add-on that ships in
`sweepedit/resources/blender/sweepedit_blender` (no sweepedit imports there). One
subprocess per call.

    export_blend(abstraction, "shape.blend") -> BlendReport (which primitives Blender
        draws approximately, by how much, which fold)
    read_blend("shape.blend") -> Abstraction (exact where nothing was edited)
"""

from __future__ import annotations

import contextlib
import importlib.util
import json
import os
import secrets
import shutil
import subprocess
import sys
import tempfile
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from sweepedit.errors import FileFormatError, SweepeditError
from sweepedit.geometry.mesher import TriangleMesh
from sweepedit.geometry.model import Abstraction, folds_onto_itself
from sweepedit.io.params import (
    abstraction_from_json,
    abstraction_to_json,
    atomic_write_bytes,
    require_folder,
)

__all__ = ["BlendReport", "BlenderRunner", "PrimitiveNote", "blend_meshes", "export_blend",
           "find_blender", "read_blend", "render_blend"]

PathLike = str | os.PathLike[str]

ADDON_DIR = Path(__file__).resolve().parent.parent / "resources" / "blender"
ENV_VAR = "SWEEPEDIT_BLENDER"
REPORT_MARKER = "SWEEPEDIT_REPORT "
# A .blend of 30 primitives builds in about a second; a cold Blender start takes a few.
TIMEOUT_S = 600
HOW_TO_GET = ("writing .blend needs Blender's bpy: run `bash scripts/setup.sh` (installs it "
              "into .venv-blender), or install Blender 4.2+ and put `blender` on PATH, or "
              f"set {ENV_VAR} to a Blender executable or to a Python that has bpy")
# The headless entry, the same for a Python with bpy (`python -c BOOT ARGS`) and for
# Blender (`blender -b ... --python-expr BOOT -- ARGS`).
_BOOT = ("import sys; sys.path.insert(0, {dir!r}); from sweepedit_blender.cli import main; "
         "sys.exit(main())")


@dataclass(frozen=True)
class BlenderRunner:
    """How to run the Blender side: `kind` "python" (an interpreter that has bpy) or
    "blender" (a Blender executable), `executable` its path, `source` where it was found."""

    kind: str
    executable: str
    source: str

    def command(self, args: Sequence[str]) -> list[str]:
        boot = _BOOT.format(dir=str(ADDON_DIR))
        if self.kind == "python":
            return [self.executable, "-c", boot, *args]
        return [self.executable, "-b", "--factory-startup", "--python-exit-code", "1",
                "--python-expr", boot, "--", *args]


@dataclass(frozen=True)
class PrimitiveNote:
    """What Blender makes of one primitive: its profile curve ("ellipse": an exact
    rational NURBS, "rhombus": exact, "polygon": an approximation), the polygon's largest
    distance from the true superellipse relative to max(a, b), and whether it folds."""

    index: int
    name: str
    profile: str
    approximated: bool
    profile_error: float
    profile_points: int
    folds: bool

    def describe(self) -> str:
        parts = []
        if self.approximated:
            parts.append(f"profile drawn as a polygon of {self.profile_points} points, at most "
                         f"{self.profile_error:.2g} of its size from the superellipse")
        if self.folds:
            parts.append("folds: Blender's curve turns inside-out there, the solid is not "
                         "exact")
        return f"{self.name}: " + "; ".join(parts) if parts else f"{self.name}: exact"


@dataclass(frozen=True)
class BlendReport:
    """The written file and one note per primitive."""

    path: Path
    primitives: tuple[PrimitiveNote, ...]

    @property
    def approximated(self) -> list[PrimitiveNote]:
        return [p for p in self.primitives if p.approximated]

    @property
    def folding(self) -> list[PrimitiveNote]:
        return [p for p in self.primitives if p.folds]

    def lines(self) -> list[str]:
        """One line per primitive that Blender does not draw exactly."""
        return [p.describe() for p in self.primitives if p.approximated or p.folds]


# --------------------------------------------------------------------------- finding Blender


def _bpy_here() -> str | None:
    """This interpreter, if bpy can be imported in it (checked without importing it)."""
    try:
        return sys.executable if importlib.util.find_spec("bpy") is not None else None
    except (ImportError, ValueError):
        return None


def _setup_python() -> str | None:
    """The Python of .venv-blender beside the running environment (scripts/setup.sh)."""
    root = Path(sys.prefix).parent / ".venv-blender"
    for exe in (root / "bin" / "python", root / "Scripts" / "python.exe"):
        if exe.is_file() and os.access(exe, os.X_OK):
            return str(exe)
    return None


def _blender_on_path() -> str | None:
    return shutil.which("blender")


def _kind_of(executable: str) -> str:
    """"blender" for a Blender executable, "python" for anything else (a Python)."""
    name = Path(executable).name.lower()
    return "blender" if name.startswith("blender") and "python" not in name else "python"


def find_blender() -> BlenderRunner:
    """The Blender runner, looked for in this order: bpy in this Python; the environment
    variable SWEEPEDIT_BLENDER (a Python that has bpy, or a Blender executable);
    .venv-blender/bin/python beside this environment; `blender` on PATH. SweepeditError
    saying how to get one when there is none."""
    here = _bpy_here()
    if here:
        return BlenderRunner("python", here, "bpy in this Python")
    named = os.environ.get(ENV_VAR)
    if named:
        exe = shutil.which(named) or (named if os.path.isfile(named) else None)
        if exe is None:
            raise SweepeditError(f"{ENV_VAR}={named} does not exist; {HOW_TO_GET}")
        return BlenderRunner(_kind_of(exe), exe, ENV_VAR)
    setup = _setup_python()
    if setup:
        return BlenderRunner("python", setup, ".venv-blender")
    blender = _blender_on_path()
    if blender:
        return BlenderRunner("blender", blender, "PATH")
    raise SweepeditError(HOW_TO_GET)


def _summary(stderr: str, stdout: str) -> str:
    """The line of Blender's output that says what went wrong."""
    lines = [ln.strip() for ln in (stderr + "\n" + stdout).splitlines() if ln.strip()]
    for ln in reversed(lines):
        if ln.startswith("sweepedit_blender"):
            return ln.split(": ", 1)[1] if ": " in ln else ln
    for ln in reversed(lines):
        if "Error" in ln or "error" in ln:
            return ln
    return lines[-1] if lines else "no output"


def _run(args: Sequence[str], path: PathLike, what: str) -> dict[str, Any]:
    """Run one command of the Blender side; its report, or SweepeditError naming `path`."""
    runner = find_blender()
    env = dict(os.environ)
    env.pop("PYTHONPATH", None)  # sweepedit's environment is not Blender's
    try:
        proc = subprocess.run(runner.command(args), capture_output=True, text=True, env=env,
                              timeout=TIMEOUT_S, check=False)
    except subprocess.TimeoutExpired:
        raise SweepeditError(f"{path}: Blender took more than {TIMEOUT_S} s to {what}") from None
    except OSError as exc:
        raise SweepeditError(f"{path}: cannot run Blender ({runner.executable}, from "
                             f"{runner.source}): {exc.strerror or exc}") from None
    report = next((ln[len(REPORT_MARKER):] for ln in proc.stdout.splitlines()
                   if ln.startswith(REPORT_MARKER)), None)
    if proc.returncode != 0 or report is None:
        raise SweepeditError(f"{path}: Blender could not {what}: "
                             f"{_summary(proc.stderr, proc.stdout)}")
    return json.loads(report)


# --------------------------------------------------------------------------- export and read


def _mesh_arrays(target: TriangleMesh | tuple[np.ndarray, np.ndarray]
                 ) -> tuple[np.ndarray, np.ndarray]:
    if isinstance(target, TriangleMesh):
        return np.asarray(target.vertices, dtype=np.float64), np.asarray(target.faces)
    vertices, faces = target
    return np.asarray(vertices, dtype=np.float64), np.asarray(faces)


def export_blend(abstraction: Abstraction, path: PathLike, *, original_frame: bool = False,
                 target_mesh: TriangleMesh | tuple[np.ndarray, np.ndarray] | None = None,
                 resolution_scale: float = 1) -> BlendReport:
    """Write the primitives as Blender curve objects (one per primitive, in a collection
    named after the file) -> BlendReport.

    original_frame: place them in the shape's original frame (a parent empty carries the
    normalisation; the curves' own coordinates stay normalised). target_mesh: a mesh in
    the normalised frame to show beside them (wireframe). resolution_scale multiplies the
    curves' resolution (and the points of approximated profiles). Atomic: Blender writes
    a temporary file in the target's folder, which replaces `path` only when complete.
    """
    path = require_folder(path)
    abstraction.validate()
    if not resolution_scale > 0:
        raise SweepeditError(f"{path}: the resolution scale must be positive, got "
                             f"{resolution_scale}")
    doc = abstraction_to_json(abstraction)
    job: dict[str, Any] = {"folds": [folds_onto_itself(p) for p in abstraction.primitives],
                           "original_frame": bool(original_frame),
                           "resolution_scale": float(resolution_scale),
                           "collection": path.stem}
    tmp = path.parent / f".{path.name}.{os.getpid()}.{secrets.token_hex(4)}.tmp.blend"
    try:
        with tempfile.TemporaryDirectory(prefix="sweepedit-blend-") as work:
            if target_mesh is not None:
                vertices, faces = _mesh_arrays(target_mesh)
                np.savez(Path(work) / "target.npz", vertices=vertices,
                         faces=faces.astype(np.int64))
                job["target"] = str(Path(work) / "target.npz")
            doc["sweepedit_blender"] = job
            job_path = Path(work) / "job.json"
            job_path.write_text(json.dumps(doc), encoding="utf-8")
            report = _run(["build", str(job_path), str(tmp)], path, "write it")
        if not tmp.is_file():
            raise SweepeditError(f"{path}: Blender wrote nothing")
        with open(tmp, "rb") as f:
            os.fsync(f.fileno())
        os.replace(tmp, path)
    finally:
        for leftover in (tmp, Path(f"{tmp}@"), Path(f"{tmp}1")):
            with contextlib.suppress(OSError):
                leftover.unlink()
    return BlendReport(path, tuple(
        PrimitiveNote(int(e["index"]), str(e["name"]), str(e["profile"]), bool(e["approximated"]),
                      float(e["profile_error"]), int(e["profile_points"]), bool(e["folds"]))
        for e in report["primitives"]))


def _require_blend(path: PathLike) -> Path:
    path = Path(path)
    if not path.is_file():
        raise SweepeditError(f"{path}: no such file")
    return path


def read_blend(path: PathLike) -> Abstraction:
    """The sweepedit curves of a .blend file as an Abstraction (docs/blender.md, "Reading
    back": exact where nothing was edited; edited curves are read from Blender's data)."""
    path = _require_blend(path)
    with tempfile.TemporaryDirectory(prefix="sweepedit-blend-") as work:
        out = Path(work) / "params.json"
        _run(["read", str(path), str(out)], path, "read it")
        data = json.loads(out.read_text(encoding="utf-8"))
    if not data.get("primitives"):
        raise FileFormatError(path, "holds no sweepedit curves")
    return abstraction_from_json(data, path)


def blend_meshes(path: PathLike) -> list[tuple[str, np.ndarray, np.ndarray]]:
    """Each sweepedit curve of a .blend as Blender evaluates it (its surface, caps
    included), in the normalised frame: [(object name, vertices (V, 3), faces (F, 3))]."""
    path = _require_blend(path)
    with tempfile.TemporaryDirectory(prefix="sweepedit-blend-") as work:
        out = Path(work) / "meshes.npz"
        _run(["mesh", str(path), str(out)], path, "mesh it")
        with np.load(out) as data:
            names = json.loads(str(data["names"]))
            return [(name, np.array(data[f"vertices_{i}"]), np.array(data[f"faces_{i}"]))
                    for i, name in enumerate(names)]


def render_blend(path: PathLike, png: PathLike, size: int = 640) -> None:
    """A workbench picture of the .blend's sweepedit curves (a quick look, headless)."""
    path = _require_blend(path)
    png = require_folder(png)
    with tempfile.TemporaryDirectory(prefix="sweepedit-blend-") as work:
        out = Path(work) / "render.png"
        _run(["render", str(path), str(out), "--size", str(int(size))], path, "render it")
        atomic_write_bytes(png, out.read_bytes())
