"""Side panels: the primitives list, the selected primitive's properties, and fitting.

Panels read the Document and turn widget edits into commands on the CommandStack; they
refresh themselves from the Document's signals (so undo updates them too), blocking
their own widgets' signals while they do so that a refresh never becomes an edit.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
from PySide6.QtCore import QEvent, QPointF, QRectF, QSignalBlocker, Qt, Signal
from PySide6.QtGui import (
    QAction,
    QColor,
    QFont,
    QIcon,
    QKeyEvent,
    QKeySequence,
    QPainter,
    QPen,
    QPixmap,
    QPolygonF,
    QWheelEvent,
)
from PySide6.QtWidgets import (
    QAbstractItemView,
    QCheckBox,
    QColorDialog,
    QComboBox,
    QDoubleSpinBox,
    QFormLayout,
    QGridLayout,
    QGroupBox,
    QHBoxLayout,
    QHeaderView,
    QLabel,
    QProgressBar,
    QPushButton,
    QSizePolicy,
    QSlider,
    QSpinBox,
    QToolButton,
    QTreeWidget,
    QTreeWidgetItem,
    QVBoxLayout,
    QWidget,
)

from sweepedit.app.commands import (
    Command,
    CommandStack,
    affine_matrix,
    move_control_point,
    selection_pivot,
    set_field,
    set_field_many,
    transform_primitives,
)
from sweepedit.app.document import DISPLAY, GEOMETRY, META, Document
from sweepedit.app.worker import FitUpdate
from sweepedit.errors import InvalidPrimitiveError, SweepeditError
from sweepedit.geometry.model import A_RANGE, B_RANGE, DEGREE_RANGE, SCALING_RANGE

CONTROL_POINT_RANGE = (-1.0, 1.0)  # wider than the fitted [-0.5, 0.5] so users can reach out
# The fit panel's method choice: (shown text, FitSettings.method).
FIT_METHODS = (("direct (fast)", "direct"), ("network (paper)", "network"))
PROGRESS_STEPS = 1000


def seconds_text(seconds: float) -> str:
    """A rough duration for people: "about 3 s", "about 2 min"."""
    if seconds < 1.0:
        return "under a second"
    if seconds < 90.0:
        return f"about {round(seconds)} s"
    return f"about {round(seconds / 60.0)} min"


def progress_text(update: FitUpdate) -> str:
    """ "refinement 40% · about 3 s left"; from a fit that names no stage, its
    iterations."""
    if update.stage is None:
        return f"Fitting: iteration {update.iteration} of {update.total}"
    text = f"{update.stage} {math.floor(update.stage_fraction * 100)}%"
    if update.seconds_left is not None:
        text += f" · {seconds_text(update.seconds_left)} left"
    return text


@functools.lru_cache(maxsize=256)  # the panels ask again on every edit of a primitive
def color_icon(color: str, size: int = 14) -> QIcon:
    """A square swatch of `color` with a thin dark border."""
    pix = QPixmap(size, size)
    pix.fill(Qt.GlobalColor.transparent)
    p = QPainter(pix)
    p.setRenderHint(QPainter.RenderHint.Antialiasing)
    p.setPen(QPen(QColor(0, 0, 0, 120), 1))
    p.setBrush(QColor(color))
    p.drawRoundedRect(QRectF(0.5, 0.5, size - 1, size - 1), 3, 3)
    p.end()
    return QIcon(pix)


def refusal_text(exc: SweepeditError, name: str) -> str:
    """Why an edit of primitive `name` was refused, in the user's words."""
    field = getattr(exc, "field", None) or ""
    detail = getattr(exc, "detail", str(exc))
    if field == "scaling":
        return (f"{name}: not changed; with that scaling the primitive would get zero or "
                "negative thickness somewhere along its axis. Choose a smaller coefficient.")
    if field.startswith("scaling["):
        return f"{name}: not changed; scaling coefficients stay within {list(SCALING_RANGE)}."
    if field == "control_points":
        return f"{name}: not changed; {detail}."
    return f"{name}: not changed; {detail}."


class _Editor:
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


# -- primitives list ------------------------------------------------------------------------

class PrimitiveListPanel(QWidget):
    """Primitives with colour swatch, name (double-click to rename), visibility and lock
    check boxes; selecting a row selects the primitive. Add/Duplicate/Delete buttons
    trigger the window's actions."""

    COL_NAME, COL_VISIBLE, COL_LOCKED = 0, 1, 2

    def __init__(self, doc: Document, stack: CommandStack, actions: Sequence[QAction] = (),
                 report: Callable[[str], None] | None = None,
                 parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.doc = doc
        self.editor = _Editor(doc, stack, report)
        self.tree = QTreeWidget()
        self.tree.setColumnCount(3)
        self.tree.setHeaderLabels(["Primitive", "Visible", "Locked"])
        self.tree.setRootIsDecorated(False)
        self.tree.setUniformRowHeights(True)
        # Ctrl/Shift-click and Ctrl+A select several (edits then act on all of them).
        self.tree.setSelectionMode(QAbstractItemView.SelectionMode.ExtendedSelection)
        # Only the name column is edited (double-click); the check boxes toggle on click.
        self.tree.setEditTriggers(QAbstractItemView.EditTrigger.NoEditTriggers)
        self.tree.itemDoubleClicked.connect(
            lambda item, column: self.tree.editItem(item, 0) if column == 0 else None)
        header = self.tree.header()
        header.setStretchLastSection(False)
        header.setSectionResizeMode(0, QHeaderView.ResizeMode.Stretch)
        for col in (1, 2):
            header.setSectionResizeMode(col, QHeaderView.ResizeMode.ResizeToContents)
        self.tree.itemChanged.connect(self._on_item_changed)
        self.tree.itemSelectionChanged.connect(self._on_tree_selection)

        buttons = QHBoxLayout()
        buttons.setContentsMargins(0, 0, 0, 0)
        self.buttons: list[QToolButton] = []
        for action in actions:
            b = QToolButton()
            b.setDefaultAction(action)
            b.setToolButtonStyle(Qt.ToolButtonStyle.ToolButtonTextOnly)
            buttons.addWidget(b)
            self.buttons.append(b)
        buttons.addStretch(1)

        layout = QVBoxLayout(self)
        layout.setContentsMargins(6, 6, 6, 6)
        layout.addWidget(self.tree, 1)
        layout.addLayout(buttons)

        self._refreshing = False
        doc.primitives_reset.connect(self.rebuild)
        doc.primitive_changed.connect(self._on_primitive_changed)
        doc.selection_changed.connect(self._on_selection_changed)
        self.rebuild()

    def rebuild(self) -> None:
        self._refreshing = True
        try:
            self.tree.clear()
            for i in range(len(self.doc)):
                item = QTreeWidgetItem()
                item.setFlags(Qt.ItemFlag.ItemIsSelectable | Qt.ItemFlag.ItemIsEnabled
                              | Qt.ItemFlag.ItemIsEditable | Qt.ItemFlag.ItemIsUserCheckable)
                self.tree.addTopLevelItem(item)
                self._fill(item, i)
            self._select_row(self.doc.selection)
        finally:
            self._refreshing = False

    def _fill(self, item: QTreeWidgetItem, index: int) -> None:
        prim = self.doc.primitive(index)
        item.setText(self.COL_NAME, prim.name or f"primitive {index + 1}")
        item.setIcon(self.COL_NAME, color_icon(prim.color))
        item.setToolTip(self.COL_NAME, f"{prim.n_control_points} control points, "
                        f"a={prim.a:.3f} b={prim.b:.3f} d={prim.degree:.2f}")
        item.setCheckState(self.COL_VISIBLE, Qt.CheckState.Checked if prim.visible
                           else Qt.CheckState.Unchecked)
        item.setCheckState(self.COL_LOCKED, Qt.CheckState.Checked if prim.locked
                           else Qt.CheckState.Unchecked)

    def _select_row(self, index: int | None) -> None:
        """Show the document's selection: every selected row, the primary current."""
        if index is None or index >= self.tree.topLevelItemCount():
            self.tree.clearSelection()
            self.tree.setCurrentItem(None)
            return
        item = self.tree.topLevelItem(index)
        self.tree.setCurrentItem(item)
        chosen = set(self.doc.selected_indices) | {index}
        for i in range(self.tree.topLevelItemCount()):
            self.tree.topLevelItem(i).setSelected(i in chosen)
        self.tree.scrollToItem(item)

    def _on_primitive_changed(self, index: int, kind: str) -> None:
        if kind in (DISPLAY, META, GEOMETRY) and index < self.tree.topLevelItemCount():
            self._refreshing = True
            try:
                self._fill(self.tree.topLevelItem(index), index)
            finally:
                self._refreshing = False

    def _on_selection_changed(self, index: int | None) -> None:
        self._refreshing = True
        try:
            self._select_row(index)
        finally:
            self._refreshing = False

    def _on_tree_selection(self) -> None:
        if self._refreshing:
            return
        rows = sorted(self.tree.indexOfTopLevelItem(item) for item in self.tree.selectedItems())
        current = self.tree.currentItem()
        primary = self.tree.indexOfTopLevelItem(current) if current is not None else None
        self.doc.set_selection(rows, primary=primary if primary in rows else None)

    def _on_item_changed(self, item: QTreeWidgetItem, column: int) -> None:
        if self._refreshing:
            return
        index = self.tree.indexOfTopLevelItem(item)
        prim = self.doc.primitive(index)
        if column == self.COL_NAME:
            name = item.text(0).strip()
            if name and name != prim.name:
                self.editor.push(set_field(self.doc, index, "name", name, merge=False))
            else:
                self._on_primitive_changed(index, META)
        elif column in (self.COL_VISIBLE, self.COL_LOCKED):
            field = "visible" if column == self.COL_VISIBLE else "locked"
            value = item.checkState(column) == Qt.CheckState.Checked
            # A box ticked on a selected row ticks it for the whole selection (one step).
            rows = (self.doc.selected_indices if index in self.doc.selected_indices
                    else [index])
            rows = [i for i in rows if getattr(self.doc.primitive(i), field) != value]
            if rows:
                self.editor.push(set_field_many(self.doc, rows, field, value))


# -- properties -----------------------------------------------------------------------------

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


class PropertySlider(QSlider):
    """A slider of the properties panel that the mouse wheel never moves."""

    def __init__(self, orientation: Qt.Orientation, parent: QWidget | None = None) -> None:
        super().__init__(orientation, parent)
        self.setFocusPolicy(Qt.FocusPolicy.StrongFocus)

    def wheelEvent(self, event: QWheelEvent) -> None:  # noqa: N802 (Qt API)
        event.ignore()


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
        self.spin = PropertySpinBox()
        self.spin.setRange(self.lo, self.hi)
        self.spin.setDecimals(decimals)
        self.spin.setSingleStep(step)
        self.spin.setKeyboardTracking(False)
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


def _spin(lo: float, hi: float, decimals: int, step: float, suffix: str = "") -> QDoubleSpinBox:
    s = PropertySpinBox()
    s.setRange(lo, hi)
    s.setDecimals(decimals)
    s.setSingleStep(step)
    s.setKeyboardTracking(False)
    s.setSuffix(suffix)
    s.setMinimumWidth(70)
    return s


class PropertiesPanel(QWidget):
    """The selected primitive: control points, profile a, b, d, scaling coefficients (all
    live, each change is a command; a drag of a slider is one undo step) and a transform
    section (translate / rotate / scale the whole primitive about its control points'
    centroid, applied as one command)."""

    def __init__(self, doc: Document, stack: CommandStack,
                 report: Callable[[str], None] | None = None,
                 parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.doc = doc
        self.stack = stack
        self.editor = _Editor(doc, stack, report)
        self._editable = True

        self.title = QLabel("No primitive selected")
        font = self.title.font()
        font.setBold(True)
        self.title.setFont(font)

        self.cp_group = QGroupBox("Axis control points")
        self.cp_grid = QGridLayout(self.cp_group)
        self.cp_grid.setContentsMargins(6, 6, 6, 6)
        self.cp_widgets: list[list[SliderSpin]] = []  # [control point][x, y, z]

        self.profile_group = QGroupBox("Profile")
        pf = QFormLayout(self.profile_group)
        pf.setContentsMargins(6, 6, 6, 6)
        self.field_widgets: dict[str, SliderSpin] = {}
        for name, label, (lo, hi), step, decimals in (
                ("a", "a (along U)", A_RANGE, 0.002, 3), ("b", "b (along V)", B_RANGE, 0.002, 3),
                ("degree", "d (shape)", DEGREE_RANGE, 0.05, 2)):
            w = SliderSpin(lo, hi, decimals, step)
            w.value_changed.connect(lambda v, n=name: self._set_field(n, v))
            w.editing_finished.connect(self.stack.close_merge)
            w.setToolTip({"a": "half-width of the profile along the frame's U axis",
                          "b": "half-width of the profile along the frame's V axis",
                          "degree": "superellipse exponent: 2 ellipse, 1 rhombus, "
                                    "large rectangle, < 1 star"}[name])
            pf.addRow(label, w)
            self.field_widgets[name] = w

        self.scaling_group = QGroupBox("Scaling f(t) = 1 + s1·t + s2·t² …")
        self.scaling_form = QFormLayout(self.scaling_group)
        self.scaling_form.setContentsMargins(6, 6, 6, 6)
        self.scaling_widgets: list[SliderSpin] = []

        self.transform_group = QGroupBox("Transform whole primitive")
        tg = QGridLayout(self.transform_group)
        tg.setContentsMargins(6, 6, 6, 6)
        self.translate_spins = [_spin(-1, 1, 3, 0.01) for _ in range(3)]
        self.rotate_spins = [_spin(-360, 360, 1, 5, "°") for _ in range(3)]
        self.scale_spin = _spin(0.05, 20, 3, 0.05, "×")
        self.scale_spin.setValue(1.0)
        tg.addWidget(QLabel(""), 0, 0)
        for c, axis in enumerate("xyz"):
            lab = QLabel(axis)
            lab.setAlignment(Qt.AlignmentFlag.AlignCenter)
            tg.addWidget(lab, 0, c + 1)
        tg.addWidget(QLabel("Move"), 1, 0)
        tg.addWidget(QLabel("Rotate"), 2, 0)
        for c in range(3):
            tg.addWidget(self.translate_spins[c], 1, c + 1)
            tg.addWidget(self.rotate_spins[c], 2, c + 1)
        tg.addWidget(QLabel("Scale"), 3, 0)
        tg.addWidget(self.scale_spin, 3, 1)
        self.apply_transform_button = QPushButton("Apply")
        self.apply_transform_button.setToolTip("Apply the move, rotation (about x, y, z) and "
                                               "scale about the control points' centroid "
                                               "(Enter)")
        self.apply_transform_button.clicked.connect(self.apply_transform)
        self.reset_transform_button = QPushButton("Reset")
        self.reset_transform_button.clicked.connect(self.reset_transform)
        tg.addWidget(self.apply_transform_button, 3, 2)
        tg.addWidget(self.reset_transform_button, 3, 3)
        self.scale_profile_check = QCheckBox("Scale the profile (a, b) too")
        self.scale_profile_check.setChecked(True)
        self.scale_profile_check.setToolTip("On: Scale resizes the whole solid. Off: only the "
                                            "axis (its control points) is scaled")
        tg.addWidget(self.scale_profile_check, 4, 1, 1, 3)
        for s in (*self.translate_spins, *self.rotate_spins, self.scale_spin):
            s.lineEdit().returnPressed.connect(self.apply_transform)

        self.color_button = QPushButton("Colour…")
        self._shown_color: str | None = None  # the colour its icon shows
        self.color_button.setToolTip("Choose the primitive's display colour")
        self.color_button.clicked.connect(self.choose_color)
        header = QHBoxLayout()
        header.addWidget(self.title, 1)
        header.addWidget(self.color_button)

        layout = QVBoxLayout(self)
        layout.setContentsMargins(6, 6, 6, 6)
        layout.addLayout(header)
        for g in (self.cp_group, self.profile_group, self.scaling_group, self.transform_group):
            layout.addWidget(g)
        layout.addStretch(1)

        doc.selection_changed.connect(lambda _i: self.refresh())
        doc.primitives_reset.connect(self.refresh)
        doc.primitive_changed.connect(self._on_primitive_changed)
        self.refresh()

    # -- building and refreshing ------------------------------------------------------------
    def _ensure_rows(self, n_points: int, n_scaling: int) -> None:
        # One grid row per coordinate: "c1 x", "y", "z", "c2 x", ...
        while len(self.cp_widgets) < n_points:
            point = len(self.cp_widgets)
            widgets = []
            for c, axis in enumerate("xyz"):
                w = SliderSpin(*CONTROL_POINT_RANGE, 4, 0.005)
                w.value_changed.connect(
                    lambda v, r=point, k=c: self._set_control_point(r, k, v))
                w.editing_finished.connect(self.stack.close_merge)
                w.setToolTip(f"{axis} of control point c{point + 1} (normalised frame)")
                label = QLabel(f"c{point + 1}  {axis}" if c == 0 else axis)
                label.setAlignment(Qt.AlignmentFlag.AlignRight | Qt.AlignmentFlag.AlignVCenter)
                self.cp_grid.addWidget(label, 3 * point + c, 0)
                self.cp_grid.addWidget(w, 3 * point + c, 1)
                widgets.append(w)
            self.cp_widgets.append(widgets)
        for point, widgets in enumerate(self.cp_widgets):
            visible = point < n_points
            for c, w in enumerate(widgets):
                self.cp_grid.itemAtPosition(3 * point + c, 0).widget().setVisible(visible)
                w.setVisible(visible)
        while len(self.scaling_widgets) < n_scaling:
            k = len(self.scaling_widgets)
            w = SliderSpin(*SCALING_RANGE, 3, 0.01)
            w.value_changed.connect(lambda _v, i=k: self._set_scaling(i))
            w.editing_finished.connect(self.stack.close_merge)
            w.setToolTip(f"coefficient of t^{k + 1} in the scaling along the axis")
            self.scaling_form.addRow(f"s{k + 1}", w)
            self.scaling_widgets.append(w)
        for k in range(len(self.scaling_widgets)):
            self.scaling_form.setRowVisible(k, k < n_scaling)

    def set_editable(self, editable: bool) -> None:
        """False while a fit runs (the document is about to be replaced)."""
        self._editable = editable
        self.refresh()

    def refresh(self) -> None:
        prim = self.doc.selected
        enabled = prim is not None and self._editable and not prim.locked
        for g in (self.cp_group, self.profile_group, self.scaling_group, self.transform_group):
            g.setEnabled(enabled)
        self.color_button.setEnabled(prim is not None and self._editable)
        if prim is not None and prim.color != self._shown_color:  # setIcon always repaints
            self.color_button.setIcon(color_icon(prim.color))
            self._shown_color = prim.color
        if prim is None:
            self.title.setText("No primitive selected")
            self.title.setToolTip("")
            self._ensure_rows(0, 0)  # no control point or scaling rows
            for w in self.field_widgets.values():
                w.set_blank()
            return
        locked = "  (locked)" if prim.locked else ""
        self.title.setText(f"{prim.name or 'primitive'}{locked}")
        self._ensure_rows(prim.n_control_points, len(prim.scaling))
        for row, point in enumerate(prim.control_points):
            for c in range(3):
                self.cp_widgets[row][c].set_value(float(point[c]))
        for name, w in self.field_widgets.items():
            w.set_value(getattr(prim, name))
        for k, value in enumerate(prim.scaling):
            self.scaling_widgets[k].set_value(value)

    def _on_primitive_changed(self, index: int, kind: str) -> None:
        if index == self.doc.selection and kind in (GEOMETRY, DISPLAY, META):
            self.refresh()

    # -- edits ----------------------------------------------------------------------------
    def _set_field(self, name: str, value: float) -> None:
        i = self.doc.selection
        if i is None:
            return
        if not self.editor.push(set_field(self.doc, i, name, value)):
            self.refresh()

    def _set_scaling(self, k: int) -> None:
        i = self.doc.selection
        if i is None:
            return
        scaling = list(self.doc.primitive(i).scaling)
        scaling[k] = self.scaling_widgets[k].value()
        if not self.editor.push(set_field(self.doc, i, "scaling", tuple(scaling))):
            self.refresh()

    def _set_control_point(self, row: int, coordinate: int, value: float) -> None:
        """Move one coordinate; the other two keep the document's exact values (the spin
        boxes show them rounded)."""
        i = self.doc.selection
        if i is None:
            return
        position = self.doc.primitive(i).control_points[row].copy()
        position[coordinate] = value
        if not self.editor.push(move_control_point(self.doc, i, row, position)):
            self.refresh()

    def choose_color(self) -> None:
        i = self.doc.selection
        if i is None:
            return
        color = QColorDialog.getColor(QColor(self.doc.primitive(i).color), self,
                                      "Primitive colour")
        if color.isValid():
            self.editor.push(set_field(self.doc, i, "color", color.name(), merge=False))

    def transform_matrix(self) -> np.ndarray:
        """The 4x4 affine of the transform section, about the centroid of the selected
        primitives' control points."""
        pivot = selection_pivot(self.doc, self.doc.selected_indices)
        return affine_matrix([s.value() for s in self.translate_spins],
                             [s.value() for s in self.rotate_spins],
                             self.scale_spin.value(), pivot)

    def apply_transform(self) -> None:
        i = self.doc.selection
        if i is None or not self._editable or self.doc.primitive(i).locked:
            return
        m = self.transform_matrix()
        if np.allclose(m, np.eye(4)):
            return
        profile_scale = self.scale_spin.value() if self.scale_profile_check.isChecked() else 1.0
        self.stack.close_merge()
        # The whole selection (locked ones skipped) moves as one undo step.
        command = transform_primitives(self.doc, self.doc.selected_indices, m,
                                       profile_scale=profile_scale)
        try:
            self.stack.push(command)
        except SweepeditError as exc:
            self.editor.report(self._transform_refusal(exc, profile_scale))
            with QSignalBlocker(self.scale_spin):
                self.scale_spin.setValue(1.0)  # the refused value does not stay shown
            return
        self.reset_transform()

    def _transform_refusal(self, exc: SweepeditError, scale: float) -> str:
        """A refused transform, in the user's words; for a scale that would take a or b
        past its limits, the scales that would work."""
        prim = self.doc.selected
        name = prim.name if prim is not None else "The primitive"
        field = getattr(exc, "field", "") or ""
        if (prim is not None and isinstance(exc, InvalidPrimitiveError)
                and field in ("profile.a", "profile.b")):
            lo = max(A_RANGE[0] / prim.a, B_RANGE[0] / prim.b)
            hi = min(A_RANGE[1] / prim.a, B_RANGE[1] / prim.b)
            which = "wider" if scale > 1.0 else "thinner"
            limit = A_RANGE[1] if scale > 1.0 else A_RANGE[0]
            return (f"{name} was not scaled: {scale:g}× would make its profile {which} "
                    f"than the limit ({limit:g}). Scale by {lo:.3g}× to {hi:.3g}×, or untick "
                    "'Scale the profile (a, b) too' to scale only its axis.")
        return refusal_text(exc, name)

    def reset_transform(self) -> None:
        for s in (*self.translate_spins, *self.rotate_spins):
            s.setValue(0.0)
        self.scale_spin.setValue(1.0)


# -- fitting ----------------------------------------------------------------------------------

LOSS_COLORS = ("#1f77b4", "#d62728", "#2ca02c", "#9467bd", "#ff7f0e", "#8c564b", "#17becf")


def total_loss(losses: dict[str, float]) -> float:
    """The total from a losses dict: its 'total' or 'loss' entry, else the sum."""
    for key in ("total", "loss"):
        if key in losses:
            return float(losses[key])
    return float(sum(losses.values()))


class LossPlot(QWidget):
    """Loss curves (log scale) drawn with QPainter: the total bold, the terms thin."""

    def __init__(self, parent: QWidget | None = None) -> None:
        super().__init__(parent)
        self.setMinimumHeight(120)
        self.setSizePolicy(QSizePolicy.Policy.Expanding, QSizePolicy.Policy.Expanding)
        self.iterations: list[int] = []
        self.series: dict[str, list[float]] = {}

    def clear(self) -> None:
        self.iterations = []
        self.series = {}
        self.update()

    def add(self, batch: Sequence[tuple[int, dict[str, float]]]) -> None:
        for iteration, losses in batch:
            self.iterations.append(int(iteration))
            values = dict(losses)
            values.setdefault("total", total_loss(losses))
            for key, value in values.items():
                s = self.series.setdefault(key, [math.nan] * (len(self.iterations) - 1))
                s.append(float(value))
            for s in self.series.values():
                if len(s) < len(self.iterations):
                    s.append(math.nan)
        self.update()

    def paintEvent(self, _event: Any) -> None:  # noqa: N802 (Qt API)
        p = QPainter(self)
        p.setRenderHint(QPainter.RenderHint.Antialiasing)
        p.fillRect(self.rect(), self.palette().base())
        small = QFont(self.font())
        small.setPointSizeF(max(6.5, small.pointSizeF() * 0.8))
        p.setFont(small)
        line = p.fontMetrics().height()
        # Legend on top, value labels on the left, iteration below: none over the curves.
        rect = QRectF(self.rect()).adjusted(40, line + 6, -6, -line - 2)
        p.setPen(QPen(QColor("#c8c8c8"), 1))
        p.drawRect(rect)
        if len(self.iterations) < 2:
            p.setPen(QColor("#888888"))
            p.drawText(rect, Qt.AlignmentFlag.AlignCenter, "loss curves appear here")
            p.end()
            return
        with np.errstate(divide="ignore", invalid="ignore"):
            # Log scale; zero or negative terms (no overlap yet) leave gaps, not a floor.
            logs = {k: np.where(np.asarray(v, float) > 0, np.log10(np.asarray(v, float)),
                                np.nan) for k, v in self.series.items()}
        finite = np.concatenate([v[np.isfinite(v)] for v in logs.values()])
        if not len(finite):
            p.end()
            return
        lo, hi = float(finite.min()), float(finite.max())
        if hi - lo < 1e-6:
            lo, hi = lo - 0.5, hi + 0.5
        it = np.asarray(self.iterations, float)
        x0, x1 = it[0], max(it[-1], it[0] + 1)

        def to_point(i: float, v: float) -> QPointF:
            return QPointF(rect.left() + (i - x0) / (x1 - x0) * rect.width(),
                           rect.bottom() - (v - lo) / (hi - lo) * rect.height())

        keys = [k for k in logs if k != "total"] + ["total"]
        legend_x = rect.left()
        for n, key in enumerate(keys):
            color = QColor("#222222" if key == "total" else LOSS_COLORS[n % len(LOSS_COLORS)])
            p.setPen(QPen(color, 2.0 if key == "total" else 1.2))
            points = [to_point(i, v) for i, v in zip(it, logs[key], strict=True)
                      if math.isfinite(v)]
            if len(points) > 1:
                p.drawPolyline(QPolygonF(points))
            p.drawText(QPointF(legend_x, line), key)
            legend_x += p.fontMetrics().horizontalAdvance(key) + 8
        p.setPen(QColor("#666666"))
        p.drawText(QRectF(0, rect.top() - line / 2, 37, line), Qt.AlignmentFlag.AlignRight,
                   f"{10 ** hi:.2g}")
        p.drawText(QRectF(0, rect.bottom() - line / 2, 37, line), Qt.AlignmentFlag.AlignRight,
                   f"{10 ** lo:.2g}")
        p.drawText(QRectF(rect.left(), rect.bottom() + 1, rect.width(), line),
                   Qt.AlignmentFlag.AlignRight, f"iteration {int(it[-1])}  (log scale)")
        p.end()


class FitPanel(QWidget):
    """Fit settings, Start / Cancel, progress with the current losses and a loss plot.

    start_requested(dict) carries the FitSettings values; cancel_requested()."""

    start_requested = Signal(dict)
    cancel_requested = Signal()
    refit_requested = Signal()

    def __init__(self, defaults: dict[str, Any] | None = None,
                 parent: QWidget | None = None) -> None:
        super().__init__(parent)
        # FitSettings' defaults; not read from it, which would import torch (seconds).
        d = {"primitives": 8, "iterations": 300, "sweeper": "analytic", "seed": 0,
             "restarts": 1, "refine_iterations": None, "method": "direct",
             "time_limit": None, "device": "auto"}
        d.update(defaults or {})
        self.primitives = QSpinBox()
        self.primitives.setRange(1, 32)
        self.primitives.setValue(int(d["primitives"]))
        self.primitives.setToolTip("how many primitives the fit may use (unlocked ones)")
        self.method = QComboBox()
        for text, method in FIT_METHODS:
            self.method.addItem(text, method)
        self.method.setCurrentIndex(max(0, self.method.findData(d["method"])))
        self.method.setToolTip("direct: the skeleton's warm start refined directly (seconds); "
                               "network: SweepNet's per-shape network stage first "
                               "(Iterations steps), then the same refinement")
        self.method.currentIndexChanged.connect(lambda _i: self._enable_inputs())
        self.time_limit = QDoubleSpinBox()
        # The minimum, shown as "none", stands for no limit (FitSettings' None).
        self.time_limit.setRange(0.0, 3600.0)
        self.time_limit.setDecimals(1)
        self.time_limit.setSingleStep(5.0)
        self.time_limit.setSuffix(" s")
        self.time_limit.setSpecialValueText("none")
        self.time_limit.setValue(float(d["time_limit"] or 0.0))
        self.time_limit.setToolTip("seconds for the whole fit; when they run out the best "
                                   "abstraction so far is kept; none: no limit")
        self.device = QComboBox()
        self.device.addItems(["auto", "cpu", "cuda"])
        self.device.setCurrentText(str(d["device"]))
        self.device.setToolTip("where the fit runs: auto uses a CUDA GPU when torch sees one")
        self.iterations = QSpinBox()
        self.iterations.setRange(1, 100000)
        self.iterations.setSingleStep(100)
        self.iterations.setValue(int(d["iterations"]))
        self.iterations.setToolTip("steps of the network stage (method network only)")
        self.refine_iterations = QSpinBox()
        # The minimum, shown as "auto", stands for FitSettings' default (None): 300 steps
        # per 8 primitives.
        self.refine_iterations.setRange(-1, 100000)
        self.refine_iterations.setSpecialValueText("auto")
        self.refine_iterations.setSingleStep(50)
        refine = d["refine_iterations"]
        self.refine_iterations.setValue(-1 if refine is None else int(refine))
        self.refine_iterations.setToolTip("steps of direct refinement of the primitives after "
                                          "the warm start (or the network stage), and of each "
                                          "round that adds primitives where the shape is "
                                          "missed (half as many); 0 skips it; auto: 300 per 8 "
                                          "primitives")
        self.sweeper = QComboBox()
        self.sweeper.addItems(["analytic", "neural"])
        self.sweeper.setCurrentText(str(d["sweeper"]))
        self.sweeper.setToolTip("analytic: soft exact sweeper; neural: the trained network "
                                "(network stage only)")
        self.seed = QSpinBox()
        self.seed.setRange(0, 2**31 - 1)
        self.seed.setValue(int(d["seed"]))
        self.restarts = QSpinBox()
        self.restarts.setRange(1, 64)
        self.restarts.setValue(int(d["restarts"]))

        # Two settings to a row where they fit: the panel must stay short enough for the
        # window to fit small screens.
        def row(*widgets: QWidget | str) -> QHBoxLayout:
            layout = QHBoxLayout()
            for w in widgets:
                if isinstance(w, str):
                    layout.addWidget(QLabel(w))
                else:
                    layout.addWidget(w, 1)
            return layout

        form = QFormLayout()
        form.addRow("Primitives", row(self.primitives, "time limit", self.time_limit))
        form.addRow("Method", row(self.method, "on", self.device))
        form.addRow("Iterations", row(self.iterations, "refine", self.refine_iterations))
        form.addRow("Sweeper", self.sweeper)
        form.addRow("Seed", row(self.seed, "restarts", self.restarts))

        self.start_button = QPushButton("Start fit")
        self.start_button.setToolTip("Fit primitives to the shape in the background; "
                                     "locked primitives stay as they are")
        self.cancel_button = QPushButton("Cancel")
        self.cancel_button.setToolTip("Stop and keep the best result so far")
        self.start_button.clicked.connect(lambda: self.start_requested.emit(self.values()))
        self.cancel_button.clicked.connect(self.cancel_requested)
        buttons = QHBoxLayout()
        buttons.addWidget(self.start_button)
        buttons.addWidget(self.cancel_button)
        self.refit_button = QPushButton("Refit selection")
        self.refit_button.setToolTip("Fit only the selected primitives to what the others "
                                     "leave uncovered; the others stay exactly as they are")
        self.refit_button.clicked.connect(self.refit_requested)
        buttons.addWidget(self.refit_button)

        # The current stage's own fraction, in tenths of a percent.
        self.progress = QProgressBar()
        self.progress.setRange(0, PROGRESS_STEPS)
        self.progress.setValue(0)
        self.progress.setFormat("%p%")
        self.status = QLabel("Idle")
        self.status.setWordWrap(True)
        mono = QFont("monospace")
        mono.setStyleHint(QFont.StyleHint.Monospace)
        mono.setPointSizeF(max(7.0, self.font().pointSizeF() * 0.9))
        self.losses = QLabel("")
        self.losses.setFont(mono)
        self.losses.setWordWrap(True)
        self.plot = LossPlot()

        layout = QVBoxLayout(self)
        layout.setContentsMargins(6, 6, 6, 6)
        layout.addLayout(form)
        layout.addLayout(buttons)
        layout.addWidget(self.progress)
        layout.addWidget(self.status)
        layout.addWidget(self.losses)
        layout.addWidget(self.plot, 1)
        self.set_running(False)

    def values(self) -> dict[str, Any]:
        """The settings as FitSettings fields (make_settings turns them into one)."""
        return {"primitives": self.primitives.value(), "method": self.method.currentData(),
                "time_limit": self.time_limit.value() or None,
                "device": self.device.currentText(), "iterations": self.iterations.value(),
                "refine_iterations": (None if self.refine_iterations.value() < 0
                                      else self.refine_iterations.value()),
                "sweeper": self.sweeper.currentText(), "seed": self.seed.value(),
                "restarts": self.restarts.value()}

    def _inputs(self) -> tuple[QWidget, ...]:
        return (self.primitives, self.method, self.time_limit, self.device, self.iterations,
                self.refine_iterations, self.sweeper, self.seed, self.restarts)

    def _enable_inputs(self) -> None:
        running = self.cancel_button.isEnabled()
        for w in self._inputs():
            w.setEnabled(not running)
        # Only the network stage has iterations and a choice of sweeper.
        network = self.method.currentData() == "network"
        self.iterations.setEnabled(not running and network)
        self.sweeper.setEnabled(not running and network)

    def set_running(self, running: bool) -> None:
        self.start_button.setEnabled(not running)
        self.refit_button.setEnabled(not running)
        self.cancel_button.setEnabled(running)
        self._enable_inputs()

    def begin(self) -> None:
        self.plot.clear()
        self.progress.setValue(0)
        self.losses.setText("")
        self.status.setText("Starting…")
        self.set_running(True)

    def show_progress(self, update: FitUpdate) -> None:
        """Show a fit's progress: its stage, the stage's fraction (the bar), the time left
        and the latest losses."""
        # QProgressBar.setValue repaints synchronously, which recomposes the whole window
        # (3D view included: ~45 ms on software GL); an ordinary deferred update instead
        # joins the one repaint the preview asks for anyway.
        self.progress.setUpdatesEnabled(False)
        self.progress.setValue(round(update.stage_fraction * PROGRESS_STEPS))
        self.progress.setUpdatesEnabled(True)
        self.progress.update()
        self.status.setText(progress_text(update))
        if update.losses:
            losses = update.losses[-1][1]
            self.losses.setText("  ".join(f"{k} {v:.4g}" for k, v in losses.items()))
            self.plot.add(update.losses)

    def finish(self, message: str) -> None:
        self.status.setText(message)
        self.set_running(False)
