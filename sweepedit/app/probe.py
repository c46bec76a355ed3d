"""Measure the first fit of a session as a user meets it, in a real window:

    python -m sweepedit.app.probe SHAPE [--time-limit S] [--primitives K] [--method M]

(under Xvfb on a headless machine). Run it in a fresh process, so that torch is not yet
imported: the window is made, the shape opened, the window shown and Start clicked at
once, while the fitting code is still loading in the background (--preloaded: once it
has loaded). A 10 ms QTimer records the largest gap between its ticks from the mouse
press until the fit's result has been applied (a stall of the GUI thread shows as a
gap); hooks on the scene record when the first complete abstraction is shown and when
its frame has been rendered. Prints one JSON object (see `measure_first_fit`). Used by
the app tests and benchmarks/bench_app.py.
"""

from __future__ import annotations

import argparse
import itertools
import json
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

TICK_MS = 10
CLICK_HOLD_MS = 80  # how long the mouse button stays down in a click


def measure_first_fit(shape_path: str | Path, time_limit: float | None = 3.0,
                      primitives: int = 8, method: str = "direct", after_s: float = 0.5,
                      timeout_s: float = 120.0, preloaded: bool = False) -> dict[str, Any]:
    """Open `shape_path`, show the window, click Start at once (`preloaded`: once the
    fitting code has been loaded in the background) and run until the fit's result is
    applied and `after_s` more. Returns, with times in seconds from the click (the
    button's release, when the fit starts):

    max_gap_ms, max_gap_at_s: the longest event-loop stall from the mouse press on, and
        when it ended; gaps_over_50ms: [ms, at] of every gap over 50 ms;
    loaded_s: the fitting code at hand in the fit thread (its import, unless preloaded);
    first_abstraction_s: the first preview put into the scene; first_frame_s: its frame
        rendered; fit_done_s: the result applied;
    primitives: in the document after the fit;
    max_preview_ms, max_render_ms: the longest preview update and render (GUI thread);
    torch_at_launch: whether torch had been imported before the window was made;
    fit_api_ready_at_start: whether the fitting code had loaded when Start was pressed;
    errors: the errors the window reported; timed_out: the probe's own timeout ran out.
    """
    from PySide6.QtCore import QEventLoop, QSettings, Qt, QTimer
    from PySide6.QtTest import QTest
    from PySide6.QtWidgets import QApplication

    app = QApplication.instance() or QApplication(sys.argv[:1])
    from sweepedit.app import worker
    from sweepedit.app.window import MainWindow

    torch_at_launch = "torch" in sys.modules
    tmp = tempfile.TemporaryDirectory()  # the window's settings: not the user's
    settings = QSettings(str(Path(tmp.name) / "settings.ini"), QSettings.Format.IniFormat)
    window = MainWindow(settings=settings)
    errors: list[str] = []
    window.report_error = lambda title, message: errors.append(f"{title}: {message}")  # type: ignore[method-assign]
    window.ask_save_changes = lambda: "discard"  # type: ignore[method-assign]
    window.resize(1280, 800)
    if not window.open_shape(shape_path):
        window.close()
        tmp.cleanup()
        return {"errors": errors}
    panel = window.fit_panel
    panel.time_limit.setValue(time_limit or 0.0)
    panel.primitives.setValue(primitives)
    panel.method.setCurrentIndex(panel.method.findData(method))

    marks: dict[str, float] = {}
    preview_s: list[float] = []  # GUI-thread time of each preview update
    render_s: list[float] = []  # and of each render
    show_preview = window.scene.show_preview

    def recording_show_preview(prims: Any) -> None:
        started = time.perf_counter()
        show_preview(prims)
        marks.setdefault("first_abstraction", time.perf_counter())
        thread = window.fit_control.thread
        if thread is not None and thread.loaded_at is not None:
            marks.setdefault("loaded", thread.loaded_at)
        preview_s.append(time.perf_counter() - started)

    window.scene.show_preview = recording_show_preview  # type: ignore[method-assign]

    def render_started(*_args: Any) -> None:
        marks["render"] = time.perf_counter()

    def rendered(*_args: Any) -> None:
        now = time.perf_counter()
        if "render" in marks:
            render_s.append(now - marks.pop("render"))
        if "first_abstraction" in marks:
            marks.setdefault("first_frame", now)

    window.plotter.render_window.AddObserver("StartEvent", render_started)
    window.plotter.render_window.AddObserver("EndEvent", rendered)

    window.show()
    _wait(timeout_s, lambda: window.windowHandle() is not None
          and window.windowHandle().isExposed())
    if preloaded:  # Start pressed once the fitting code is in (not the first fit's case)
        _wait(timeout_s, worker.fit_api_ready)
        _wait(0.1)
    ticks: list[float] = []
    loop = QEventLoop()
    deadline = time.perf_counter() + timeout_s

    def tick() -> None:
        now = time.perf_counter()
        ticks.append(now)
        if "done" not in marks and "first_frame" in marks and not window.fitting:
            marks["done"] = now
        if now > deadline or ("done" in marks and now - marks["done"] >= after_s):
            loop.quit()

    timer = QTimer()
    timer.setTimerType(Qt.TimerType.PreciseTimer)
    timer.setInterval(TICK_MS)
    timer.timeout.connect(tick)
    timer.start()
    api_ready = worker.fit_api_ready()
    pressed = time.perf_counter()
    ticks.append(pressed)
    # Pressed and released like a person clicks, with the button held a moment in
    # between (QTest.mouseClick would send both at once, adding the two synchronous
    # repaints of the button, ~30 ms each on software GL, into one block).
    QTest.mousePress(panel.start_button, Qt.MouseButton.LeftButton)
    _wait(CLICK_HOLD_MS / 1000)
    clicked = time.perf_counter()  # the button acts on release: times count from here
    QTest.mouseRelease(panel.start_button, Qt.MouseButton.LeftButton)
    loop.exec()
    timer.stop()
    gaps = [(b - a, b - clicked) for a, b in itertools.pairwise(ticks)]
    longest = max(gaps, default=(0.0, 0.0))
    result = {
        "shape": str(shape_path),
        "max_gap_ms": round(longest[0] * 1e3, 1),
        "max_gap_at_s": round(longest[1], 3),
        "gaps_over_50ms": [[round(g * 1e3, 1), round(at, 3)] for g, at in gaps if g > 0.05],
        "loaded_s": _since(marks, "loaded", clicked),
        "first_abstraction_s": _since(marks, "first_abstraction", clicked),
        "first_frame_s": _since(marks, "first_frame", clicked),
        "fit_done_s": _since(marks, "done", clicked),
        "primitives": len(window.doc),
        "max_preview_ms": round(max(preview_s, default=0.0) * 1e3, 1),
        "max_render_ms": round(max(render_s, default=0.0) * 1e3, 1),
        "torch_at_launch": torch_at_launch,
        "fit_api_ready_at_start": api_ready,
        "errors": errors,
        "timed_out": "done" not in marks,
    }
    window.doc.set_dirty(False)
    window.close()
    app.processEvents()
    tmp.cleanup()
    return result


def _wait(seconds: float, until: Callable[[], bool] | None = None) -> None:
    """Run the event loop for `seconds` or until `until()`. Not QTest.qWait: PySide6 keeps
    the GIL through it, which would starve the threads this measures."""
    from PySide6.QtCore import QEventLoop, QTimer

    end = time.perf_counter() + seconds

    def over() -> bool:
        return time.perf_counter() >= end or (until is not None and until())

    loop = QEventLoop()
    poll = QTimer()
    poll.setInterval(5)
    poll.timeout.connect(lambda: over() and loop.quit())
    poll.start()
    if not over():
        loop.exec()
    poll.stop()


def _since(marks: dict[str, float], key: str, start: float) -> float | None:
    return round(marks[key] - start, 3) if key in marks else None


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("shape")
    parser.add_argument("--time-limit", type=float, default=3.0,
                        help="the fit's time limit in seconds (0: none)")
    parser.add_argument("--primitives", type=int, default=8)
    parser.add_argument("--method", choices=("direct", "network"), default="direct")
    parser.add_argument("--after", type=float, default=0.5,
                        help="seconds to keep measuring after the fit's result is applied")
    parser.add_argument("--timeout", type=float, default=120.0)
    parser.add_argument("--preloaded", action="store_true",
                        help="press Start only once the fitting code has been loaded")
    args = parser.parse_args(argv)
    result = measure_first_fit(args.shape, args.time_limit or None, args.primitives,
                               args.method, args.after, args.timeout, args.preloaded)
    print(json.dumps(result))
    return 0 if result.get("first_frame_s") is not None and not result["errors"] else 1


if __name__ == "__main__":
    sys.exit(main())
