"""The app's file handling on its own: FileControl with a Document and a recorder for the
user's questions, no window and no 3D view (the window's own file tests are in
test_app.py)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from sweepedit.app.autosave import Autosaver
from sweepedit.app.commands import CommandStack, SetFields
from sweepedit.app.document import Document
from sweepedit.app.file_control import MAX_RECENT, FileControl, with_suffix
from sweepedit.io.params import read_abstraction


class Prompts:
    """Records what the user would be told; answers questions from queues."""

    def __init__(self) -> None:
        self.errors: list[tuple[str, str]] = []
        self.status: list[str] = []
        self.save_answers: list[str] = []
        self.keep_answers: list[str] = []

    def report_error(self, title: str, message: str) -> None:
        self.errors.append((title, message))

    def ask_save_changes(self) -> str:
        return self.save_answers.pop(0)

    def ask_keep_primitives(self, shape_name: str) -> str:
        return self.keep_answers.pop(0)

    def ask_recover(self, recovery: object) -> bool:
        return False

    def show_status(self, message: str, timeout_ms: int = 6000) -> None:
        self.status.append(message)


@pytest.fixture
def files(qtbot, tmp_path: Path):
    from PySide6.QtCore import QSettings

    doc = Document()
    stack = CommandStack(doc)
    autosave = Autosaver(doc, tmp_path / "recovery")
    settings = QSettings(str(tmp_path / "settings.ini"), QSettings.Format.IniFormat)
    control = FileControl(doc, stack, autosave, settings, prompts=Prompts(),
                          busy=lambda: control.fitting, reset_view=lambda: views.append(1))
    control.fitting = False  # type: ignore[attr-defined]
    views: list[int] = []
    control.views = views  # type: ignore[attr-defined]
    yield control
    autosave.shutdown()


def _edit(control: FileControl) -> None:
    """One undoable edit: the first primitive's a, +0.01."""
    a = control.doc.abstraction.primitives[0].a
    control.stack.push(SetFields(0, {"a": a + 0.01}))


def test_open_params_reads_the_file_and_frames_it(files, small_files) -> None:
    assert files.open_params(small_files["json"])
    expected = read_abstraction(small_files["json"])
    assert [p.name for p in files.doc.abstraction.primitives] == ["bar", "cross"]
    np.testing.assert_array_equal(files.doc.abstraction.primitives[0].control_points,
                                  expected.primitives[0].control_points)
    assert files.doc.path == small_files["json"] and not files.doc.dirty
    assert files.views, "the view was not framed on the opened primitives"
    assert files.recent_files() == [str(small_files["json"].resolve())]


@pytest.mark.parametrize("kind", ["broken_json", "broken_txt"])
def test_a_broken_parameter_file_is_reported_by_name_and_changes_nothing(
        files, small_files, kind: str) -> None:
    assert files.open_params(small_files["json"])
    before = files.doc.abstraction.primitives[0].control_points.copy()
    assert not files.open_params(small_files[kind])
    (title, message), = files.prompts.errors
    assert title == "Cannot open parameters" and small_files[kind].name in message
    assert "Traceback" not in message
    np.testing.assert_array_equal(files.doc.abstraction.primitives[0].control_points, before)
    assert files.doc.path == small_files["json"]
    assert str(small_files[kind].resolve()) not in files.recent_files()


def test_unsaved_edits_are_asked_about_before_they_are_replaced(files, small_files,
                                                                tmp_path: Path) -> None:
    assert files.open_params(small_files["json"])
    _edit(files)
    edited_a = files.doc.abstraction.primitives[0].a
    files.prompts.save_answers = ["cancel"]
    assert not files.open_params(small_files["json"])
    assert files.doc.abstraction.primitives[0].a == edited_a and files.doc.dirty
    files.prompts.save_answers = ["discard"]
    assert files.open_params(small_files["json"])
    assert files.doc.abstraction.primitives[0].a == pytest.approx(edited_a - 0.01)
    assert not files.doc.dirty
    # "save" writes the edit to the document's file before New empties the document.
    _edit(files)
    files.prompts.save_answers = ["save"]
    assert files.new_document()
    assert len(files.doc) == 0 and files.doc.path is None and files.doc.shape is None
    assert read_abstraction(small_files["json"]).primitives[0].a == pytest.approx(edited_a)


def test_a_failed_save_says_why_in_the_users_words_and_keeps_the_edit(files, small_files,
                                                                      tmp_path: Path) -> None:
    assert files.open_params(small_files["json"])
    _edit(files)
    target = tmp_path / "no such folder" / "out.json"
    assert not files.save_to(target)
    (title, message), = files.prompts.errors
    assert title == "Cannot save"
    assert message == (f"Could not save out.json: the folder {target.parent} does not exist. "
                       "Choose another folder.")
    assert files.doc.dirty and files.doc.path == small_files["json"]
    assert files.save_to(tmp_path / "out.json")
    assert not files.doc.dirty and files.doc.path == tmp_path / "out.json"
    saved = read_abstraction(tmp_path / "out.json")
    assert saved.primitives[0].a == files.doc.abstraction.primitives[0].a


def test_nothing_replaces_the_document_while_a_fit_runs(files, small_files) -> None:
    files.fitting = True
    assert not files.open_params(small_files["json"])
    assert not files.open_path(small_files["obj"])
    assert not files.new_document()
    assert len(files.doc) == 0 and files.doc.shape is None and files.prompts.errors == []


def test_recent_files_newest_first_without_repeats_and_at_most_max(files,
                                                                    tmp_path: Path) -> None:
    paths = [tmp_path / f"f{i}.json" for i in range(MAX_RECENT + 3)]
    for p in paths:
        files.add_recent(p)
    files.add_recent(paths[4])
    recent = files.recent_files()
    assert recent[0] == str(paths[4].resolve())
    assert len(recent) == MAX_RECENT == len(set(recent))
    assert recent[1:] == [str(p.resolve()) for p in reversed(paths)
                          if p != paths[4]][:MAX_RECENT - 1]
    assert files.last_dir() == str(tmp_path.resolve())


def test_fill_recent_menu_opens_the_chosen_file(files, small_files) -> None:
    from PySide6.QtWidgets import QMenu

    files.add_recent(small_files["json"])
    menu = QMenu()
    files.fill_recent_menu(menu)
    entry = menu.actions()[0]
    assert entry.text() == str(small_files["json"].resolve())
    entry.trigger()
    assert [p.name for p in files.doc.abstraction.primitives] == ["bar", "cross"]
    menu.actions()[-1].trigger()  # "Clear list"
    assert files.recent_files() == []
    files.fill_recent_menu(menu)
    assert [a.text() for a in menu.actions()] == ["(none)"]


@pytest.mark.parametrize(("typed", "suffixes", "expected"), [
    ("a", (".json",), "a.json"),
    ("a.JSON", (".json",), "a.JSON"),
    ("a.txt", (".json",), "a.txt.json"),
    ("part.stp", (".step", ".stp"), "part.stp"),
    ("part", (".step", ".stp"), "part.step"),
])
def test_save_dialog_names_get_the_suffix_once(typed: str, suffixes: tuple[str, ...],
                                               expected: str) -> None:
    assert with_suffix(typed, suffixes) == expected
