"""A labelled slider and number box over one float range, kept in step."""

from __future__ import annotations

from PySide6.QtCore import QSignalBlocker, Qt, Signal
from PySide6.QtWidgets import QHBoxLayout, QSlider, QWidget

from sweepedit.app.widgets.property_slider import PropertySlider
from sweepedit.app.widgets.property_spin_box import number_box


class SliderSpin(QWidget):
    """A labelled slider and spin box over one float range, kept in step.

    value_changed(float) on every change by the user; editing_finished() ends an undo
    step: around every discrete change (a key, a click on the groove, a value typed in
    the box), when a drag of the handle starts and when it ends. A drag is one step; a
    key press is a step of its own and never merges with a later click or drag."""

    value_changed = Signal(float)
    editing_finished = Signal()
    STEPS = 1000

    def __init__(self, lo: float, hi: float, decimals: int = 3, step: float = 0.005,
                 parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.lo, self.hi = float(lo), float(hi)
        self.slider = PropertySlider(Qt.Orientation.Horizontal)
        self.slider.setRange(0, self.STEPS)
        self.slider.setMinimumWidth(90)
        self.spin = number_box(self.lo, self.hi, decimals, step)
        self.spin.setMinimumWidth(78)
        layout = QHBoxLayout(self)
        layout.setContentsMargins(0, 0, 0, 0)
        layout.addWidget(self.slider, 1)
        layout.addWidget(self.spin)
        self._discrete = False  # the slider's pending change is a key or a page click
        self.slider.actionTriggered.connect(self._on_slider_action)
        self.slider.valueChanged.connect(self._from_slider)
        self.slider.sliderPressed.connect(self.editing_finished)
        self.slider.sliderReleased.connect(self.editing_finished)
        self.spin.valueChanged.connect(self._from_spin)
        self.spin.editingFinished.connect(self.editing_finished)

    def value(self) -> float:
        return float(self.spin.value())

    def set_value(self, value: float) -> None:
        """Show `value` without emitting value_changed."""
        with QSignalBlocker(self.spin), QSignalBlocker(self.slider):
            # Both repaint the box even when nothing changes, and a drag refreshes the
            # panel on every mouse move.
            if self.spin.specialValueText():
                self.spin.setSpecialValueText("")
            if self.spin.textFromValue(value) != self.spin.textFromValue(self.spin.value()):
                self.spin.setValue(value)
            self.slider.setValue(self._to_steps(value))

    def set_blank(self) -> None:
        """Show no value (nothing selected), not the range's minimum."""
        with QSignalBlocker(self.spin), QSignalBlocker(self.slider):
            self.spin.setSpecialValueText(" ")  # shown while the value is the minimum
            self.spin.setValue(self.spin.minimum())
            self.slider.setValue(0)

    def is_blank(self) -> bool:
        return self.spin.text().strip() == ""

    def _on_slider_action(self, action: int) -> None:
        # Emitted before the value changes: a key or a click on the groove is a step of
        # its own; a drag (SliderMove) merges until the handle is released.
        self._discrete = action != QSlider.SliderAction.SliderMove.value

    def _to_steps(self, value: float) -> int:
        return round((value - self.lo) / (self.hi - self.lo) * self.STEPS)

    def _from_slider(self, steps: int) -> None:
        value = self.lo + (self.hi - self.lo) * steps / self.STEPS
        with QSignalBlocker(self.spin):
            self.spin.setSpecialValueText("")
            self.spin.setValue(value)
        discrete, self._discrete = self._discrete, False
        if discrete:
            self.editing_finished.emit()
        self.value_changed.emit(self.value())
        if discrete:
            self.editing_finished.emit()

    def _from_spin(self, value: float) -> None:
        # Enter, an arrow key or a step button: one change, one undo step.
        with QSignalBlocker(self.slider):
            self.slider.setValue(self._to_steps(value))
        self.spin.setSpecialValueText("")
        self.editing_finished.emit()
        self.value_changed.emit(float(value))
        self.editing_finished.emit()

