"""Background work for the app: fitting and metrics, off the GUI thread.

Results come back through Qt signals; a signal emitted in a worker thread reaches slots of
objects living in the GUI thread as a queued call, so views are only touched there.
"""

from __future__ import annotations

import dataclasses
import threading
import time
import traceback
from collections.abc import Callable
from typing import Any

from PySide6.QtCore import QEventLoop, QObject, Qt, QThread, QTimer, Signal, Slot

from sweepedit.geometry.model import Abstraction, SweepPrimitive

# The fit is reported to the GUI at most this often; later progress replaces earlier.
PROGRESS_INTERVAL_S = 0.1
METRICS_SAMPLES = 20000
METRICS_DELAY_MS = 350


def load_fit_api() -> tuple[Callable[..., Any], type]:
    """(fit_abstraction, FitSettings) from sweepedit.fitting.fit, imported lazily (torch is
    slow to import). Raises ImportError when fitting is not available."""
    from sweepedit.fitting.fit import FitSettings, fit_abstraction

    return fit_abstraction, FitSettings


def load_evaluate() -> Callable[..., dict]:
    """sweepedit.analysis.metrics.evaluate, imported lazily."""
    from sweepedit.analysis.metrics import evaluate

    return evaluate


class _Finished(QObject):
    """Carries "the call is over" from a worker thread to the GUI thread's event loop."""

    finished = Signal()


def call_keeping_window_live(fn: Callable[[], Any]) -> Any:
    """fn() run in a worker thread while the GUI thread keeps painting and resizing (user
    input waits, so nothing can change under the call); its result is returned, or its
    exception re-raised, here. For short blocking work such as loading a shape."""
    outcome: dict[str, Any] = {}
    signal = _Finished()
    loop = QEventLoop()
    # Queued: the quit runs in this thread's loop, even if fn ends before exec() starts.
    signal.finished.connect(loop.quit, Qt.ConnectionType.QueuedConnection)

    def run() -> None:
        try:
            outcome["value"] = fn()
        except BaseException as exc:  # handed back to the caller's thread
            outcome["error"] = exc
        finally:
            signal.finished.emit()

    thread = threading.Thread(target=run, name="sweepedit-load", daemon=True)
    thread.start()
    loop.exec(QEventLoop.ProcessEventsFlag.ExcludeUserInputEvents)
    thread.join()
    if "error" in outcome:
        raise outcome["error"]
    return outcome.get("value")


def make_settings(settings_type: type, values: dict[str, Any]) -> Any:
    """Build FitSettings from the fit panel's values, passing only fields it has."""
    if dataclasses.is_dataclass(settings_type):
        names = {f.name for f in dataclasses.fields(settings_type)}
        values = {k: v for k, v in values.items() if k in names}
    return settings_type(**values)


def _same_primitive(a: SweepPrimitive, b: SweepPrimitive) -> bool:
    return (a.control_points.shape == b.control_points.shape
            and bool((a.control_points == b.control_points).all())
            and (a.a, a.b, a.degree, a.scaling) == (b.a, b.b, b.degree, b.scaling))


def with_locked(result: Abstraction, locked: list[SweepPrimitive]) -> list[SweepPrimitive]:
    """The primitives of a fit result with the locked ones kept exactly as they were.

    A result that already contains each locked primitive (the fit passes them through)
    is used as is, with the originals' names and colours; otherwise the locked ones come
    first, followed by the new primitives."""
    prims = [p.copy() for p in result.primitives]
    missing = []
    for lp in locked:
        match = next((i for i, p in enumerate(prims) if _same_primitive(p, lp)), None)
        if match is None:
            missing.append(lp.copy())
        else:
            prims[match] = lp.copy()
    return missing + prims


class FitThread(QThread):
    """Runs fit_abstraction in a thread.

    Signals: progress(iteration, total, losses_batch, abstraction) with losses_batch a list
    of (iteration, {name: value}) since the last report and abstraction a private copy;
    done(result) with the FitResult; failed(message).
    """

    progress = Signal(int, int, object, object)
    done = Signal(object)
    failed = Signal(str)

    def __init__(self, shape: Any, settings: Any, locked: list[SweepPrimitive],
                 fit_function: Callable[..., Any], parent: QObject | None = None) -> None:
        super().__init__(parent)
        self.shape = shape
        self.settings = settings
        self.locked = [p.copy() for p in locked]
        self.fit_function = fit_function
        self.cancel_event = threading.Event()
        self._last_emit = 0.0
        self._losses: list[tuple[int, dict[str, float]]] = []
        self.cancel_requested_at: float | None = None
        self.returned_at: float | None = None  # when fit_function returned (diagnostics)

    def cancel(self) -> None:
        """Ask the fit to stop; it returns its best result so far (done is still emitted)."""
        if self.cancel_requested_at is None:
            self.cancel_requested_at = time.perf_counter()
        self.cancel_event.set()

    def _callback(self, p: Any) -> None:
        self._losses.append((int(p.iteration), {k: float(v) for k, v in p.losses.items()}))
        now = time.perf_counter()
        last = int(p.iteration) >= int(p.total)
        if now - self._last_emit >= PROGRESS_INTERVAL_S or last:
            self._last_emit = now
            batch, self._losses = self._losses, []
            abstraction = p.abstraction.copy() if p.abstraction is not None else None
            self.progress.emit(int(p.iteration), int(p.total), batch, abstraction)

    def run(self) -> None:  # in the worker thread
        try:
            result = self.fit_function(self.shape, self.settings, locked=self.locked,
                                       callback=self._callback, cancel=self.cancel_event)
        except Exception as exc:  # reported to the user, the app goes on
            traceback.print_exc()
            self.failed.emit(f"{type(exc).__name__}: {exc}")
            return
        finally:
            self.returned_at = time.perf_counter()
        self.done.emit(result)


class _MetricsJob(QObject):
    """Lives in the metrics thread; computes one evaluation per request."""

    finished = Signal(int, object)
    failed = Signal(int, str)

    def __init__(self, n_samples: int) -> None:
        super().__init__()
        self.n_samples = n_samples

    @Slot(int, object, object)
    def compute(self, generation: int, abstraction: Abstraction, shape: Any) -> None:
        try:
            evaluate = load_evaluate()
            t0 = time.perf_counter()
            result = dict(evaluate(abstraction, shape, n_samples=self.n_samples, seed=0))
            result["seconds"] = time.perf_counter() - t0
        except Exception as exc:  # a broken metric must not take the editor down
            self.failed.emit(generation, f"{type(exc).__name__}: {exc}")
            return
        self.finished.emit(generation, result)


class MetricsRunner(QObject):
    """Debounced, never-blocking metrics: `request()` after every edit; the evaluation
    starts once edits pause, runs in its own thread, and only the newest result is
    reported (`updated(dict)`); `busy(bool)` says whether one is being computed."""

    updated = Signal(object)
    failed = Signal(str)
    busy = Signal(bool)
    _compute = Signal(int, object, object)

    def __init__(self, parent: QObject | None = None, n_samples: int = METRICS_SAMPLES,
                 delay_ms: int = METRICS_DELAY_MS) -> None:
        super().__init__(parent)
        self._thread = QThread()
        self._thread.setObjectName("sweepedit-metrics")
        self._job = _MetricsJob(n_samples)
        self._job.moveToThread(self._thread)
        self._compute.connect(self._job.compute)
        self._job.finished.connect(self._on_finished)
        self._job.failed.connect(self._on_failed)
        self._thread.start()
        self._timer = QTimer(self)
        self._timer.setSingleShot(True)
        self._timer.setInterval(delay_ms)
        self._timer.timeout.connect(self._launch)
        self._generation = 0
        self._running: int | None = None
        self._pending: tuple[Abstraction, Any] | None = None
        self.last_result: dict | None = None

    def request(self, abstraction: Abstraction, shape: Any) -> None:
        """Evaluate a copy of `abstraction` against `shape` once edits pause."""
        self._generation += 1
        self._pending = (abstraction.copy(), shape)
        self._timer.start()

    def cancel(self) -> None:
        """Forget pending requests; a running one finishes but is not reported."""
        self._generation += 1
        self._pending = None
        self._timer.stop()

    @property
    def running(self) -> bool:
        return self._running is not None or self._timer.isActive()

    def _launch(self) -> None:
        if self._running is not None or self._pending is None:
            return  # launched again when the running one finishes
        abstraction, shape = self._pending
        self._pending = None
        self._running = self._generation
        self.busy.emit(True)
        self._compute.emit(self._generation, abstraction, shape)

    def _done(self) -> bool:
        """Bookkeeping after a job; True when the finished job is the newest request."""
        current = self._running == self._generation
        self._running = None
        if self._pending is not None and not self._timer.isActive():
            self._launch()
        if self._running is None:
            self.busy.emit(False)
        return current

    def _on_finished(self, generation: int, result: dict) -> None:
        if self._done() and generation == self._generation:
            self.last_result = result
            self.updated.emit(result)

    def _on_failed(self, generation: int, message: str) -> None:
        if self._done() and generation == self._generation:
            self.failed.emit(message)

    def shutdown(self, wait_ms: int = 5000) -> None:
        """Stop the thread (at exit); waits for a running evaluation."""
        self.cancel()
        self._thread.quit()
        self._thread.wait(wait_ms)
