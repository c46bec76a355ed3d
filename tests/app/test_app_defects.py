"""Issue 16's defects and File > New / Close / another shape (item 8), each against a real
window under Xvfb with real key, mouse and wheel events, and the Qt-free naming rules."""

from __future__ import annotations

import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from sweepedit.app.commands import (
    AddPrimitive,
    CommandStack,
    DeletePrimitive,
    apply_fit,
    new_primitive,
    set_field,
)
from sweepedit.app.document import Document, unique_name
from sweepedit.errors import InvalidPrimitiveError
from sweepedit.geometry.model import A_RANGE, Abstraction, SweepPrimitive, palette_color


def _primitive(i: int, name: str = "") -> SweepPrimitive:
    x = 0.05 * i
    return SweepPrimitive(control_points=[[x, 0, -0.2], [x, 0.01, 0], [x, 0, 0.2]], a=0.05,
                          b=0.05, name=name, color=palette_color(i))


def _snapshot(doc: Document) -> list[tuple]:
    return [(p.control_points.tobytes(), p.a, p.b, p.degree, p.scaling, p.name, p.color,
             p.visible, p.locked) for p in doc.primitives]


# -- names (Qt-free) -------------------------------------------------------------------------

def test_residual_round_names_become_one_numbering() -> None:
    doc = Document(Abstraction([_primitive(0, "primitive 1")]))
    stack = CommandStack(doc)
    # What a fit with residual rounds returned: each round numbered its own from 1.
    rounds = ["primitive 1", "primitive 2", "primitive 3", "primitive 4", "primitive 1",
              "primitive 2", "primitive 3", "primitive 1"]
    stack.push(apply_fit(doc, [_primitive(i, n) for i, n in enumerate(rounds)]))
    assert [p.name for p in doc.primitives] == [f"primitive {i}" for i in range(1, 9)]


def test_a_txt_counts_from_one_and_add_takes_the_next_free_number(tmp_path: Path) -> None:
    from sweepedit.io.params import read_abstraction, write_official_txt

    path = tmp_path / "five.txt"
    write_official_txt(Abstraction([_primitive(i) for i in range(5)]), path)
    doc = Document()
    doc.set_abstraction(read_abstraction(path), path, frame_known=False)
    stack = CommandStack(doc)
    assert [p.name for p in doc.primitives] == [f"primitive {i}" for i in range(1, 6)]
    stack.push(AddPrimitive(new_primitive(doc)))
    assert doc.primitives[-1].name == "primitive 6"
    # After a delete, Add never repeats a name still in use.
    stack.push(DeletePrimitive(1))  # "primitive 2"
    stack.push(AddPrimitive(new_primitive(doc)))
    names = [p.name for p in doc.primitives]
    assert names[-1] == "primitive 7" and len(set(names)) == len(names)
    # Undo and redo give the same names back.
    stack.undo()
    stack.undo()
    assert [p.name for p in doc.primitives] == [f"primitive {i}" for i in range(1, 7)]


def test_names_stay_unique_after_rename_insert_and_delete() -> None:
    doc = Document(Abstraction([_primitive(0, "bar"), _primitive(1, "cross")]))
    stack = CommandStack(doc)
    stack.push(set_field(doc, 1, "name", "bar", merge=False))
    assert [p.name for p in doc.primitives] == ["bar", "bar 2"]
    stack.push(AddPrimitive(_primitive(2, "bar")))
    assert doc.primitives[-1].name == "bar 3"
    stack.push(DeletePrimitive(0))
    stack.push(AddPrimitive(_primitive(3, "bar 2")))
    names = [p.name for p in doc.primitives]
    assert len(set(names)) == len(names) == 3
    stack.undo()
    stack.undo()
    stack.undo()
    stack.undo()
    assert [p.name for p in doc.primitives] == ["bar", "cross"]
    assert unique_name("cross", {"cross", "cross 7"}) == "cross 8"
    assert unique_name("new", {"cross"}) == "new"


def test_error_messages_count_primitives_like_the_list() -> None:
    doc = Document(Abstraction([_primitive(0), _primitive(1)]))
    assert [p.name for p in doc.primitives] == ["primitive 1", "primitive 2"]
    bad = doc.primitive(1).copy()
    bad.a = 9.0
    with pytest.raises(InvalidPrimitiveError) as err:
        bad.validate(1)
    assert str(err.value).startswith("primitive 2, field 'profile.a'")
    assert err.value.primitive == 1  # the index stays an index


# -- real window -----------------------------------------------------------------------------

def _focus(qtbot, window, widget) -> None:
    window.activateWindow()
    qtbot.waitUntil(window.isActiveWindow, timeout=5000)
    widget.setFocus()
    qtbot.waitUntil(widget.hasFocus, timeout=5000)


def _type_value(qtbot, spin, text: str) -> None:
    from PySide6.QtCore import Qt

    qtbot.keyClick(spin, Qt.Key.Key_A, Qt.KeyboardModifier.ControlModifier)
    qtbot.keyClicks(spin, text)
    qtbot.keyClick(spin, Qt.Key.Key_Return)


@pytest.mark.gui
def test_ctrl_z_in_a_spin_box_undoes_the_edit_after_enter(qtbot, window, small_files) -> None:
    from PySide6.QtCore import Qt

    window.open_path(small_files["json"])
    window.doc.select(1)
    before = _snapshot(window.doc)
    spin = window.props_panel.field_widgets["a"].spin
    _focus(qtbot, window, spin)
    _type_value(qtbot, spin, "0.2")
    assert window.doc.primitive(1).a == pytest.approx(0.2)
    assert len(window.stack) == 1
    qtbot.keyClick(spin, Qt.Key.Key_Z, Qt.KeyboardModifier.ControlModifier)
    assert spin.hasFocus()
    assert _snapshot(window.doc) == before and len(window.stack) == 0
    assert spin.value() == pytest.approx(before[1][1], abs=1e-3)  # the box follows
    qtbot.keyClick(spin, Qt.Key.Key_Z, Qt.KeyboardModifier.ControlModifier
                   | Qt.KeyboardModifier.ShiftModifier)
    assert window.doc.primitive(1).a == pytest.approx(0.2) and len(window.stack) == 1
    qtbot.keyClick(spin, Qt.Key.Key_Z, Qt.KeyboardModifier.ControlModifier)
    qtbot.keyClick(spin, Qt.Key.Key_Y, Qt.KeyboardModifier.ControlModifier)
    assert window.doc.primitive(1).a == pytest.approx(0.2) and len(window.stack) == 1


def _wheel(widget, steps: int = -3) -> bool:
    """Send a wheel event to `widget`; whether the widget took it. (Qt passes a wheel
    event a widget ignores on to its parents only when it comes from the window system;
    this one is sent directly, so the test sends it on to the scroll area itself.)"""
    from PySide6.QtCore import QPoint, QPointF, Qt
    from PySide6.QtGui import QWheelEvent
    from PySide6.QtWidgets import QApplication

    pos = QPointF(widget.width() / 2, widget.height() / 2)
    event = QWheelEvent(pos, QPointF(widget.mapToGlobal(pos.toPoint())), QPoint(0, 0),
                        QPoint(0, 120 * steps), Qt.MouseButton.NoButton,
                        Qt.KeyboardModifier.NoModifier, Qt.ScrollPhase.NoScrollPhase, False)
    QApplication.sendEvent(widget, event)
    return event.isAccepted()


@pytest.mark.gui
def test_the_mouse_wheel_over_the_properties_never_edits(qtbot, window, small_files) -> None:
    window.open_path(small_files["json"])
    window.doc.select(0)
    window.resize(1100, 560)  # the panel is taller than its dock: the wheel scrolls it
    qtbot.wait(50)
    before = _snapshot(window.doc)
    panel = window.props_panel
    scroll_bar = window.props_dock.widget().verticalScrollBar()
    assert scroll_bar.maximum() > 0
    targets = [panel.field_widgets["a"].slider, panel.field_widgets["a"].spin,
               panel.cp_widgets[0][0].slider, panel.cp_widgets[0][0].spin,
               panel.scaling_widgets[0].slider, panel.scale_spin]
    for widget in targets:
        assert not _wheel(widget, -3)  # ignored: it goes on to the scroll area
        _focus(qtbot, window, widget)  # not even with the focus on it
        assert not _wheel(widget, 3)
    assert _snapshot(window.doc) == before and len(window.stack) == 0
    assert panel.scale_spin.value() == 1.0
    scroll_bar.setValue(0)
    _wheel(window.props_dock.widget().viewport(), -2)
    assert scroll_bar.value() > 0  # where the ignored wheel goes, the panel scrolls


@pytest.mark.gui
def test_keyboard_steps_on_a_slider_do_not_merge_with_a_later_click(qtbot, window,
                                                                     small_files) -> None:
    from PySide6.QtCore import QPoint, Qt

    window.open_path(small_files["json"])
    window.doc.select(1)
    slider = window.props_panel.field_widgets["degree"].slider
    start = window.doc.primitive(1).degree
    _focus(qtbot, window, slider)
    qtbot.keyClick(slider, Qt.Key.Key_Right)
    qtbot.keyClick(slider, Qt.Key.Key_Right)
    after_keys = window.doc.primitive(1).degree
    assert after_keys > start and len(window.stack) == 2  # a step per key
    # A click far along the groove (not on the handle).
    qtbot.mouseClick(slider, Qt.MouseButton.LeftButton,
                     pos=QPoint(slider.width() - 4, slider.height() // 2))
    assert window.doc.primitive(1).degree != after_keys
    assert len(window.stack) == 3
    window.stack.undo()
    assert window.doc.primitive(1).degree == after_keys
    window.stack.undo()
    window.stack.undo()
    assert window.doc.primitive(1).degree == start


@pytest.mark.gui
def test_nothing_selected_shows_blanks(qtbot, window, small_files) -> None:
    window.open_path(small_files["json"])
    panel = window.props_panel
    assert window.doc.selection is None
    for w in panel.field_widgets.values():
        assert w.is_blank() and w.spin.text().strip() == ""
        assert not w.isEnabled() or not panel.profile_group.isEnabled()
    assert not any(w.isVisibleTo(panel) for row in panel.cp_widgets for w in row)
    window.doc.select(0)
    a = window.doc.primitive(0).a
    assert float(panel.field_widgets["a"].spin.text()) == pytest.approx(a, abs=1e-3)
    window.doc.select(None)
    assert all(w.is_blank() for w in panel.field_widgets.values())
    # A primitive whose a is the range's minimum shows it, not a blank.
    window.stack.push(set_field(window.doc, 0, "a", A_RANGE[0], merge=False))
    window.doc.select(0)
    assert float(panel.field_widgets["a"].spin.text()) == pytest.approx(A_RANGE[0])


@pytest.mark.gui
def test_a_refused_scale_reverts_the_box_and_says_why(qtbot, window, small_files) -> None:
    from PySide6.QtCore import Qt

    window.open_path(small_files["json"])
    window.doc.select(0)  # "bar", a = b = 0.22: more than 2.27x breaks a <= 0.5
    before = _snapshot(window.doc)
    spin = window.props_panel.scale_spin
    _focus(qtbot, window, spin)
    qtbot.keyClick(spin, Qt.Key.Key_A, Qt.KeyboardModifier.ControlModifier)
    qtbot.keyClicks(spin, "3")
    qtbot.keyClick(spin, Qt.Key.Key_Return)
    assert _snapshot(window.doc) == before and len(window.stack) == 0
    assert spin.value() == 1.0
    message = window.statusBar().currentMessage()
    assert message.startswith("bar was not scaled: 3× would make its profile wider"), message
    assert "Scale by 0.0455× to 2.27×" in message and "field" not in message
    # A scale inside the range it names is accepted.
    _type_value(qtbot, spin, "2.2")
    assert window.doc.primitive(0).a == pytest.approx(0.22 * 2.2) and len(window.stack) == 1


@pytest.mark.gui
def test_a_failed_save_says_what_happened_and_what_to_do(qtbot, window, small_files,
                                                          tmp_path: Path) -> None:
    window.open_path(small_files["json"])
    target = tmp_path / "x" / "y" / "cactus.json"
    assert not window.save_to(target)
    assert window.errors == [("Cannot save", f"Could not save cactus.json: the folder "
                                             f"{target.parent} does not exist. Choose another "
                                             "folder.")]
    assert "Errno" not in window.errors[0][1]
    # exporting a mesh and saving a picture there: the same words, and the app goes on
    assert not window.export_mesh(target.with_suffix(".obj"))
    assert not window.save_screenshot(target.with_suffix(".png"))
    assert window.errors[1:] == [
        ("Cannot export mesh", f"Could not save cactus.obj: the folder {target.parent} "
                               "does not exist. Choose another folder."),
        ("Cannot save screenshot", f"Could not save cactus.png: the folder {target.parent} "
                                   "does not exist. Choose another folder.")]
    assert not target.parent.exists()


@pytest.mark.gui
def test_fewer_primitives_than_asked_is_explained_after_cancel(qtbot, window, small_files,
                                                               monkeypatch) -> None:
    from dataclasses import dataclass

    import sweepedit.app.fit_control as fit_control_module

    @dataclass
    class Settings:
        primitives: int = 8
        seed: int = 0

    started = []

    def short_fit(shape, settings, *, locked=(), callback=None, cancel=None):
        """Places one primitive per 50 ms until cancelled: fewer than asked for."""
        placed = []
        while len(placed) < settings.primitives and not cancel.is_set():
            placed.append(_primitive(len(placed)))
            started.append(1)
            time.sleep(0.05)
        return SimpleNamespace(abstraction=Abstraction([*(q.copy() for q in locked),
                                                        *placed]),
                               seconds=0.2, cancelled=cancel.is_set())

    monkeypatch.setattr(fit_control_module, "load_fit_api", lambda: (short_fit, Settings))
    window.open_path(small_files["obj"])
    assert window.start_fit(window.fit_panel.values() | {"primitives": 6})
    qtbot.waitUntil(lambda: len(started) >= 2, timeout=10000)
    window.cancel_fit()
    qtbot.waitUntil(lambda: not window.fitting, timeout=5000)
    got = len(window.doc)
    assert 1 <= got < 6
    expected = (f"Asked for 6 primitives, got {got}: the fit was stopped before it had "
                "placed them all")
    assert expected in window.fit_panel.status.text()
    assert window.statusBar().currentMessage().startswith(expected)


@pytest.mark.gui
def test_the_automatic_count_says_why_it_stopped(qtbot, window, small_files,
                                                 monkeypatch) -> None:
    """With auto the status says how many the shape took and why the fit stopped adding
    (the fit record's words)."""
    from dataclasses import dataclass

    import sweepedit.app.fit_control as fit_control_module

    @dataclass
    class Settings:
        primitives: int = 8
        seed: int = 0
        auto: bool = False
        tolerance: float = 0.008

    def auto_fit(shape, settings, *, locked=(), callback=None, cancel=None):
        assert settings.auto and settings.primitives == 32
        abstraction = Abstraction([_primitive(0), _primitive(1), _primitive(2)])
        abstraction.fit = {"stopped": "accurate",
                           "stopped_because": "the surfaces agree within the tolerance"}
        return SimpleNamespace(abstraction=abstraction, seconds=0.1)

    monkeypatch.setattr(fit_control_module, "load_fit_api", lambda: (auto_fit, Settings))
    window.open_path(small_files["obj"])
    window.fit_panel.auto.setChecked(True)
    assert window.start_fit(window.fit_panel.values())
    qtbot.waitUntil(lambda: not window.fitting, timeout=5000)
    expected = ("Automatic count: 3 primitives (at most 32): the surfaces agree within "
                "the tolerance.")
    assert expected in window.fit_panel.status.text()
    assert window.statusBar().currentMessage() == expected


def _other_box(tmp_path: Path) -> Path:
    import trimesh

    path = tmp_path / "tall.obj"
    trimesh.creation.box(extents=(0.2, 0.2, 0.9)).export(path)
    return path


@pytest.mark.gui
def test_opening_another_shape_asks_whether_to_keep_the_primitives(qtbot, window, small_files,
                                                                   tmp_path: Path) -> None:
    from sweepedit.io.params import read_abstraction

    asked = []
    answers = ["cancel", "keep", "discard"]

    def ask(name: str) -> str:
        asked.append(name)
        return answers.pop(0)

    window.ask_keep_primitives = ask
    window.open_path(small_files["obj"])
    window.open_path(small_files["json"])
    assert asked == []  # the parameters' own shape: nothing to ask
    before = _snapshot(window.doc)
    other = _other_box(tmp_path)
    # Cancel: nothing changes.
    assert not window.open_shape(other)
    assert window.doc.shape_path == small_files["obj"] and _snapshot(window.doc) == before
    # Keep: the same primitives, now against the new shape, whose frame and path the
    # document records (not the old shape's); a change to save.
    assert window.open_shape(other)
    assert asked == ["tall.obj", "tall.obj"]
    assert _snapshot(window.doc) == before and window.doc.shape_path == other
    assert window.doc.dirty
    assert window.doc.abstraction.source == {"path": str(other)}
    norm = window.doc.shape.normalization
    assert window.doc.abstraction.normalization.scale == norm.scale
    assert np.array_equal(window.doc.abstraction.normalization.center, norm.center)
    saved = tmp_path / "kept.json"
    assert window.save_to(saved)
    assert read_abstraction(saved).source == {"path": str(other)}
    # Discard: no primitives, no parameter file, the new shape.
    window.answers.append("discard")  # to the unsaved-changes question, if asked
    assert window.open_shape(small_files["obj"])
    assert len(window.doc) == 0 and window.doc.path is None
    assert window.doc.shape_path == small_files["obj"] and not window.doc.dirty
    assert len(window.stack) == 0


@pytest.mark.gui
def test_file_new_and_close(qtbot, window, small_files) -> None:
    from PySide6.QtCore import Qt

    window.open_path(small_files["obj"])
    window.open_path(small_files["json"])
    window.stack.push(set_field(window.doc, 0, "a", 0.1, merge=False))
    before = _snapshot(window.doc)
    assert window.menuBar().actions()[0].menu().actions()[0].text() == "&New"
    # Cancel at the unsaved-changes question: everything stays.
    window.answers.append("cancel")
    _focus(qtbot, window, window.plotter)
    qtbot.keyClick(window.plotter, Qt.Key.Key_N, Qt.KeyboardModifier.ControlModifier)
    assert _snapshot(window.doc) == before and window.doc.shape is not None
    # Discard: an empty, clean, untitled document.
    window.answers.append("discard")
    qtbot.keyClick(window.plotter, Qt.Key.Key_N, Qt.KeyboardModifier.ControlModifier)
    assert len(window.doc) == 0 and window.doc.shape is None and window.doc.path is None
    assert window.doc.shape_path is None and not window.doc.dirty and len(window.stack) == 0
    assert window.windowTitle().startswith("untitled")
    # Close (Ctrl+W) after opening again; not dirty: no question.
    window.open_path(small_files["json"])
    assert len(window.doc) == 2
    qtbot.keyClick(window.plotter, Qt.Key.Key_W, Qt.KeyboardModifier.ControlModifier)
    assert len(window.doc) == 0 and window.doc.shape is None and window.doc.path is None
    assert window.isVisible()


@pytest.mark.gui
@pytest.mark.parametrize("reports", [True, False])
def test_cancel_returns_control_within_a_second_when_the_fit_is_slow_to_stop(
        qtbot, window, small_files, monkeypatch, reports: bool) -> None:
    """Under load the fit's low-priority thread can take seconds to reach a cancel check;
    the window keeps the last preview (or nothing) after a short grace and goes on."""
    import threading
    from dataclasses import dataclass

    import sweepedit.app.fit_control as fit_control_module

    @dataclass
    class Settings:
        primitives: int = 3
        seed: int = 0

    release = threading.Event()
    shown = [_primitive(i, f"fit {i}") for i in range(3)]

    def stubborn_fit(shape, settings, *, locked=(), callback=None, cancel=None):
        if reports:
            callback(SimpleNamespace(iteration=1, total=100, losses={"total": 1.0},
                                     abstraction=Abstraction([p.copy() for p in shown])))
        release.wait(20)  # a starved thread: cancel is seen only much later
        return SimpleNamespace(abstraction=Abstraction([_primitive(7, "late")]),
                               seconds=5.0, cancelled=True)

    monkeypatch.setattr(fit_control_module, "load_fit_api", lambda: (stubborn_fit, Settings))
    window.open_path(small_files["obj"])
    window.open_path(small_files["json"])
    before = _snapshot(window.doc)
    assert window.start_fit(window.fit_panel.values())
    if reports:
        qtbot.waitUntil(lambda: window.scene.previewing, timeout=10000)
    else:
        qtbot.wait(300)
    t0 = time.perf_counter()
    window.cancel_fit()
    qtbot.waitUntil(lambda: not window.fitting, timeout=3000)
    assert time.perf_counter() - t0 < 2.5  # the stubborn fit holds on for 20 s
    assert window.act_undo.isEnabled() == reports and window.act_open_shape.isEnabled()
    if reports:
        assert [p.name for p in window.doc.primitives] == ["fit 0", "fit 1", "fit 2"]
        assert window.doc.abstraction.fit["cancelled"] is True
        window.stack.undo()
    assert _snapshot(window.doc) == before
    release.set()  # the fit returns late: its result is ignored, nothing breaks
    qtbot.wait(300)
    assert _snapshot(window.doc) == before and not window.fitting


def test_no_two_actions_share_a_shortcut(window) -> None:
    """Qt runs neither of two actions bound to one key (Mirror Z once took Redo's
    Ctrl+Shift+Z), so every shortcut of the window belongs to one action."""
    from PySide6.QtGui import QAction

    owners: dict[str, str] = {}
    for action in window.findChildren(QAction):
        for key in action.shortcuts():
            text = key.toString()
            if not text:
                continue
            assert text not in owners, f"{text}: {owners[text]!r} and {action.text()!r}"
            owners[text] = action.text()
    assert owners.get("Ctrl+Shift+Z") == window.act_redo.text()
    assert owners.get("Ctrl+Alt+Z") == window.act_mirror[2].text()
