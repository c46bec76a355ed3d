"""A Document outlives its views: panels and the 3D scene that close or are destroyed
disconnect from it, so that an edit afterwards never calls into a widget that is gone
(PySide raises "Internal C++ object already deleted" when it does)."""

from __future__ import annotations

import numpy as np
import pytest

from sweepedit.app.commands import CommandStack, move_control_point, set_field
from sweepedit.app.document import Connections, Document, Signal
from sweepedit.geometry.model import Abstraction, SweepPrimitive


def _signals(doc: Document) -> dict[str, Signal]:
    return {name: value for name, value in vars(doc).items() if isinstance(value, Signal)}


def _two_primitives() -> Abstraction:
    return Abstraction([
        SweepPrimitive(control_points=[[-0.4, 0, 0], [0, 0.05, 0], [0.4, 0, 0]], a=0.1, b=0.1),
        SweepPrimitive(control_points=[[0, -0.3, 0], [0, 0, 0.02], [0, 0.3, 0]], a=0.08,
                       b=0.08),
    ])


def test_connections_disconnect_exactly_what_they_connected() -> None:
    doc = Document(_two_primitives())
    kept: list[int] = []
    doc.selection_changed.connect(kept.append)  # someone else's slot stays
    links = Connections()
    seen: list[tuple[int, str]] = []
    links.connect(doc.primitive_changed, lambda i, kind: seen.append((i, kind)))
    links.connect(doc.selection_changed, lambda i: seen.append((i, "selected")))
    assert len(links) == 2
    doc.select(1)
    assert seen == [(1, "selected")] and kept == [1]
    links.disconnect_all()
    assert len(links) == 0
    assert doc.primitive_changed.receivers() == 0
    assert doc.selection_changed.receivers() == 1
    doc.select(0)
    assert seen == [(1, "selected")] and kept == [1, 0]


def test_panels_destroyed_before_the_document_leave_it(qtbot) -> None:
    import shiboken6

    from sweepedit.app.panels import PrimitiveListPanel, PropertiesPanel

    doc = Document(_two_primitives())
    stack = CommandStack(doc)
    before = {name: signal.receivers() for name, signal in _signals(doc).items()}
    panels = [PrimitiveListPanel(doc, stack), PropertiesPanel(doc, stack)]
    doc.select(0)
    assert doc.primitive_changed.receivers() == before["primitive_changed"] + 2
    for panel in panels:
        shiboken6.delete(panel)  # as Qt deletes a panel with its dock or window
    assert {name: signal.receivers() for name, signal in _signals(doc).items()} == before
    # Edits of the surviving document reach no deleted widget.
    stack.push(move_control_point(doc, 0, 1, [0.0, 0.1, 0.0]))
    stack.push(set_field(doc, 1, "name", "rod", merge=False))
    doc.select(1)
    stack.undo()
    np.testing.assert_array_equal(doc.primitive(0).control_points[1], [0.0, 0.1, 0.0])


@pytest.mark.gui
def test_closing_the_window_disconnects_every_view_from_the_document(qtbot, window,
                                                                      small_files) -> None:
    window.open_path(small_files["obj"])
    window.open_path(small_files["json"])
    window.set_heatmap_visible(True)
    doc = window.doc
    assert doc.primitive_changed.receivers() >= 3  # the scene and two panels at least
    assert window.close()
    assert {name: signal.receivers() for name, signal in _signals(doc).items()} == {
        name: 0 for name in _signals(doc)}
    # Edits of the document after the window closed reach none of its views.
    doc.select(1)
    CommandStack(doc).push(move_control_point(doc, 1, 0, [0.0, -0.25, 0.0]))
    np.testing.assert_array_equal(doc.primitive(1).control_points[0], [0.0, -0.25, 0.0])


def test_a_failing_view_neither_stops_the_others_nor_loses_the_edit() -> None:
    doc = Document(_two_primitives())
    stack = CommandStack(doc)
    seen: list[int] = []
    failures: list[BaseException] = []

    def broken_view(index: int, kind: str) -> None:
        raise RuntimeError("cannot draw")

    doc.primitive_changed.connect(broken_view)
    doc.primitive_changed.connect(lambda index, kind: seen.append(index))
    doc.on_view_error = failures.append
    before = doc.primitive(0).control_points.copy()
    stack.push(move_control_point(doc, 0, 1, [0.0, 0.2, 0.0]))
    # The view after the broken one followed the edit, and the edit is in the history.
    assert seen == [0] and [str(f) for f in failures] == ["cannot draw"]
    assert len(stack) == 1 and stack.can_undo
    stack.undo()
    np.testing.assert_array_equal(doc.primitive(0).control_points, before)
    assert seen == [0, 0] and len(failures) == 2
    # With nobody to tell, the failure is raised, still after every slot has run.
    doc.on_view_error = None
    with pytest.raises(RuntimeError, match="cannot draw"):
        stack.push(move_control_point(doc, 0, 1, [0.0, 0.3, 0.0]))
    assert seen == [0, 0, 0]


@pytest.mark.gui
def test_the_window_tells_of_a_view_that_failed_and_keeps_the_edit(qtbot, window,
                                                                     small_files) -> None:
    window.open_path(small_files["json"])
    window.doc.on_view_error = window.view_failed  # as the app runs (the fixture raises)

    def broken_view(index: int, kind: str) -> None:
        raise RuntimeError("cannot draw")

    window.doc.primitive_changed.connect(broken_view)
    window.stack.push(set_field(window.doc, 0, "a", 0.2, merge=False))
    assert window.doc.primitive(0).a == 0.2 and len(window.stack) == 1
    assert "could not show that change (RuntimeError: cannot draw)" in (
        window.statusBar().currentMessage())
    assert window.errors == []  # no dialog
    window.doc.primitive_changed.disconnect(broken_view)
    window.stack.undo()
    assert window.doc.primitive(0).a == pytest.approx(0.22)
