"""Autosave and recovery (issue 18, "The app never loses work"): the recovery file, its
throttle, the offer at start, declining, stale files, and an editor killed with SIGKILL
in a subprocess whose edits a second editor recovers exactly."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from sweepedit.app.commands import CommandStack, move_control_point, set_field
from sweepedit.app.document import Document
from sweepedit.geometry.model import Abstraction, SweepPrimitive, palette_color

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
DRIVER = HERE / "recovery_driver.py"


def _abstraction(n: int = 3) -> Abstraction:
    rng = np.random.default_rng(3)
    return Abstraction([SweepPrimitive(control_points=rng.uniform(-0.3, 0.3, (3, 3)),
                                       a=rng.uniform(0.03, 0.1), b=rng.uniform(0.03, 0.1),
                                       degree=rng.uniform(1, 4), scaling=(0.1, -0.05),
                                       color=palette_color(i)) for i in range(n)])


def _same(a: Abstraction, b: Abstraction) -> None:
    """Bit-identical parameters, frame, source and fit record."""
    from sweepedit.io.params import abstraction_to_json

    assert json.dumps(abstraction_to_json(a), sort_keys=True) == json.dumps(
        abstraction_to_json(b), sort_keys=True)
    for p, q in zip(a.primitives, b.primitives, strict=True):
        assert p.control_points.tobytes() == q.control_points.tobytes()


def test_autosave_writes_the_exact_document_at_most_once_per_interval(qtbot,
                                                                     tmp_path: Path) -> None:
    from sweepedit.app.autosave import AUTOSAVE_INTERVAL_MS, Autosaver, read_recovery

    assert AUTOSAVE_INTERVAL_MS <= 3000  # "at most every few seconds"
    doc = Document(_abstraction())
    doc.set_path(tmp_path / "cactus.json")
    stack = CommandStack(doc)
    saver = Autosaver(doc, tmp_path / "recovery", interval_ms=300)
    assert not saver.path.exists()
    rng = np.random.default_rng(0)
    t0 = time.perf_counter()
    # A drag of 1.2 s: one edit every 20 ms, all in one gesture.
    while time.perf_counter() - t0 < 1.2:
        stack.push(move_control_point(doc, 1, 2, rng.uniform(-0.4, 0.4, 3)))
        qtbot.wait(20)
    stack.close_merge()
    elapsed = time.perf_counter() - t0
    qtbot.waitUntil(lambda: not saver.pending, timeout=5000)
    # Throttled: written during the drag (not only after it), never more than once a period.
    assert 3 <= saver.written <= elapsed / 0.3 + 2
    recovery = read_recovery(saver.path)
    _same(recovery.abstraction, doc.abstraction)
    assert recovery.document_path == tmp_path / "cactus.json"
    assert recovery.question().startswith("Recover the unsaved edits of cactus.json from ")
    assert recovery.question()[-6:-1] == time.strftime("%H:%M", time.localtime(recovery.saved_at))
    # Undone back to the saved state: nothing to lose, no file.
    stack.undo()
    qtbot.waitUntil(lambda: not saver.path.exists(), timeout=5000)
    saver.shutdown()


@pytest.mark.gui
def test_save_and_clean_exit_remove_the_recovery_file(qtbot, window, small_files) -> None:
    window.open_path(small_files["obj"])
    window.open_path(small_files["json"])
    window.stack.push(set_field(window.doc, 0, "a", 0.1, merge=False))
    assert window.autosave.write_now() and window.autosave.path.is_file()
    assert window.save_to(small_files["json"])
    assert not window.autosave.path.exists()
    window.stack.push(set_field(window.doc, 0, "a", 0.12, merge=False))
    window.autosave.write_now()
    assert window.autosave.path.is_file()
    window.answers.append("discard")
    window.close()
    assert not window.autosave.path.exists()
    assert list(window.autosave.directory.iterdir()) == []  # the lock is gone too


def _crash(window, edit_after=None) -> Path:
    """What a killed editor leaves, in this process: its last autosave, and no live lock
    (the lock of a dead process is stale to Qt). `edit_after` runs after that autosave."""
    saver = window.autosave
    assert saver.write_now() and saver.path.is_file()
    left = saver.path.read_bytes()
    if edit_after is not None:
        edit_after()
    window.doc.set_dirty(False)
    window.close()  # removes file and lock, as a clean exit does ...
    saver.path.write_bytes(left)  # ... so the file is put back as the crash left it
    return saver.path


@pytest.mark.gui
def test_recovery_gives_the_last_autosaved_state_and_declining_keeps_it(qtbot, tmp_path: Path,
                                                                       small_files) -> None:
    from PySide6.QtCore import QSettings

    from sweepedit.app.window import MainWindow

    recovery_dir = tmp_path / "recovery"
    windows: list[MainWindow] = []

    def make() -> MainWindow:
        w = MainWindow(settings=QSettings(str(tmp_path / "s.ini"), QSettings.Format.IniFormat),
                       recovery_dir=recovery_dir, preload_fit=False)
        w.report_error = lambda title, message: pytest.fail(f"{title}: {message}")
        w.show()
        qtbot.waitExposed(w)
        windows.append(w)
        return w

    try:
        _recovery_story(make, small_files)
    finally:
        for w in windows:  # closed even when an assertion failed (threads stop)
            if w.isVisible():
                w.doc.set_dirty(False)
                w.close()


def _recovery_story(make, small_files) -> None:
    first = make()
    first.open_path(small_files["obj"])
    first.open_path(small_files["json"])
    saved_state = first.doc.abstraction.copy()
    first.stack.push(move_control_point(first.doc, 0, 1, [0.0123456789, -0.1, 0.05]))
    first.stack.push(set_field(first.doc, 1, "name", "crossbar", merge=False))
    first.stack.push(set_field(first.doc, 1, "degree", 3.3, merge=False))
    left = _crash(first, lambda: first.stack.push(set_field(first.doc, 1, "a", 0.05,
                                                             merge=False)))
    assert left.is_file()

    # Declined: the file stays, also across a restart, until that session autosaves.
    second = make()
    questions = []
    second.ask_recover = lambda r: questions.append(r.question()) or False
    assert not second.offer_recovery()
    assert questions[0].startswith("Recover the unsaved edits of box.json from ")
    assert left.is_file() and len(second.doc) == 0
    second.open_path(small_files["obj"])
    second.open_path(small_files["json"])
    second.stack.push(set_field(second.doc, 0, "a", 0.2, merge=False))
    assert second.autosave.write_now()
    assert not left.exists()  # replaced by this session's own file
    own = _crash(second)

    # Recovered: exactly the last autosaved state, one undo step above the saved file.
    third = make()
    assert third.offer_recovery(True)
    assert third.doc.path == small_files["json"] and third.doc.shape_path == small_files["obj"]
    assert third.doc.dirty and third.stack.undo_text == "Recover unsaved edits"
    assert not own.exists() and third.autosave.path.is_file()
    expected = saved_state.copy()
    expected.primitives[0].a = 0.2
    _same(third.doc.abstraction, expected)
    third.stack.undo()
    _same(third.doc.abstraction, saved_state)
    third.doc.set_dirty(False)
    third.close()


@pytest.mark.gui
def test_a_recovery_file_older_than_its_document_is_not_offered(qtbot, window,
                                                                small_files) -> None:
    from sweepedit.app.autosave import Autosaver, read_recovery

    window.open_path(small_files["json"])
    window.stack.push(set_field(window.doc, 0, "a", 0.1, merge=False))
    directory = window.autosave.directory
    left = _crash(window)
    time.sleep(0.05)
    assert len(Autosaver(Document(), directory).orphans()) == 1  # offered while newer
    os.utime(small_files["json"])  # saved after the last autosave (by another editor)
    assert read_recovery(left).saved_at < small_files["json"].stat().st_mtime
    other = Autosaver(Document(), directory)
    assert other.orphans() == []
    assert not left.exists()
    other.shutdown()


def _start(args: list[str], env: dict[str, str]) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, str(DRIVER), *args], stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True, env=env, cwd=ROOT)


def _read_until(proc: subprocess.Popen, word: str, timeout: float = 120.0) -> list[str]:
    """Lines of `proc` up to the first that starts with `word` (split)."""
    end = time.monotonic() + timeout
    for line in proc.stdout:  # type: ignore[union-attr]
        parts = line.split()
        if parts and parts[0] == word:
            return parts
        if time.monotonic() > end:
            break
    proc.kill()
    raise AssertionError(f"no '{word}' from the driver (exit {proc.wait()})")


@pytest.mark.gui
@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="SIGKILL and Xvfb")
def test_an_editor_killed_with_sigkill_is_recovered_exactly(tmp_path: Path,
                                                            small_files) -> None:
    from sweepedit.io.params import read_abstraction

    sys.path.insert(0, str(HERE))
    try:
        from recovery_driver import apply_edits, state_hash
    finally:
        sys.path.remove(str(HERE))
    env = dict(os.environ, XDG_DATA_HOME=str(tmp_path / "data"),
               XDG_CONFIG_HOME=str(tmp_path / "config"), OMP_NUM_THREADS="1",
               PYTHONPATH=str(ROOT))
    seed, edits = 11, 25
    editor = _start(["edit", str(small_files["obj"]), str(small_files["json"]), str(seed),
                     str(edits)], env)
    ready = _read_until(editor, "ready")
    later = _read_until(editor, "edited")
    editor.send_signal(signal.SIGKILL)
    editor.wait(10)
    recovery_file = Path(ready[2])
    assert recovery_file.is_file() and str(recovery_file).startswith(str(tmp_path / "data"))

    assert later[1] != ready[1]  # the edit after the last autosave, never written

    out = tmp_path / "recovered.json"
    recoverer = _start(["recover", str(out)], env)
    line = _read_until(recoverer, "recovered")
    assert recoverer.wait(60) == 0
    assert line[1] == ready[1], line
    assert f"path={small_files['json']}" in line and f"shape={small_files['obj']}" in line
    assert "dirty=True" in line
    # The truth, independently: the same seeded edits replayed on the saved file give
    # the recovered primitives to the bit.
    back = read_abstraction(out)
    assert state_hash(back) == ready[1]
    replay = Document(read_abstraction(small_files["json"]))
    apply_edits(replay, CommandStack(replay), np.random.default_rng(seed), edits)
    assert len(back) == len(replay)
    for p, q in zip(back.primitives, replay.primitives, strict=True):
        assert p.control_points.tobytes() == q.control_points.tobytes()
        assert (p.a, p.b, p.degree, p.scaling, p.name) == (q.a, q.b, q.degree, q.scaling,
                                                           q.name)
    assert back.source == {"path": str(small_files["obj"])}
    assert not recovery_file.exists()


def test_an_autosave_that_cannot_write_says_so_once(qtbot, tmp_path: Path) -> None:
    from sweepedit.app.autosave import Autosaver

    blocker = tmp_path / "not-a-folder"
    blocker.write_text("a file where the data folder should be")
    messages: list[str] = []
    doc = Document(_abstraction())
    stack = CommandStack(doc)
    saver = Autosaver(doc, blocker / "recovery", report=messages.append)
    for a in (0.05, 0.06):
        stack.push(set_field(doc, 0, "a", a, merge=False))
        assert not saver.write_now()
    assert len(messages) == 1 and messages[0].startswith("Autosave failed: cannot write ")
    assert "save your work" in messages[0]
    saver.shutdown()
