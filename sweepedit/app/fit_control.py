"""The app's background fit: starting a fit (or a refit of some primitives with the
others held), its live preview in the scene and its progress in the fit panel, Cancel
with a grace period, and the result applied as one undo step.

Nothing here imports torch: the fit thread loads the fitting code itself (or waits for
the preload that started with the window) and reports a bad setting or missing fitting
code through its failed signal.
"""

from __future__ import annotations

import atexit
import contextlib
import time
from types import SimpleNamespace
from typing import Any

from PySide6.QtCore import QObject, QTimer, Signal

from sweepedit.app.commands import CommandStack, apply_fit
from sweepedit.app.document import Document
from sweepedit.app.panels import FitPanel
from sweepedit.app.prompts import UserPrompts
from sweepedit.app.scene import SweepScene
from sweepedit.app.worker import FitThread, FitUpdate, load_fit_api, refit_loader, with_locked
from sweepedit.errors import SweepeditError
from sweepedit.geometry.model import Abstraction

# Fit threads that outlived their window, or a cancel's grace period, kept referenced (see
# FitControl.shutdown and _cancel_deadline): destroying a running QThread aborts the
# process.
_orphan_threads: list[FitThread] = []
# After Cancel, the fit has this long to return its best result; then the last preview
# (what the user sees) is kept and the fit winds down in the background. Under load the
# fit's low-priority thread can need seconds to reach its next cancel check (measured:
# 2-4 s with two CPU burners, in shape preparation); the user gets control in < 1 s.
CANCEL_GRACE_MS = 400


@atexit.register
def _join_orphan_threads() -> None:
    """At exit, let fits that were told to stop finish (their cancel is set): a QThread
    destroyed while it runs aborts the process."""
    for thread in _orphan_threads:
        with contextlib.suppress(RuntimeError):  # finished earlier and deleted
            thread.wait()


def count_text(values: dict[str, Any], got: int, record: dict[str, Any],
               interrupted: bool) -> str:
    """Why a fit gave the primitives it did, for the status bar: with the automatic count
    why it stopped adding (the record's stopped_because); else why it gave fewer than
    asked for; '' when there is nothing to say."""
    if values.get("auto"):
        because = record.get("stopped_because")
        cap = values.get("primitives")
        return (f"Automatic count: {got} primitive{'s' if got != 1 else ''} (at most {cap})"
                + (f": {because}." if because else "."))
    try:
        asked = int(values.get("primitives"))  # type: ignore[arg-type]
    except (TypeError, ValueError):
        return ""
    if got >= asked:
        return ""
    plural = "s" if asked != 1 else ""
    if interrupted:
        why = ("the fit was stopped before it had placed them all; it keeps the best "
               "result so far (run it again to let it finish)")
    else:
        why = ("the fit drops primitives that add nothing the others do not already cover")
    return f"Asked for {asked} primitive{plural}, got {got}: {why}."


class FitControl(QObject):
    """Runs one background fit at a time for a Document shown in a SweepScene, reporting
    to a FitPanel. running_changed(bool) when a fit starts and when it ends (the window
    locks editing meanwhile). `prompts` (the window) tells the user."""

    running_changed = Signal(bool)

    def __init__(self, doc: Document, stack: CommandStack, scene: SweepScene, panel: FitPanel,
                 prompts: UserPrompts, parent: QObject | None = None) -> None:
        super().__init__(parent)
        self.doc = doc
        self.stack = stack
        self.scene = scene
        self.panel = panel
        self.prompts = prompts
        self.thread: FitThread | None = None
        self.last_result: Any = None
        self.last_cancel_timing: dict[str, float] = {}
        self._locked: list[Any] = []
        self._values: dict[str, Any] = {}
        self._refit = False
        self._started = 0.0
        self._preview: Abstraction | None = None

    @property
    def running(self) -> bool:
        return self.thread is not None

    def start(self, values: dict[str, Any], refit: list[int] | None = None) -> bool:
        """Start a background fit with the fit panel's values; False if it cannot start.
        refit: indices of primitives to refit with all the others fixed, instead."""
        if self.running:
            return False
        if self.doc.shape is None:
            self.prompts.report_error("Cannot fit", "Open a shape first: the fit needs a target.")
            return False
        self._values = dict(values)
        self._refit = refit is not None
        self._preview = None
        # A refit's result holds every primitive (the fixed ones as exact copies).
        self._locked = ([] if refit is not None
                        else [p.copy() for p in self.doc.primitives if p.locked])
        self.stack.close_merge()
        # load_fit_api is looked up now, so that tests can substitute a stand-in.
        load_api = (load_fit_api if refit is None
                    else refit_loader([p.copy() for p in self.doc.primitives], list(refit)))
        thread = FitThread(self.doc.shape, dict(values), self._locked, parent=self,
                           load_api=load_api)
        thread.note.connect(self._on_note)
        thread.progress.connect(self._on_progress)
        thread.done.connect(self._on_done)
        thread.failed.connect(self._on_failed)
        thread.finished.connect(self._on_thread_finished)
        self.thread = thread
        self._started = time.perf_counter()
        self.panel.begin()
        self.running_changed.emit(True)
        thread.start()
        return True

    def cancel(self) -> None:
        """Stop the fit; its best result so far is applied when it returns."""
        if self.thread is not None:
            thread = self.thread
            thread.cancel()
            self.panel.status.setText("Cancelling… (keeping the best result)")
            QTimer.singleShot(CANCEL_GRACE_MS, lambda: self._cancel_deadline(thread))

    def shutdown(self) -> None:
        """The window is closing: stop the fit, and drop what it would still report."""
        thread = self.thread
        if thread is None:
            return
        self._detach(thread)
        thread.cancel()
        if not thread.wait(5000):
            # Still importing torch (a slow first start): destroying a running QThread
            # aborts the process, so it outlives the window (a few seconds).
            thread.setParent(None)
            _orphan_threads.append(thread)
        self.thread = None

    @staticmethod
    def _detach(thread: FitThread) -> None:
        for signal in (thread.note, thread.progress, thread.done, thread.failed):
            signal.disconnect()

    def _cancel_deadline(self, thread: FitThread) -> None:
        """The cancelled fit has not returned in time: keep the last preview it reported
        (or nothing, if it reported none) and let the thread finish in the background."""
        if self.thread is not thread or not thread.isRunning():
            return
        self._detach(thread)
        thread.setParent(None)
        _orphan_threads.append(thread)
        preview = self._preview
        self.last_cancel_timing = {"detached_s": time.perf_counter()
                                   - (thread.cancel_requested_at or time.perf_counter())}
        if preview is None:
            self._on_done(None)
            return
        self._on_done(SimpleNamespace(
            abstraction=preview, seconds=time.perf_counter() - self._started,
            timed_out=False))

    def _on_note(self, text: str) -> None:
        if self.thread is not None and not self.thread.cancel_event.is_set():
            self.panel.status.setText(text)

    def _on_progress(self, update: FitUpdate) -> None:
        if self.thread is None:
            return
        if not self.thread.cancel_event.is_set():  # keep "Cancelling…" up
            self.panel.show_progress(update)
        if update.abstraction is not None:
            self._preview = update.abstraction  # kept if a cancel cannot wait
            # Every report carries a complete abstraction, the first one (the warm start)
            # included: the scene shows it at once and each later one replaces it.
            self.scene.show_preview(with_locked(update.abstraction, self._locked))

    def _on_done(self, result: Any) -> None:
        if self.thread is None:  # the window closed meanwhile
            return
        thread = self.thread
        cancelled = thread.cancel_event.is_set()
        if result is None:  # cancelled before the fit began
            self.scene.end_preview()
            self._finish()
            self.panel.finish("Cancelled before the fit began; nothing changed.")
            return
        self.last_result = result
        if cancelled and thread.cancel_requested_at and thread.returned_at:
            self.last_cancel_timing = {"fit_returned_s": thread.returned_at
                                       - thread.cancel_requested_at}
        self.scene.end_preview()
        prims = with_locked(result.abstraction, self._locked)
        seconds = float(getattr(result, "seconds", time.perf_counter() - self._started))
        timed_out = bool(getattr(result, "timed_out", False))
        record = dict(result.abstraction.fit or {})
        record.update({k: v for k, v in self._values.items() if k not in record})
        record.setdefault("seconds", seconds)
        record["cancelled"] = cancelled
        self._finish()
        try:
            self.stack.push(apply_fit(self.doc, prims, record))
        except SweepeditError as exc:
            self.prompts.report_error("Fit result rejected", str(exc))
            self.panel.finish("The fit returned invalid primitives.")
            return
        self.doc.select(None)
        how = ("Cancelled; kept the best result" if cancelled
               else "Time limit reached; kept the best result" if timed_out else "Done")
        message = f"{how}: {len(prims)} primitives in {seconds:.1f} s (Ctrl+Z undoes it)"
        # A refit neither adds nor removes primitives: no count to explain.
        shortfall = "" if self._refit else count_text(
            self._values, len(prims) - len(self._locked), record, cancelled or timed_out)
        if shortfall:
            message = f"{message}. {shortfall}"
        self.panel.finish(message)
        self.prompts.show_status(shortfall or message, 15000)

    def _on_failed(self, message: str) -> None:
        if self.thread is None:
            return
        self.scene.end_preview()
        self._finish()
        self.panel.finish("Fit failed.")
        self.prompts.report_error("Fit failed", message)

    def _finish(self) -> None:
        self.thread = None
        self.running_changed.emit(False)

    def _on_thread_finished(self) -> None:
        sender = self.sender()
        if isinstance(sender, FitThread):
            sender.deleteLater()
