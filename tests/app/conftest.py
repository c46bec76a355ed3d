"""Fixtures for the app tests: a real MainWindow (under Xvfb) that never opens modal
dialogs, small generated shapes and parameter files."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from sweepedit.geometry.model import Abstraction, SweepPrimitive, palette_color

HAVE_DISPLAY = bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))
if not HAVE_DISPLAY:
    # Without a display Qt would abort the whole session when pytest-qt makes its
    # QApplication; the offscreen platform serves the tests that need no window, and
    # the window tests skip.
    os.environ.setdefault("QT_QPA_PLATFORM", "offscreen")


@pytest.fixture
def small_files(tmp_path: Path) -> dict[str, Path]:
    """A box mesh (.obj), a two-primitive parameter file (.json) inside it, and broken
    files of several kinds."""
    import trimesh

    from sweepedit.io.params import write_abstraction

    box = trimesh.creation.box(extents=(0.6, 0.3, 0.3))
    obj = tmp_path / "box.obj"
    box.export(obj)
    abstraction = Abstraction([
        # In the normalised frame the box spans [-0.5, 0.5] x [-0.25, 0.25]^2.
        SweepPrimitive(control_points=[[-0.45, 0, 0], [0, 0.02, 0], [0.45, 0, 0]], a=0.22,
                       b=0.22, degree=4.0, name="bar", color=palette_color(0)),
        SweepPrimitive(control_points=[[0, -0.2, 0], [0, 0, 0.01], [0, 0.2, 0]], a=0.15,
                       b=0.15, name="cross", color=palette_color(1)),
    ])
    params = tmp_path / "box.json"
    write_abstraction(abstraction, params)
    broken_json = tmp_path / "broken.json"
    broken_json.write_text('{"format": "sweepedit.abstraction", "version": 1, "primitives": [')
    broken_stl = tmp_path / "broken.stl"
    broken_stl.write_bytes(b"solid nothing\n facet normal 0 0\n garbage\n")
    broken_txt = tmp_path / "broken.txt"
    broken_txt.write_text("1 2 3 4 5 6 7 8 9 nan 0.1 2 0 0\n")
    return {"obj": obj, "json": params, "broken_json": broken_json, "broken_stl": broken_stl,
            "broken_txt": broken_txt}


@pytest.fixture
def window(qtbot, tmp_path: Path):
    """A shown MainWindow whose errors and questions are recorded instead of shown."""
    if not HAVE_DISPLAY:
        pytest.skip("needs a display (run under xvfb-run)")
    from PySide6.QtCore import QSettings

    from sweepedit.app.window import MainWindow

    settings = QSettings(str(tmp_path / "settings.ini"), QSettings.Format.IniFormat)
    # Recovery files go to the test's folder, never the user's data folder.
    w = MainWindow(settings=settings, recovery_dir=tmp_path / "recovery")
    w.errors = []  # type: ignore[attr-defined]
    w.doc.on_view_error = None  # a view that fails to follow an edit fails the test
    w.answers = []  # type: ignore[attr-defined]  # queued answers to ask_save_changes
    w.report_error = lambda title, message: w.errors.append((title, message))  # type: ignore[method-assign]
    w.ask_save_changes = lambda: w.answers.pop(0) if w.answers else "discard"  # type: ignore[method-assign]
    w.resize(1280, 800)
    w.show()
    qtbot.waitExposed(w)
    yield w
    w.doc.set_dirty(False)
    w.close()
