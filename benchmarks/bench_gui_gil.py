"""The GUI thread beside worker threads that run Python (the GIL).

A window with 8 primitives of ant.txt over ant.ply; timed on the GUI thread, alone and
beside one and two threads that run pure Python (as torch's import and the Python side of
a fit do): a control point dragged and the frame rendered, and a fit preview of all 8
primitives shown and rendered. Once at Python's default switch interval (5 ms) and once
at the app's (sweepedit.app.worker.GUI_SWITCH_INTERVAL_S).

    xvfb-run -a -s "-screen 0 1600x1000x24" .venv/bin/python benchmarks/bench_gui_gil.py

Run it alone: other processes on the two cores change what it measures.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import threading
import time
from collections.abc import Callable

import numpy as np
from ant_window import PARAMS, SHAPE, ant_window, close_window

PYTHON_DEFAULT_S = 0.005


class PythonBurner:
    """`count` threads running pure Python until stopped (holding the GIL but for the
    switch interval)."""

    def __init__(self, count: int) -> None:
        self.stop = threading.Event()
        self.threads = [threading.Thread(target=self._burn, daemon=True) for _ in range(count)]

    def _burn(self) -> None:
        while not self.stop.is_set():
            sum(i * i for i in range(200))

    def __enter__(self) -> PythonBurner:
        for thread in self.threads:
            thread.start()
        time.sleep(0.1)
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop.set()
        for thread in self.threads:
            thread.join()


def median_ms(action: Callable[[int], None], repeats: int) -> float:
    times = []
    for k in range(repeats):
        t0 = time.perf_counter()
        action(k)
        times.append(time.perf_counter() - t0)
    return statistics.median(times) * 1e3


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--repeats", type=int, default=15)
    args = parser.parse_args()
    if not SHAPE.is_file() or not PARAMS.is_file():
        print(f"needs {SHAPE} and {PARAMS}")
        return 1

    from PySide6.QtWidgets import QApplication

    app = QApplication.instance() or QApplication(sys.argv[:1])
    from sweepedit.app.worker import GUI_SWITCH_INTERVAL_S

    window, _ = ant_window(app, "sweepedit-bench-gil.ini", preload_fit=False)
    for _ in range(50):
        app.processEvents()
        time.sleep(0.01)
    scene = window.scene
    start = window.doc.primitive(0).control_points[1].copy()

    def drag(k: int) -> None:
        scene.drag_control_point(0, 1, start + 0.01 * np.sin(k))
        scene.render_now()

    def preview(k: int) -> None:
        shown = [p.copy() for p in window.doc.primitives]
        for p in shown:
            p.control_points = p.control_points + 0.001 * np.sin(k)
        scene.show_preview(shown)
        scene.render_now()

    size = window.plotter.render_window.GetSize()
    print(f"view {size[0]}x{size[1]} px, {len(window.doc)} primitives, median of "
          f"{args.repeats} (ms, on the GUI thread)")
    print(f"{'switch interval':>16} {'Python threads':>15} {'drag + render':>14} "
          f"{'preview + render':>17}")
    for interval in (PYTHON_DEFAULT_S, GUI_SWITCH_INTERVAL_S):
        sys.setswitchinterval(interval)
        for burners in (0, 1, 2):
            with PythonBurner(burners):
                dragged = median_ms(drag, args.repeats)
                previewed = median_ms(preview, max(3, args.repeats // 3))
            print(f"{interval * 1e3:>13.1f} ms {burners:>15} {dragged:>14.1f} {previewed:>17.1f}")
    close_window(app, window)
    return 0


if __name__ == "__main__":
    sys.exit(main())
