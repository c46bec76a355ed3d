"""File > Export > STEP: the export runs in a worker thread behind a progress dialog
with Cancel, so the window stays live while OpenCascade builds and fuses the solids."""

from __future__ import annotations

import threading
from collections.abc import Callable
from pathlib import Path

from PySide6.QtCore import Qt, QThread, Signal
from PySide6.QtWidgets import QProgressDialog, QWidget

from sweepedit.app.worker import lower_thread_priority
from sweepedit.geometry.model import Abstraction

_STEPS = 1000  # progress dialog resolution


class StepExportThread(QThread):
    """Writes a STEP file off the GUI thread (sweepedit.io.step.export_step).

    Signals: progress(fraction, text); done(StepReport); failed(message), with an empty
    message when the user cancelled (nothing is written then).
    """

    progress = Signal(float, str)
    done = Signal(object)
    failed = Signal(str)

    def __init__(self, abstraction: Abstraction, path: Path, union: bool,
                 original_frame: bool = True) -> None:
        super().__init__()
        self._abstraction = abstraction.copy()  # edits while it runs do not reach it
        self._path = Path(path)
        self._union = union
        self._original_frame = original_frame
        self._cancel = threading.Event()

    def cancel(self) -> None:
        self._cancel.set()

    def run(self) -> None:  # in the worker thread
        from sweepedit.io.step import ExportCancelledError, export_step
        from sweepedit.io.step.workers import start_helper

        lower_thread_priority()
        start_helper()  # kept for the next exports: folding primitives built on two cores
        try:
            report = export_step(self._abstraction, self._path, union=self._union,
                                 original_frame=self._original_frame,
                                 progress=self.progress.emit, cancelled=self._cancel.is_set)
        except ExportCancelledError:
            self.failed.emit("")
        except Exception as exc:  # shown to the user; the app goes on
            self.failed.emit(str(exc) or type(exc).__name__)
        else:
            self.done.emit(report)


def start_step_export(parent: QWidget, abstraction: Abstraction, path: Path, union: bool,
                      on_done: Callable[[object], None], on_failed: Callable[[str], None]
                      ) -> StepExportThread:
    """Start a STEP export with a modal progress dialog whose Cancel stops it; on_done
    gets the StepReport, on_failed the error message ('' when cancelled). The caller
    keeps the returned thread referenced until it has finished."""
    dialog = QProgressDialog("Exporting STEP…", "Cancel", 0, _STEPS, parent)
    dialog.setWindowTitle("Export STEP")
    dialog.setWindowModality(Qt.WindowModality.WindowModal)
    dialog.setMinimumDuration(300)
    dialog.setAutoClose(False)
    dialog.setAutoReset(False)
    thread = StepExportThread(abstraction, path, union)

    def progress(fraction: float, text: str) -> None:
        dialog.setValue(round(fraction * _STEPS))
        dialog.setLabelText(f"Exporting {path.name}: {text}")

    def cancel() -> None:
        dialog.setLabelText("Cancelling…")
        thread.cancel()

    thread.progress.connect(progress)
    thread.done.connect(on_done)
    thread.failed.connect(on_failed)
    thread.finished.connect(dialog.close)
    thread.finished.connect(dialog.deleteLater)
    dialog.canceled.connect(cancel)
    thread.start()
    return thread
