"""File > Export > STEP in the app: runs off the GUI thread, can be cancelled, and what it
writes reads back with OpenCascade as one named solid per visible primitive."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

pytestmark = pytest.mark.skipif(importlib.util.find_spec("OCP") is None,
                                reason="the optional 'cad' extra (OpenCascade) is not installed")


def test_export_step_in_the_background_and_cancel(window, qtbot, small_files,
                                                  tmp_path: Path) -> None:
    from sweepedit.io.step import read_step

    assert window.open_path(small_files["json"])
    assert window.act_export_step.isEnabled()
    out = tmp_path / "box.step"
    assert window.export_step(out)
    qtbot.waitUntil(lambda: window.files.step_job.isFinished(), timeout=60_000)
    qtbot.waitUntil(lambda: "Exported 2 solid(s)" in window.statusBar().currentMessage(),
                    timeout=5_000)
    assert window.errors == []
    assert [s.name for s in read_step(out)] == ["bar", "cross"]
    # Cancelled at once: nothing is written, and no error is shown.
    cancelled = tmp_path / "cancelled.step"
    assert window.export_step(cancelled, union=True)
    window.files.step_job.cancel()
    qtbot.waitUntil(lambda: window.files.step_job.isFinished(), timeout=60_000)
    qtbot.waitUntil(lambda: "cancelled" in window.statusBar().currentMessage(), timeout=5_000)
    assert not cancelled.exists() and window.errors == []
