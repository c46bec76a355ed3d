"""The primitives list: swatch, name, visibility and lock of each primitive."""

from __future__ import annotations

from collections.abc import Callable, Sequence

from PySide6.QtCore import Qt
from PySide6.QtGui import QAction
from PySide6.QtWidgets import (
    QAbstractItemView,
    QHBoxLayout,
    QHeaderView,
    QToolButton,
    QTreeWidget,
    QTreeWidgetItem,
    QVBoxLayout,
    QWidget,
)

from sweepedit.app.commands import CommandStack, set_field, set_field_many
from sweepedit.app.document import DISPLAY, GEOMETRY, META, Document
from sweepedit.app.panels.editing import PanelEditor, document_links
from sweepedit.app.widgets.color_swatch import color_icon


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
        self.editor = PanelEditor(doc, stack, report)
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
        # Let go when destroyed, or when the window closes (it calls disconnect_all).
        self.document_links = links = document_links(self)
        links.connect(doc.primitives_reset, self.rebuild)
        links.connect(doc.primitive_changed, self._on_primitive_changed)
        links.connect(doc.selection_changed, self._on_selection_changed)
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
        # Qt cannot tell two icons apart, so a new one repaints the row: only when the
        # colour changed (not on every move of a drag).
        if item.data(self.COL_NAME, Qt.ItemDataRole.UserRole) != prim.color:
            item.setData(self.COL_NAME, Qt.ItemDataRole.UserRole, prim.color)
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

