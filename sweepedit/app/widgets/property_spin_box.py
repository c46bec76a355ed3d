"""The properties panel's number box: the wheel never edits it, and once a typed value
is committed the undo keys reach the window."""

from __future__ import annotations

from PySide6.QtCore import QEvent, Qt
from PySide6.QtGui import QKeyEvent, QKeySequence, QWheelEvent
from PySide6.QtWidgets import QDoubleSpinBox, QWidget

# Keys the window's undo and redo actions own, also while a property box has the focus.
_HISTORY_KEYS = (QKeySequence.StandardKey.Undo, QKeySequence.StandardKey.Redo)
_REDO_EXTRA = QKeySequence("Ctrl+Y")


def _is_history_key(event: QKeyEvent) -> bool:
    if any(event.matches(k) for k in _HISTORY_KEYS):
        return True
    return QKeySequence(event.keyCombination()) == _REDO_EXTRA


class PropertySpinBox(QDoubleSpinBox):
    """A spin box of the properties panel. The mouse wheel never edits it (scrolling the
    panel must not change the geometry: the wheel goes on to the scroll area), and
    Ctrl+Z / Ctrl+Shift+Z / Ctrl+Y reach the window's undo and redo once the typed value
    is committed (Enter); only while a number is being typed do they undo the typing."""

    def __init__(self, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.setFocusPolicy(Qt.FocusPolicy.StrongFocus)

    def typing(self) -> bool:
        """Whether the text shows something not yet committed as the value."""
        return self.cleanText() != self.textFromValue(self.value()) and bool(self.cleanText())

    def event(self, event: QEvent) -> bool:
        if (event.type() == QEvent.Type.ShortcutOverride and isinstance(event, QKeyEvent)
                and _is_history_key(event) and not self.typing()):
            event.ignore()  # not ours: the window's shortcut takes it
            return False
        return super().event(event)

    def wheelEvent(self, event: QWheelEvent) -> None:  # noqa: N802 (Qt API)
        event.ignore()


def number_box(lo: float, hi: float, decimals: int, step: float,
               suffix: str = "") -> PropertySpinBox:
    """A property box over [lo, hi] that commits its value on Enter, not per keystroke."""
    s = PropertySpinBox()
    s.setRange(lo, hi)
    s.setDecimals(decimals)
    s.setSingleStep(step)
    s.setKeyboardTracking(False)
    s.setSuffix(suffix)
    s.setMinimumWidth(70)
    return s
