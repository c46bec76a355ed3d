"""Background work for the app: fitting and metrics, off the GUI thread.

Results come back through Qt signals; a signal emitted in a worker thread reaches slots of
objects living in the GUI thread as a queued call, so views are only touched there.
"""

from __future__ import annotations

import dataclasses
import gc
import importlib.util
import os
import sys
import threading
import time
import traceback
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from PySide6.QtCore import QEventLoop, QObject, Qt, QThread, Signal

from sweepedit.app.background import DebouncedJob
from sweepedit.errors import SweepeditError
from sweepedit.geometry.model import Abstraction, SweepPrimitive

# The fit is reported to the GUI at most this often; later progress replaces earlier.
PROGRESS_INTERVAL_S = 0.1
METRICS_SAMPLES = 20000
# Edits pause this long before the metrics are recomputed: a drag sends a move every few
# milliseconds. LiveMetrics redoes only the edited primitive's share (~0.1 s), so the
# status bar follows an edit within half a second.
METRICS_DELAY_MS = 120
# Mapped without the GIL before torch is imported (_preload_torch_libraries).
TORCH_LIBRARIES = ("libc10.so", "libtorch_cpu.so", "libtorch.so")
# Nice value added to a fit's thread once the fitting code is loaded (Linux): with every
# core busy, the GUI thread gets the CPU first, and an idle GUI costs the fit nothing.
# Not while importing torch: its long GIL-holding steps would then take longer, and the
# GUI thread waits for the GIL (measured: one 135 ms stall).
WORKER_NICENESS = 10
# How long a thread may keep the GIL while another waits for it (Python's default: 5 ms).
# The GUI thread gives the GIL up many times a frame (numpy on arrays of more than a few
# hundred items, Qt's event processing, rendering), and beside a thread running Python
# (torch's import, the fit's own Python) it waits a whole interval to get it back each
# time: a preview of 8 primitives took 302 ms beside one such thread at 5 ms, 58 ms at
# 0.5 ms (BENCHMARKS.md, "App responsiveness").
GUI_SWITCH_INTERVAL_S = 0.0005


def lower_thread_priority(increment: int = WORKER_NICENESS) -> None:
    """Make the calling thread (and the threads it starts later, such as torch's CPU
    workers) yield the CPU to the GUI thread. Linux only, where the nice value belongs
    to a thread; elsewhere it would apply to the whole process."""
    if not sys.platform.startswith("linux") or increment <= 0:
        return
    try:
        tid = threading.get_native_id()
        os.setpriority(os.PRIO_PROCESS, tid, os.getpriority(os.PRIO_PROCESS, tid) + increment)
    except OSError:
        pass


def favour_gui_thread() -> None:
    """Let the GUI thread have the GIL back within GUI_SWITCH_INTERVAL_S when a worker
    thread holds it (process-wide; never lengthens a shorter interval set elsewhere)."""
    sys.setswitchinterval(min(sys.getswitchinterval(), GUI_SWITCH_INTERVAL_S))


def _dlopen_without_gil(path: str) -> bool:
    """dlopen(path) through ctypes' foreign-function call, which releases the GIL: unlike
    an import (or ctypes.CDLL), the GUI thread keeps running while a large library is
    mapped and its static constructors run. Linux only; False when not done."""
    import ctypes

    try:
        libc = ctypes.CDLL(None)
        libc.dlopen.restype = ctypes.c_void_p
        libc.dlopen.argtypes = [ctypes.c_char_p, ctypes.c_int]
        return bool(libc.dlopen(path.encode(), os.RTLD_NOW))
    except (OSError, AttributeError):
        return False


def _preload_torch_libraries() -> None:
    """Map libtorch before `import torch` does. The import would dlopen it holding the
    GIL: ~170 ms in which the GUI thread cannot run a line of Python. Loaded here first
    (RTLD_LOCAL, so no symbol is exported that torch would not export itself), the
    import finds it already in memory. Only the CPU libraries: CUDA builds preload their
    own dependencies in an order this must not pre-empt."""
    if not sys.platform.startswith("linux"):
        return
    spec = importlib.util.find_spec("torch")  # finds the package without importing it
    if spec is None or spec.origin is None:
        return
    lib = Path(spec.origin).parent / "lib"
    for name in TORCH_LIBRARIES:
        if (lib / name).is_file():
            _dlopen_without_gil(str(lib / name))


def _import_fit_api() -> tuple[Callable[..., Any], type]:
    """Import the fit API, keeping the GIL free for the GUI thread as much as possible."""
    # torch imports this module, which registers an exit hook: refused once the app is
    # quitting (which waits for this import), so it is imported first.
    import concurrent.futures.thread  # noqa: F401

    _preload_torch_libraries()
    # Importing torch creates millions of objects; with the collector on, the full
    # collections they trigger (up to ~100 ms each, holding the GIL) stall the GUI
    # thread. Off meanwhile; frozen afterwards, so that later full collections do not
    # scan torch's objects either (it would stall a later fit the same way).
    gc_was_enabled = gc.isenabled()
    gc.disable()
    try:
        import torch

        from sweepedit.fitting.fit import FitSettings, fit_abstraction

        # The first optimiser imports torch._dynamo lazily (another 1.5 s): here, not
        # when the fit has started.
        torch.optim.Adam([torch.zeros(1, requires_grad=True)])
    finally:
        gc.freeze()
        if gc_was_enabled:
            gc.enable()
    return fit_abstraction, FitSettings


_fit_api: tuple[Callable[..., Any], type] | None = None
_fit_api_lock = threading.Lock()
_preload_thread: threading.Thread | None = None


def load_fit_api() -> tuple[Callable[..., Any], type]:
    """(fit_abstraction, FitSettings) from sweepedit.fitting.fit, imported on first use
    (torch: seconds). Call it from a worker thread, never the GUI thread; while the
    preload (`preload_fit_api`) is importing, this waits for it instead of importing a
    second time. Raises ImportError when fitting is not available."""
    global _fit_api
    with _fit_api_lock:
        if _fit_api is None:
            _fit_api = _import_fit_api()
        return _fit_api


def refit_loader(primitives: list[SweepPrimitive], selected: list[int]
                 ) -> Callable[[], tuple[Callable[..., Any], type]]:
    """A load_api for FitThread that refits `selected` (indices into `primitives`) with
    the others fixed (sweepedit.fitting.refit); imported in the worker thread, as the fit
    is."""
    def load() -> tuple[Callable[..., Any], type]:
        _, settings_type = load_fit_api()
        from sweepedit.fitting.refit import refit_selection

        def run(shape: Any, settings: Any, *, locked: Any = (), callback: Any = None,
                cancel: Any = None) -> Any:
            return refit_selection(shape, primitives, selected, settings, callback=callback,
                                   cancel=cancel)

        return run, settings_type

    return load


def fit_api_ready() -> bool:
    """Whether load_fit_api would return at once."""
    return _fit_api is not None


def preload_fit_api() -> threading.Thread:
    """Start importing the fit API in a background thread (once per process), so that the
    first fit of a session starts without waiting for torch. Returns that thread."""
    global _preload_thread
    if _preload_thread is None:
        def run() -> None:
            try:
                load_fit_api()
            except Exception:  # reported when a fit asks for it (load_fit_api again)
                traceback.print_exc()

        # Not a daemon: quitting at once waits for the import to finish instead of
        # tearing the process down under a library's static constructors.
        _preload_thread = threading.Thread(target=run, name="sweepedit-preload-fit")
        _preload_thread.start()
    return _preload_thread


def load_live_metrics() -> type:
    """sweepedit.analysis.live_metrics.LiveMetrics, imported lazily."""
    from sweepedit.analysis.live_metrics import LiveMetrics

    return LiveMetrics


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


@dataclass
class FitUpdate:
    """One progress report of a running fit, as the GUI receives it.

    `stage` is the fit's stage ("warm start", "network", "refinement", "residual round k
    of n"; None from a fit that does not say) and `stage_fraction` its own progress, 0..1;
    `seconds_left` an estimate or None; `losses` every (iteration, {name: value}) since
    the previous update; `abstraction` a private copy of the current primitives."""

    iteration: int
    total: int
    stage: str | None = None
    stage_fraction: float = 0.0
    seconds_left: float | None = None
    losses: list[tuple[int, dict[str, float]]] = field(default_factory=list)
    abstraction: Abstraction | None = None


class FitThread(QThread):
    """Runs fit_abstraction in a thread.

    Either `fit_function` is given and `settings` is its settings object, or `load_api`
    (load_fit_api by default) is called here, in the worker thread, for (fit_function,
    settings type) and `settings` is a dict of values for that type: the GUI thread
    never imports torch.

    Signals: note(text) while preparing (loading the fitting code); progress(FitUpdate),
    at most every PROGRESS_INTERVAL_S except the first report, a new stage and the end
    of a stage, which always go through; done(result) with the FitResult, or None when
    cancelled before the fit began; failed(message).
    """

    note = Signal(str)
    progress = Signal(object)
    done = Signal(object)
    failed = Signal(str)

    def __init__(self, shape: Any, settings: Any, locked: list[SweepPrimitive],
                 fit_function: Callable[..., Any] | None = None,
                 parent: QObject | None = None, *,
                 load_api: Callable[[], tuple[Callable[..., Any], type]] | None = None) -> None:
        super().__init__(parent)
        self.shape = shape
        self.settings = settings
        self.locked = [p.copy() for p in locked]
        self.fit_function = fit_function
        self.load_api = load_api or load_fit_api
        self.cancel_event = threading.Event()
        self._last_emit: float | None = None
        self._last_stage: str | None = None
        self._losses: list[tuple[int, dict[str, float]]] = []
        self.cancel_requested_at: float | None = None
        # Diagnostics: when the fit API was at hand and when fit_function returned.
        self.loaded_at: float | None = None
        self.returned_at: float | None = None

    def cancel(self) -> None:
        """Ask the fit to stop; it returns its best result so far (done is still emitted)."""
        if self.cancel_requested_at is None:
            self.cancel_requested_at = time.perf_counter()
        self.cancel_event.set()

    def _callback(self, p: Any) -> None:
        self._losses.append((int(p.iteration), {k: float(v) for k, v in p.losses.items()}))
        now = time.perf_counter()
        stage = getattr(p, "stage", None)
        fraction = getattr(p, "stage_fraction", None)
        if fraction is None:  # a fit that reports iterations only
            fraction = int(p.iteration) / max(int(p.total), 1)
        # The first report (the complete warm start), a new stage and the end of one
        # always go through; in between, at most one report per interval.
        due = (self._last_emit is None or stage != self._last_stage or fraction >= 1.0
               or int(p.iteration) >= int(p.total)
               or now - self._last_emit >= PROGRESS_INTERVAL_S)
        if not due:
            return
        self._last_emit, self._last_stage = now, stage
        batch, self._losses = self._losses, []
        seconds_left = getattr(p, "seconds_left", None)
        self.progress.emit(FitUpdate(
            int(p.iteration), int(p.total), stage, float(min(max(fraction, 0.0), 1.0)),
            None if seconds_left is None else float(seconds_left), batch,
            p.abstraction.copy() if p.abstraction is not None else None))

    def _prepare(self) -> tuple[Callable[..., Any], Any]:
        """The fit function and its settings, loading the API here when not given."""
        if self.fit_function is not None:
            self.loaded_at = time.perf_counter()
            return self.fit_function, self.settings
        if not fit_api_ready():
            self.note.emit("Loading the fitting code (first fit of the session)…")
        try:
            fit_function, settings_type = self.load_api()
        except Exception as exc:
            message = f"Fitting is not available: {type(exc).__name__}: {exc}"
            raise _UnavailableError(message) from exc
        settings = self.settings
        if isinstance(settings, dict):
            settings = make_settings(settings_type, settings)
        validate = getattr(settings, "validate", None)
        if callable(validate):
            validate()  # a bad value is one clear error before the shape is prepared
        self.loaded_at = time.perf_counter()
        self.note.emit("Preparing the shape…")
        return fit_function, settings

    def run(self) -> None:  # in the worker thread
        try:
            fit_function, settings = self._prepare()
            lower_thread_priority()
            if self.cancel_event.is_set():  # cancelled while loading: nothing to keep
                self.done.emit(None)
                return
            result = fit_function(self.shape, settings, locked=self.locked,
                                  callback=self._callback, cancel=self.cancel_event)
        except (_UnavailableError, SweepeditError) as exc:  # the message says it all
            self.failed.emit(str(exc))
            return
        except Exception as exc:  # reported to the user, the app goes on
            traceback.print_exc()
            self.failed.emit(f"{type(exc).__name__}: {exc}")
            return
        finally:
            self.returned_at = time.perf_counter()
        self.done.emit(result)


class _UnavailableError(Exception):
    """The fit API could not be loaded (its message says so)."""


class _LiveMetricsCache:
    """The current shape's LiveMetrics, which keeps each primitive's share between
    evaluations; used in the metrics thread only."""

    def __init__(self, n_samples: int) -> None:
        self.n_samples = n_samples
        self._live: Any = None

    def evaluate(self, payload: tuple[Abstraction, Any]) -> dict:
        abstraction, shape = payload
        t0 = time.perf_counter()
        if self._live is None or self._live.shape is not shape:
            self._live = None  # the old shape's caches go first
            self._live = load_live_metrics()(shape, n_samples=self.n_samples, seed=0)
        result = dict(self._live.evaluate(abstraction.primitives))
        result["seconds"] = time.perf_counter() - t0
        return result


class MetricsRunner(QObject):
    """Debounced, never-blocking metrics: `request()` after every edit; the evaluation
    starts once edits pause, runs in its own thread, and only the newest result is
    reported (`updated(dict)`); `busy(bool)` says whether one is being computed."""

    updated = Signal(object)
    failed = Signal(str)
    busy = Signal(bool)

    def __init__(self, parent: QObject | None = None, n_samples: int = METRICS_SAMPLES,
                 delay_ms: int = METRICS_DELAY_MS) -> None:
        super().__init__(parent)
        self._job = DebouncedJob(_LiveMetricsCache(n_samples).evaluate, delay_ms,
                                 "sweepedit-metrics", self)
        self._job.finished.connect(self._on_finished)
        self._job.failed.connect(self.failed)
        self._job.busy.connect(self.busy)
        self.last_result: dict | None = None

    def request(self, current: Callable[[], tuple[Abstraction, Any]]) -> None:
        """Evaluate the abstraction against the shape that `current()` returns once edits
        pause. It is called then, and the abstraction copied then: a drag's moves copy
        nothing."""

        def payload() -> tuple[Abstraction, Any]:
            abstraction, shape = current()
            return abstraction.copy(), shape

        self._job.request(payload)

    def cancel(self) -> None:
        """Forget pending requests; a running one finishes but is not reported."""
        self._job.cancel()

    @property
    def running(self) -> bool:
        return self._job.running

    def _on_finished(self, result: dict) -> None:
        self.last_result = result
        self.updated.emit(result)

    def shutdown(self, wait_ms: int = 5000) -> None:
        """Stop the thread (at exit); waits for a running evaluation."""
        self._job.shutdown(wait_ms)
