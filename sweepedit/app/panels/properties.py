"""The selected primitive's properties: control points, profile, scaling, transform."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from PySide6.QtCore import QSignalBlocker, Qt
from PySide6.QtGui import QColor
from PySide6.QtWidgets import (
    QCheckBox,
    QColorDialog,
    QFormLayout,
    QGridLayout,
    QGroupBox,
    QHBoxLayout,
    QLabel,
    QPushButton,
    QVBoxLayout,
    QWidget,
)

from sweepedit.app.commands import (
    CommandStack,
    affine_matrix,
    move_control_point,
    selection_pivot,
    set_field,
    transform_primitives,
)
from sweepedit.app.document import DISPLAY, GEOMETRY, META, Document
from sweepedit.app.panels.editing import PanelEditor, document_links, refusal_text
from sweepedit.app.widgets.color_swatch import color_icon
from sweepedit.app.widgets.property_spin_box import number_box
from sweepedit.app.widgets.slider_spin import SliderSpin
from sweepedit.errors import InvalidPrimitiveError, SweepeditError
from sweepedit.geometry.model import A_RANGE, B_RANGE, DEGREE_RANGE, SCALING_RANGE

CONTROL_POINT_RANGE = (-1.0, 1.0)  # wider than the fitted [-0.5, 0.5] so users can reach out


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
        self.editor = PanelEditor(doc, stack, report)
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
        self.translate_spins = [number_box(-1, 1, 3, 0.01) for _ in range(3)]
        self.rotate_spins = [number_box(-360, 360, 1, 5, "°") for _ in range(3)]
        self.scale_spin = number_box(0.05, 20, 3, 0.05, "×")
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

        # Let go when destroyed, or when the window closes (it calls disconnect_all).
        self.document_links = links = document_links(self)
        links.connect(doc.selection_changed, lambda _i: self.refresh())
        links.connect(doc.primitives_reset, self.refresh)
        links.connect(doc.primitive_changed, self._on_primitive_changed)
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
