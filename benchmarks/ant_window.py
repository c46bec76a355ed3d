"""The window the app benchmarks measure: 1600 x 1000, the first 8 primitives of ant.txt
over ant.ply (../shared), the first selected, dialogs answered without a person.

Imported by bench_app.py, bench_edit.py and bench_gui_gil.py (run from the repository
root, so this folder is on sys.path), so that their figures are of the same scene.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

SHARED = Path(__file__).resolve().parents[2] / "shared"
SHAPE = SHARED / "shapes" / "ant.ply"
PARAMS = SHARED / "sweepnet_params" / "ant.txt"
N_PRIMITIVES = 8


def spin(app: Any, seconds: float, until: Callable[[], bool] | None = None,
         step: float = 0.002) -> None:
    """Process Qt events for `seconds` (or until `until()`), sleeping `step` between."""
    end = time.perf_counter() + seconds
    while time.perf_counter() < end:
        app.processEvents()
        if until is not None and until():
            return
        time.sleep(step)


def ant_window(app: Any, settings_name: str, preload_fit: bool = True) -> tuple[Any, Any]:
    """(window, shape): a shown MainWindow with the ant scene, settings in a temporary
    INI file named `settings_name`; errors are printed, questions answered "discard"."""
    import tempfile

    from PySide6.QtCore import QSettings

    from sweepedit.app.window import MainWindow
    from sweepedit.geometry.model import Abstraction
    from sweepedit.io.params import read_abstraction
    from sweepedit.io.shapes import load_shape

    settings = QSettings(str(Path(tempfile.gettempdir()) / settings_name),
                         QSettings.Format.IniFormat)
    w = MainWindow(settings=settings, preload_fit=preload_fit)
    w.report_error = lambda title, message: print(f"error: {title}: {message}")
    w.ask_save_changes = lambda: "discard"
    w.ask_keep_primitives = lambda _name: "discard"  # opening another shape over them
    w.resize(1600, 1000)
    w.show()
    spin(app, 0.5)
    shape = load_shape(SHAPE)
    w.doc.set_shape(shape, SHAPE)
    primitives = read_abstraction(PARAMS).primitives[:N_PRIMITIVES]
    w.doc.set_abstraction(Abstraction(primitives, normalization=shape.normalization), PARAMS)
    w.stack.clear()
    w.scene.reset_camera()
    w.doc.select(0)
    return w, shape


def close_window(app: Any, window: Any) -> None:
    """Close a benchmark's window without the unsaved-edits question, and let Qt finish."""
    window.doc.set_dirty(False)
    window.close()
    app.processEvents()
