"""The app's files: opening a shape or parameters (asking what to do with the primitives
shown), New and Close, saving, exporting meshes, STEP solids and the official format,
recent files, and recovering the unsaved edits of an editor that is gone.

The user is asked and told through `UserPrompts` (sweepedit.app.prompts: the window,
which is also the file dialogs' parent).
"""

from __future__ import annotations

import copy
import errno
from collections.abc import Callable
from pathlib import Path
from typing import Any

from PySide6.QtCore import QObject, QSettings, Qt
from PySide6.QtWidgets import QApplication, QFileDialog, QMenu, QWidget

from sweepedit.app.autosave import Autosaver, Recovery
from sweepedit.app.commands import CommandStack, ReplacePrimitives
from sweepedit.app.document import Document
from sweepedit.app.prompts import UserPrompts
from sweepedit.app.worker import call_keeping_window_live
from sweepedit.errors import SweepeditError
from sweepedit.geometry.model import Abstraction
from sweepedit.io.params import is_parameter_file

SHAPE_EXTENSIONS = (".obj", ".ply", ".stl", ".off", ".glb", ".gltf", ".binvox", ".npy", ".npz",
                    ".xyz", ".pts")
MESH_EXPORT_TYPES = {"OBJ (*.obj)": "obj", "PLY (*.ply)": "ply", "STL (*.stl)": "stl",
                     "GLB (*.glb)": "glb"}
MAX_RECENT = 10


class FileControl(QObject):
    """Files for a Document. `prompts` (a QWidget, the parent of the file dialogs) asks and
    tells the user; `busy()` is True while a fit runs, when no file may replace the
    document; `reset_view()` frames a newly opened document. Methods return False when
    nothing was done (the user cancelled, or the file could not be read or written: the
    user has been told)."""

    def __init__(self, doc: Document, stack: CommandStack, autosave: Autosaver,
                 settings: QSettings, prompts: UserPrompts, busy: Callable[[], bool],
                 reset_view: Callable[[], None]) -> None:
        super().__init__(prompts if isinstance(prompts, QObject) else None)
        self.doc = doc
        self.stack = stack
        self.autosave = autosave
        self.settings = settings
        self.prompts = prompts
        self.busy = busy
        self.reset_view = reset_view
        self.step_job: Any = None  # the running or last STEP export (sweepedit.app.step_job)

    @property
    def _dialog_parent(self) -> QWidget | None:
        return self.prompts if isinstance(self.prompts, QWidget) else None

    def _suggestion(self) -> Path | None:
        return self.doc.path or self.doc.shape_path

    # -- opening --------------------------------------------------------------------------
    def open_path(self, path: str | Path) -> bool:
        """Open a parameter file (.json, .txt) or a shape (anything else)."""
        if is_parameter_file(path):
            return self.open_params(path)
        return self.open_shape(path)

    def open_shape(self, path: str | Path, ask: bool = True) -> bool:
        """Load `path` as the target shape; on failure report it and keep what was there.
        With primitives shown against another shape, asks whether to keep them (`ask`
        False: keep them without asking)."""
        path = Path(path)
        if self.busy():
            return False
        # Loading voxelises and samples the shape (a second or two): off the GUI thread, so
        # the window keeps painting while the status bar says what it is doing.
        self.prompts.show_status(f"Loading {path.name}…", 0)
        QApplication.setOverrideCursor(Qt.CursorShape.WaitCursor)
        try:
            from sweepedit.api import load_shape

            shape = call_keeping_window_live(lambda: load_shape(path))
        except Exception as exc:  # any loader failure is the file's, not the app's
            QApplication.restoreOverrideCursor()
            self.prompts.show_status("", 0)
            self.prompts.report_error("Cannot open shape", open_failure_text(exc, path))
            return False
        QApplication.restoreOverrideCursor()
        self.prompts.show_status("", 0)
        # Primitives shown against another shape: keep them for this one or start anew.
        # Primitives without a shape yet (an official .txt opened first) simply get it.
        keep = True
        if len(self.doc) and self.doc.shape is not None and ask:
            answer = self.prompts.ask_keep_primitives(path.name)
            if answer == "cancel" or (answer == "discard" and not self.maybe_save()):
                self.prompts.show_status(f"Did not open {path.name}")
                return False
            keep = answer == "keep"
        if not keep:
            self.clear_document()
        if keep and len(self.doc) and self.doc.shape is not None:
            self._adopt_shape(shape, path)
        else:
            self.doc.set_shape(shape, path)
        self.reset_view()
        self.add_recent(path)
        self.prompts.show_status(f"Opened shape {path.name}")
        return True

    def _adopt_shape(self, shape: Any, path: Path) -> None:
        """Keep the primitives for a new target shape: they stay where they are in the view
        (the normalised frame), and the document now records this shape's frame and path,
        not the old shape's; it is a change to save."""
        self.doc.set_shape(shape, path)
        normalization = getattr(shape, "normalization", None)
        if normalization is not None:
            self.doc.abstraction.normalization = copy.deepcopy(normalization)
        self.doc.abstraction.source = {"path": str(path)}
        self.stack.mark_modified()

    def open_params(self, path: str | Path, ask: bool = True) -> bool:
        """Load primitives from `path`; the current ones are replaced (asks to save first)."""
        path = Path(path)
        if self.busy() or (ask and not self.maybe_save()):
            return False
        try:
            from sweepedit.api import load

            abstraction = load(path)
        except Exception as exc:
            self.prompts.report_error("Cannot open parameters", open_failure_text(exc, path))
            return False
        shape_norm = getattr(self.doc.shape, "normalization", None)
        # The official format has no frame: it takes the shape's, now or once one is opened.
        no_frame = path.suffix.lower() == ".txt"
        if shape_norm is not None and no_frame:
            abstraction.normalization = copy.deepcopy(shape_norm)
        if self.doc.shape_path is not None and abstraction.source is None:
            abstraction.source = {"path": str(self.doc.shape_path)}
        self.doc.set_abstraction(abstraction, path,
                                 frame_known=not no_frame or shape_norm is not None)
        self.stack.clear()
        self.add_recent(path)
        self.prompts.show_status(f"Opened {len(abstraction)} primitives from {path.name}")
        if self.doc.shape is None:
            self._open_source_shape(path, abstraction.source)
        if self.doc.shape is None:
            self.reset_view()
        return True

    def _open_source_shape(self, params_path: Path, source: dict | None) -> None:
        """Open the shape a parameter file was made from, when it can be found."""
        if not source or not source.get("path"):
            return
        candidate = Path(str(source["path"]))
        if not candidate.is_absolute():
            candidate = params_path.parent / candidate
        if candidate.is_file():
            self.open_shape(candidate, ask=False)

    def open_shape_dialog(self) -> bool:
        patterns = " ".join(f"*{e}" for e in SHAPE_EXTENSIONS)
        name, _ = QFileDialog.getOpenFileName(self._dialog_parent, "Open shape", self.last_dir(),
                                              f"Shapes ({patterns});;All files (*)")
        return bool(name) and self.open_shape(name)

    def open_params_dialog(self) -> bool:
        name, _ = QFileDialog.getOpenFileName(
            self._dialog_parent, "Open parameters", self.last_dir(),
            "Parameters (*.json *.txt);;SweepEdit (*.json);;SweepNet (*.txt);;All files (*)")
        return bool(name) and self.open_params(name)

    # -- New and Close --------------------------------------------------------------------
    def clear_document(self) -> None:
        """No primitives, no parameter file, an empty history (New, Close, Discard)."""
        self.doc.set_abstraction(Abstraction(), None, frame_known=False)
        self.stack.clear()

    def new_document(self) -> bool:
        """File > New: no shape, no primitives; False when the user cancels."""
        if self.busy() or not self.maybe_save():
            return False
        self.clear_document()
        self.doc.set_shape(None, None)
        self.reset_view()
        self.autosave.remove()
        self.prompts.show_status("New document")
        return True

    def close_document(self) -> bool:
        """File > Close: the window stays, empty (the same as New in a one-document
        editor); False when the user cancels."""
        if not self.new_document():
            return False
        self.prompts.show_status("Closed; open a shape (Ctrl+O) or parameters (Ctrl+Shift+O)")
        return True

    # -- saving ---------------------------------------------------------------------------
    def maybe_save(self) -> bool:
        """Before discarding the document: True to go on, False when the user cancels."""
        if not self.doc.dirty:
            return True
        answer = self.prompts.ask_save_changes()
        if answer == "save":
            return self.save()
        return answer == "discard"

    def save(self) -> bool:
        path = self.doc.path
        if path is None or path.suffix.lower() != ".json":
            return self.save_as()
        return self.save_to(path)

    def save_as(self) -> bool:
        start = self._suggestion()
        suggestion = str(start.with_suffix(".json")) if start is not None else "primitives.json"
        name, _ = QFileDialog.getSaveFileName(self._dialog_parent, "Save primitives",
                                              suggestion, "SweepEdit parameters (*.json)")
        if not name:
            return False
        return self.save_to(with_suffix(name, (".json",)))

    def save_to(self, path: str | Path) -> bool:
        """Write the primitives to `path` (.json, or .txt for the official format)."""
        path = Path(path)
        try:
            from sweepedit.api import export

            export(self.doc.abstraction, path)
        except Exception as exc:
            self.prompts.report_error("Cannot save", save_failure_text(exc, path))
            return False
        if path.suffix.lower() == ".json":
            self.doc.set_path(path)
            self.stack.set_clean()
            self.autosave.remove()  # nothing unsaved is left to recover
        self.add_recent(path)
        self.prompts.show_status(f"Saved {path}")
        return True

    # -- exporting ------------------------------------------------------------------------
    def export_txt_dialog(self) -> bool:
        start = self._suggestion()
        suggestion = str(start.with_suffix(".txt")) if start else "primitive_parameters.txt"
        name, _ = QFileDialog.getSaveFileName(self._dialog_parent,
                                              "Export official SweepNet parameters",
                                              suggestion, "SweepNet parameters (*.txt)")
        if not name:
            return False
        return self.save_to(with_suffix(name, (".txt",)))

    def export_mesh_dialog(self, per_primitive: bool) -> bool:
        start = self._suggestion()
        stem = start.stem if start is not None else "primitives"
        name, chosen = QFileDialog.getSaveFileName(
            self._dialog_parent, "Export mesh",
            f"{stem}_{'parts' if per_primitive else 'union'}.obj", ";;".join(MESH_EXPORT_TYPES))
        if not name:
            return False
        if Path(name).suffix.lower().lstrip(".") not in MESH_EXPORT_TYPES.values():
            name += "." + MESH_EXPORT_TYPES.get(chosen, "obj")
        return self.export_mesh(name, per_primitive)

    def export_mesh(self, path: str | Path, per_primitive: bool = False) -> bool:
        """Export the visible primitives in the shape's original frame: their union as one
        watertight mesh, or one file per primitive (STEM_00.EXT, ...)."""
        path = Path(path)
        try:
            from sweepedit.api import export

            visible = self.doc.abstraction.copy()
            visible.primitives = visible.visible()
            written = export(visible, path, per_primitive=per_primitive, original_frame=True)
        except Exception as exc:
            self.prompts.report_error("Cannot export mesh", save_failure_text(exc, path))
            return False
        self.prompts.show_status(
            f"Exported {len(written)} file(s): {', '.join(p.name for p in written)}")
        return True

    def export_step_dialog(self, union: bool) -> bool:
        start = self._suggestion()
        stem = start.stem if start is not None else "primitives"
        name, _ = QFileDialog.getSaveFileName(self._dialog_parent, "Export STEP",
                                              f"{stem}.step", "STEP (*.step *.stp)")
        if not name:
            return False
        return self.export_step(with_suffix(name, (".step", ".stp")), union)

    def export_step(self, path: str | Path, union: bool = False) -> bool:
        """Start writing the visible primitives (in the shape's original frame) as STEP
        solids in a worker thread, behind a progress dialog with Cancel; False if an
        export is already running."""
        from sweepedit.app.step_job import start_step_export

        if self.step_job is not None and self.step_job.isRunning():
            self.prompts.show_status("A STEP export is already running")
            return False
        path = Path(path)

        def done(report: Any) -> None:
            self.prompts.show_status(f"Exported {report.solids} solid(s) to {path.name} "
                                     f"({report.size / 1024:.0f} kB, {report.seconds:.1f} s)")

        def failed(message: str) -> None:
            if message:
                self.prompts.report_error("Cannot export STEP", message)
            else:
                self.prompts.show_status("STEP export cancelled; nothing was written")

        self.step_job = start_step_export(self._dialog_parent, self.doc.abstraction, path,
                                          union, done, failed)
        return True

    def shutdown(self) -> None:
        """When the window closes: a running STEP export is cancelled between two steps,
        and writes nothing."""
        if self.step_job is not None:
            self.step_job.cancel()
            self.step_job.wait()

    # -- recent files ---------------------------------------------------------------------
    def recent_files(self) -> list[str]:
        value = self.settings.value("recent_files", [])
        if isinstance(value, str):
            value = [value]
        return [str(v) for v in (value or [])]

    def add_recent(self, path: Path) -> None:
        p = str(Path(path).resolve())
        recent = [r for r in self.recent_files() if r != p]
        self.settings.setValue("recent_files", [p, *recent][:MAX_RECENT])

    def last_dir(self) -> str:
        recent = self.recent_files()
        return str(Path(recent[0]).parent) if recent else ""

    def fill_recent_menu(self, menu: QMenu) -> None:
        """The recent files as a menu's entries (each opens its file), newest first."""
        menu.clear()
        recent = self.recent_files()
        if not recent:
            menu.addAction("(none)").setEnabled(False)
            return
        for p in recent:
            action = menu.addAction(p)
            action.setEnabled(not self.busy())
            action.triggered.connect(lambda _c=False, p=p: self.open_path(p))
        menu.addSeparator()
        menu.addAction("Clear list").triggered.connect(
            lambda: self.settings.setValue("recent_files", []))

    # -- recovery -------------------------------------------------------------------------
    def offer_recovery(self, answer: bool | None = None) -> bool:
        """Offer the unsaved edits of editors that are gone, newest first (`answer`: True
        or False answers every offer without asking, for `sweepedit gui --recover`).
        True when one was recovered; declined ones stay until this session autosaves."""
        for recovery in self.autosave.orphans():
            take = self.prompts.ask_recover(recovery) if answer is None else answer
            if take and self.recover(recovery):
                return True
            self.autosave.declined(recovery)
        return False

    def recover(self, recovery: Recovery) -> bool:
        """Replace the document by exactly the autosaved one: its shape is opened again,
        its parameter file becomes the document's path, and the autosaved primitives are
        one undoable step on top of that file (so Ctrl+Z shows what was last saved)."""
        if self.busy():
            return False
        self.clear_document()
        self.doc.set_shape(None, None)
        shape_path = recovery.shape_path
        if shape_path is not None and shape_path.is_file():
            self.open_shape(shape_path, ask=False)
        elif shape_path is not None:
            self.prompts.show_status(f"The shape {shape_path} is gone; recovered the "
                                     "primitives without it", 15000)
        doc_path = recovery.document_path
        base = None
        if doc_path is not None and doc_path.is_file():
            try:
                from sweepedit.io.params import read_abstraction

                base = read_abstraction(doc_path)
            except Exception:  # a damaged file: the recovered state is all there is
                base = None
        saved = recovery.abstraction
        base_from_file = base is not None
        if base is not None:
            base.normalization = copy.deepcopy(saved.normalization)
        else:
            base = Abstraction(normalization=copy.deepcopy(saved.normalization))
        base.source = copy.deepcopy(saved.source)
        base.extras = copy.deepcopy(saved.extras)
        self.doc.set_abstraction(base, doc_path, frame_known=recovery.frame_known)
        self.stack.clear()
        self.stack.push(ReplacePrimitives([p.copy() for p in saved.primitives],
                                          copy.deepcopy(saved.fit),
                                          text="Recover unsaved edits"))
        if base_from_file is False:
            self.stack.mark_modified()  # undo must not make an unsaved document look saved
        self.autosave.taken(recovery)
        self.reset_view()
        self.prompts.show_status(f"Recovered the unsaved edits of {recovery.title}", 15000)
        return True


def with_suffix(name: str, suffixes: tuple[str, ...]) -> str:
    """`name` as typed in a save dialog, with the first of `suffixes` added unless it ends
    in one of them (in any case)."""
    return name if Path(name).suffix.lower() in suffixes else name + suffixes[0]


def save_failure_text(exc: BaseException, path: Path) -> str:
    """Why a save failed and what to do, in the user's words (not "[Errno 2] ...")."""
    what = f"Could not save {path.name}"
    folder = path.parent
    if not folder.exists():  # whoever found it out first (an OSError, or a check before)
        return f"{what}: the folder {folder} does not exist. Choose another folder."
    if isinstance(exc, OSError):
        code = exc.errno
        if code == errno.ENOENT or (code is None and not folder.is_dir()):
            return f"{what}: the folder {folder} does not exist. Choose another folder."
        if code in (errno.EACCES, errno.EPERM):
            return (f"{what}: you may not write to the folder {folder}. "
                    "Choose another folder.")
        if code == errno.EROFS:
            return f"{what}: {folder} is on a read-only disk. Choose another folder."
        if code == errno.ENOSPC:
            return f"{what}: the disk is full. Free some space or choose another disk."
        if code == errno.EISDIR:
            return f"{what}: {path} is a folder. Choose another name."
        if code == errno.ENOTDIR:
            return f"{what}: part of {folder} is a file, not a folder. Choose another folder."
        return f"{what}: {exc.strerror or exc}. Choose another folder or name."
    if isinstance(exc, SweepeditError):  # the format cannot hold it; its message says why
        return f"{what}: {str(exc).removeprefix(f'{path}: ')}"
    return f"{what}: {exc} ({type(exc).__name__})"


def open_failure_text(exc: BaseException, path: Path) -> str:
    """A message naming the file and the problem (FileFormatError already names the file)."""
    message = str(exc) or type(exc).__name__
    if str(path) not in message and path.name not in message:
        message = f"{path}: {message}"
    if not isinstance(exc, SweepeditError | OSError | ValueError):
        message += f" ({type(exc).__name__})"
    return message
