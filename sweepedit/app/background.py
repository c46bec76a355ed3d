"""Debounced work off the GUI thread: the live metrics and the heat map both recompute
after edits, once edits pause, in a thread of their own, and show only the newest result.

`DebouncedJob.request(payload)` after every edit; `payload()` is called when the job
starts (on the GUI thread, so it may read the Document), `compute(payload())` runs in
the job's thread, and `finished(result)` or `failed(message)` come back on the GUI
thread for the newest request only. One computation runs at a time: requests made
meanwhile are folded into one more run once it ends.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from PySide6.QtCore import QObject, QThread, QTimer, Signal, Slot


class _Worker(QObject):
    """Lives in the job's thread and runs `compute` on each payload it is sent."""

    finished = Signal(int, object)
    failed = Signal(int, str)

    def __init__(self, compute: Callable[[Any], Any]) -> None:
        super().__init__()
        self._compute = compute

    @Slot(int, object)
    def run(self, generation: int, payload: Any) -> None:
        try:
            result = self._compute(payload)
        except Exception as exc:  # a broken computation must not take the editor down
            self.failed.emit(generation, f"{type(exc).__name__}: {exc}")
            return
        self.finished.emit(generation, result)


class DebouncedJob(QObject):
    """A computation rerun after edits pause (see the module docstring).

    compute(payload) -> result runs in the job's thread (named `name`); it may keep caches
    between calls, since it only ever runs there. Signals: finished(result) and
    failed(message) for the newest request; busy(bool) while a computation runs.
    """

    finished = Signal(object)
    failed = Signal(str)
    busy = Signal(bool)
    _start = Signal(int, object)

    def __init__(self, compute: Callable[[Any], Any], delay_ms: int, name: str,
                 parent: QObject | None = None) -> None:
        super().__init__(parent)
        self._thread = QThread()
        self._thread.setObjectName(name)
        self._worker = _Worker(compute)
        self._worker.moveToThread(self._thread)
        self._start.connect(self._worker.run)
        self._worker.finished.connect(self._on_finished)
        self._worker.failed.connect(self._on_failed)
        self._thread.start()
        self._timer = QTimer(self)
        self._timer.setSingleShot(True)
        self._timer.setInterval(delay_ms)
        self._timer.timeout.connect(self._launch)
        self._generation = 0
        self._running = False
        self._payload: Callable[[], Any] | None = None
        self._closed = False

    def request(self, payload: Callable[[], Any], delay: bool = True) -> None:
        """Compute on what payload() returns once edits pause (at once with delay=False,
        or as soon as the running computation ends)."""
        if self._closed:
            return
        self._generation += 1
        self._payload = payload
        if delay:
            self._timer.start()
        else:
            self._timer.stop()
            self._launch()

    def cancel(self) -> None:
        """Forget pending requests; a running computation ends unreported."""
        self._generation += 1
        self._payload = None
        self._timer.stop()

    @property
    def running(self) -> bool:
        """Whether a result is still to come (waiting for edits to pause, or computing)."""
        return self._running or self._payload is not None or self._timer.isActive()

    def _launch(self) -> None:
        if self._running or self._payload is None:
            return  # launched again when the running one ends
        payload, self._payload = self._payload, None
        self._running = True
        self.busy.emit(True)
        self._start.emit(self._generation, payload())

    def _done(self, generation: int) -> bool:
        """Bookkeeping after a computation; True when it answers the newest request."""
        self._running = False
        newest = generation == self._generation and self._payload is None
        if self._payload is not None and not self._timer.isActive():
            self._launch()
        if not self._running:
            self.busy.emit(False)
        return newest

    def _on_finished(self, generation: int, result: Any) -> None:
        if self._done(generation):
            self.finished.emit(result)

    def _on_failed(self, generation: int, message: str) -> None:
        if self._done(generation):
            self.failed.emit(message)

    def shutdown(self, wait_ms: int = 5000) -> None:
        """Stop the thread (when the owner closes); waits for a running computation."""
        if self._closed:
            return
        self._closed = True
        self.cancel()
        self._thread.quit()
        self._thread.wait(wait_ms)
