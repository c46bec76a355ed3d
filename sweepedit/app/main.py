"""Entry points behind the CLI: `sweepedit [FILE]` and `sweepedit gui FILE --screenshot PNG`."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

from PySide6.QtWidgets import QApplication

from sweepedit.errors import primitive_label

EXAMPLE_NAME = "cactus.off"


def example_path() -> Path | None:
    """The bundled example shape, if it ships with this installation."""
    here = Path(__file__).resolve()
    # The repository's example, else the same file in the packaged benchmark set (what a
    # `pip install` has).
    for candidate in (here.parents[2] / "resources" / "examples" / EXAMPLE_NAME,
                      here.parents[1] / "resources" / "benchmark" / EXAMPLE_NAME):
        if candidate.is_file():
            return candidate
    return None


def has_display() -> bool:
    """Whether Qt can open windows here (an X or Wayland display, or a non-GUI platform
    forced through QT_QPA_PLATFORM)."""
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")
                or os.environ.get("QT_QPA_PLATFORM")) or sys.platform in ("win32", "darwin")


def _application() -> QApplication:
    app = QApplication.instance()
    if app is None:
        app = QApplication(sys.argv[:1])
        app.setApplicationName("SweepEdit")
        app.setOrganizationName("sweepedit")
    return app  # type: ignore[return-value]


def _wait(app: QApplication, seconds: float, until: Callable[[], bool] | None = None) -> None:
    """Spin the event loop for up to `seconds`, or until `until()` is true."""
    end = time.perf_counter() + seconds
    while time.perf_counter() < end:
        app.processEvents()
        if until is not None and until():
            return
        time.sleep(0.01)


RECOVER_ANSWERS = {"ask": None, "yes": True, "no": False}


def run_app(path: str | None = None, recover: str = "ask", also: str | None = None,
            heatmap: bool = False) -> int:
    """Open the editor on `path` (a shape or a parameter file; `also` a second one, the
    parameters for the shape), or on the bundled example when no path is given; `heatmap`
    shows the heat map of the error. Returns the application's exit code. Unsaved edits that an
    editor killed or crashed left behind are offered first (`recover`: "ask", or "yes" /
    "no" to answer without asking); when they are recovered, `path` is not opened."""
    if recover not in RECOVER_ANSWERS:
        raise ValueError(f"recover must be one of {sorted(RECOVER_ANSWERS)}, got {recover!r}")
    if not has_display():
        print("sweepedit: no display to open the editor on (DISPLAY is not set); "
              "use `xvfb-run sweepedit ...` on a headless machine", file=sys.stderr)
        return 2
    app = _application()
    from sweepedit.app.window import MainWindow

    window = MainWindow()
    app.aboutToQuit.connect(window.metrics.shutdown)
    window.show()
    target = Path(path) if path else example_path()

    def start() -> None:
        if window.offer_recovery(RECOVER_ANSWERS[recover]):
            return
        if target is not None:
            if window.open_path(target) and also is not None:
                window.open_path(also)
            if heatmap:
                window.set_heatmap_visible(True)
        else:
            window.show_status("No file given and no bundled example found: "
                               "open a shape with Ctrl+O.")

    # After the event loop starts, so that a dialog has a window to sit on.
    from PySide6.QtCore import QTimer

    QTimer.singleShot(0, start)
    return int(app.exec())


def screenshot(path_in: str, png_out: str, full_window: bool = True,
               size: tuple[int, int] = (1600, 1000), metrics_timeout_s: float = 20.0,
               select: int | None = None, also: str | None = None,
               heatmap: bool = False) -> int:
    """Open `path_in` (and `also`, the parameters for a shape), render, write a PNG of the
    window (or only the 3D view) to `png_out` atomically and quit. `select`: the primitive
    shown selected, with its axis and handles (0-based here; the command line counts from
    1); `heatmap`: the heat map of the error shown (waits for it). Returns 0 on success,
    1 (with a message on stderr) on failure. Without a display it re-runs itself under
    xvfb-run when that is installed."""
    if not has_display():
        return _screenshot_under_xvfb(path_in, png_out, full_window, size, select, also,
                                      heatmap)
    app = _application()
    from sweepedit.app.window import MainWindow

    errors: list[str] = []
    window = MainWindow(preload_fit=False)  # no fit here: torch would only slow the exit
    window.report_error = lambda title, message: errors.append(f"{title}: {message}")  # type: ignore[method-assign]
    window.ask_save_changes = lambda: "discard"  # type: ignore[method-assign]
    window.resize(*size)
    window.show()
    _wait(app, 0.3)
    ok = window.open_path(path_in)
    if ok and also is not None:
        ok = window.open_path(also)
    if ok and heatmap and not window.set_heatmap_visible(True):
        errors.append(f"{path_in}: the heat map needs a target shape (give SHAPE PARAMS)")
        ok = False
    if ok and select is not None:
        if 0 <= select < len(window.doc):
            window.doc.select(select)
        else:
            errors.append(f"{path_in}: cannot select {primitive_label(select)}; the file has "
                          f"{len(window.doc)} (1 to {len(window.doc)})")
            ok = False
    if ok:
        window.scene.reset_camera()
        _wait(app, metrics_timeout_s, until=lambda: not window.metrics.running
              and not window.heatmap.running)
        _wait(app, 0.2)
        ok = window.save_screenshot(png_out, full_window=full_window)
    window.doc.set_dirty(False)
    window.close()
    app.processEvents()
    for message in errors:
        print(message, file=sys.stderr)
    return 0 if ok and not errors else 1


def _screenshot_under_xvfb(path_in: str, png_out: str, full_window: bool,
                           size: tuple[int, int], select: int | None,
                           also: str | None = None, heatmap: bool = False) -> int:
    xvfb = shutil.which("xvfb-run")
    if xvfb is None:
        print("sweepedit: a screenshot needs a display; none is set and xvfb-run is not "
              "installed", file=sys.stderr)
        return 2
    code = ("import sys; from sweepedit.app.main import screenshot; "
            f"sys.exit(screenshot({str(path_in)!r}, {str(png_out)!r}, {full_window!r}, "
            f"{tuple(size)!r}, select={select!r}, also={also!r}, heatmap={heatmap!r}))")
    screen = f"-screen 0 {size[0] + 64}x{size[1] + 64}x24"
    return subprocess.call([xvfb, "-a", "-s", screen, sys.executable, "-c", code])
