"""What the panels share: pushing a command, telling a refusal in the user's words, and
letting go of the Document when the panel is destroyed."""

from __future__ import annotations

from collections.abc import Callable

from PySide6.QtWidgets import QWidget

from sweepedit.app.commands import Command, CommandStack
from sweepedit.app.document import Connections, Document
from sweepedit.errors import SweepeditError
from sweepedit.geometry.model import SCALING_RANGE


def refusal_text(exc: SweepeditError, name: str) -> str:
    """Why an edit of primitive `name` was refused, in the user's words."""
    field = getattr(exc, "field", None) or ""
    detail = getattr(exc, "detail", str(exc))
    if field == "scaling":
        return (f"{name}: not changed; with that scaling the primitive would get zero or "
                "negative thickness somewhere along its axis. Choose a smaller coefficient.")
    if field.startswith("scaling["):
        return f"{name}: not changed; scaling coefficients stay within {list(SCALING_RANGE)}."
    return f"{name}: not changed; {detail}."


def document_links(widget: QWidget) -> Connections:
    """Connections to a Document that are all disconnected when `widget` is destroyed
    (with its window, or on its own while the Document lives on)."""
    links = Connections()
    # The slot holds the links, not the widget, which is half gone when this runs.
    widget.destroyed.connect(lambda *_args: links.disconnect_all())
    return links


class PanelEditor:
    """Shared by panels: push a command, report refusals instead of raising."""

    def __init__(self, doc: Document, stack: CommandStack,
                 report: Callable[[str], None] | None = None) -> None:
        self.doc = doc
        self.stack = stack
        self.report = report or (lambda message: None)

    def push(self, command: Command) -> bool:
        try:
            self.stack.push(command)
        except SweepeditError as exc:  # e.g. a scaling that makes f(t) <= 0
            index = getattr(command, "index", None)
            name = (self.doc.primitive(index).name if isinstance(index, int)
                    and 0 <= index < len(self.doc) else "The primitive")
            self.report(refusal_text(exc, name))
            return False
        return True
