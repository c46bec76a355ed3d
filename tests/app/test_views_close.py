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
