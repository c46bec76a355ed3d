"""The main window: menus, toolbar, the 3D view, side panels and status bar with live
metrics, wired to the document, its files (sweepedit.app.file_control), the background
fit (sweepedit.app.fit_control) and the heat map.

Errors reach the user through `report_error` and questions through `ask_save_changes`,
`ask_keep_primitives` and `ask_recover`; tests replace these methods so that no modal
dialog ever blocks them.
"""

from __future__ import annotations

import sys
import traceback
from pathlib import Path
from typing import Any

import pyvista as pv
from PySide6.QtCore import QBuffer, QByteArray, QIODevice, QPoint, QRect, QSettings, Qt, QTimer
from PySide6.QtGui import (
    QAction,
    QCloseEvent,
    QDragEnterEvent,
    QDropEvent,
    QImage,
    QKeySequence,
    QPainter,
)
from PySide6.QtWidgets import (
    QCheckBox,
    QDockWidget,
    QFileDialog,
    QLabel,
    QMainWindow,
    QMessageBox,
    QScrollArea,
    QSlider,
    QWidget,
)

from sweepedit.app.autosave import Autosaver, Recovery
from sweepedit.app.commands import (
    AddPrimitive,
    CommandStack,
    DeletePrimitive,
    DeletePrimitives,
    duplicate_primitive,
    mirror_selection,
    new_primitive,
    set_field_many,
)
from sweepedit.app.document import Connections, Document
from sweepedit.app.file_control import FileControl, save_failure_text
from sweepedit.app.fit_control import FitControl
from sweepedit.app.heatmap_view import HeatMapView
from sweepedit.app.panels import FitPanel, PrimitiveListPanel, PropertiesPanel
from sweepedit.app.scene import SweepScene
from sweepedit.app.scene_mouse import SceneMouse
from sweepedit.app.worker import (
    MetricsRunner,
    favour_gui_thread,
    preload_fit_api,
)
from sweepedit.errors import SweepeditError
from sweepedit.io.params import is_parameter_file

APP_NAME = "SweepEdit"
MULTI_SAMPLES = 0  # anti-aliasing: FXAA, and only on a GPU (see _check_antialiasing)
SOFTWARE_GL = ("llvmpipe", "softpipe", "swrast", "swiftshader", "software rasterizer")
HELP_TEXT = """<b>Mouse</b><br>
Left-drag: rotate · Shift+left-drag or middle-drag: pan · wheel / right-drag: zoom<br>
Click a primitive to select it (Ctrl/Shift+click: add to the selection); drag its white
handles to move its axis control points (in the view plane; during a drag X/Y/Z keep it
on that axis, Shift+X/Y/Z in the plane across it, Ctrl snaps to 0.01, Esc puts the point
back). Right-click: insert a control point on the axis or delete the one under the
cursor.<br><br>
<b>Keys</b><br>
Ctrl+N new · Ctrl+W close · Ctrl+O open shape · Ctrl+Shift+O open parameters ·
Ctrl+S save · Ctrl+Shift+S save as<br>
Ctrl+Z undo · Ctrl+Shift+Z / Ctrl+Y redo · Ctrl+Shift+N add · Ctrl+D duplicate ·
Delete delete<br>
F fit view · T show/hide the target shape · Enter in the transform section applies it<br>
Ctrl+A select all · I insert a control point · Shift+Del delete the control point under
the cursor · H hide · L lock · Ctrl+Alt+X/Y/Z mirror the selection · Shift+M
symmetric editing<br>
Numpad 1/3/7 front/right/top (Ctrl: back/left/bottom) · 9 isometric · 5 orthographic ·
. frame the selection"""


def _png_bytes(image: QImage) -> bytes:
    data = QByteArray()
    buffer = QBuffer(data)
    buffer.open(QIODevice.OpenModeFlag.WriteOnly)
    image.save(buffer, "PNG")
    buffer.close()
    return bytes(data.data())


class MainWindow(QMainWindow):
    """SweepEdit's main window. `settings` defaults to the user's QSettings (recent files);
    `preload_fit`: import the fitting code in the background once the window is shown;
    `recovery_dir`: where the autosave writes its recovery file (default: the user's
    application data folder, sweepedit.app.autosave)."""

    def __init__(self, settings: QSettings | None = None, parent: QWidget | None = None,
                 preload_fit: bool = True, recovery_dir: Path | None = None) -> None:
        super().__init__(parent)
        favour_gui_thread()
        self.preload_fit = preload_fit
        from sweepedit.app.view3d import make_view  # heavy import, only when a window is made

        self.settings = settings if settings is not None else QSettings("sweepedit", "sweepedit")
        self.doc = Document()
        self.doc.on_view_error = self.view_failed
        self.stack = CommandStack(self.doc)
        self.autosave = Autosaver(self.doc, recovery_dir, parent=self,
                                  report=lambda message: self.show_status(message, 15000))
        # One headlight instead of pyvista's five-light kit: lighting is per fragment and
        # software GL (no GPU) pays for every light on every pixel.
        self.plotter = make_view(self, multi_samples=MULTI_SAMPLES, lighting="none")
        self.plotter.add_light(pv.Light(light_type="headlight", intensity=1.0))
        self._antialiasing_checked = False
        self.plotter.setAcceptDrops(False)  # drops go to the window (pyvistaqt would add meshes)
        self.setCentralWidget(self.plotter)
        self.plotter.add_axes(interactive=False, line_width=2)
        self.scene = SweepScene(self.plotter, self.doc, self.stack)
        self.mouse = SceneMouse(self.scene, self.plotter)
        self.scene.report = self.show_status
        self.heatmap = HeatMapView(self.scene, self.doc, self)
        self.heatmap.failed.connect(lambda m: self.show_status(f"Heat map unavailable: {m}"))
        self.files = FileControl(self.doc, self.stack, self.autosave, self.settings,
                                 prompts=self, busy=lambda: self.fitting,
                                 reset_view=self.scene.reset_camera)

        self.last_metrics: dict | None = None

        self._make_actions()
        self._make_menus()
        self._make_toolbar()
        self._make_docks()
        self._make_status_bar()
        self.fit_control = FitControl(self.doc, self.stack, self.scene, self.fit_panel,
                                      prompts=self, parent=self)
        self.fit_control.running_changed.connect(self._on_fit_running)

        self.metrics = MetricsRunner(self)
        self.metrics.updated.connect(self._on_metrics)
        self.metrics.failed.connect(self._on_metrics_failed)
        self.metrics.busy.connect(self._on_metrics_busy)
        self._links = Connections()
        self._links.connect(self.doc.edited, self._schedule_metrics)
        self._links.connect(self.doc.dirty_changed, lambda _d: self._update_title())
        self._links.connect(self.doc.path_changed, self._update_title)
        self._links.connect(self.doc.selection_changed, lambda _i: self._update_actions())
        self._links.connect(self.doc.primitives_reset, self._update_actions)
        self._links.connect(self.doc.shape_changed, self._update_actions)
        self.stack.changed.connect(self._update_actions)

        self.setAcceptDrops(True)
        self.resize(1500, 940)
        self._update_title()
        self._update_actions()
        self._schedule_metrics()
        self.statusBar().showMessage("Click a primitive to select it, drag its handles to edit; "
                                     "Help ▸ Mouse and keys lists the controls.", 8000)

    # -- construction ---------------------------------------------------------------------
    def _action(self, text: str, slot: Any, shortcut: Any = None, tip: str = "") -> QAction:
        action = QAction(text, self)
        if shortcut is not None:
            if isinstance(shortcut, list | tuple):
                action.setShortcuts([QKeySequence(s) for s in shortcut])
            else:
                action.setShortcut(QKeySequence(shortcut))
        if tip:
            action.setStatusTip(tip)
            action.setToolTip(tip)
        action.triggered.connect(lambda _checked=False: slot())
        self.addAction(action)  # shortcuts work wherever the focus is in the window
        return action

    def _make_actions(self) -> None:
        A = self._action
        self.act_new = A("&New", self.files.new_document, QKeySequence.StandardKey.New,
                         "Start anew: no shape, no primitives (asks to save changes first)")
        self.act_close = A("&Close", self.files.close_document, QKeySequence.StandardKey.Close,
                           "Close the shape and the primitives (asks to save changes first)")
        self.act_open_shape = A("Open &shape…", self.files.open_shape_dialog,
                                QKeySequence.StandardKey.Open,
                                "Open a mesh, voxel grid or point cloud as the target shape")
        self.act_open_params = A("Open &parameters…", self.files.open_params_dialog,
                                 "Ctrl+Shift+O",
                                 "Open primitives (.json or official SweepNet .txt)")
        self.act_save = A("&Save", self.files.save, QKeySequence.StandardKey.Save,
                          "Save the primitives")
        self.act_save_as = A("Save &As…", self.files.save_as, "Ctrl+Shift+S",
                             "Save the primitives under a new name")
        self.act_export_union = A("Export mesh (&union)…",
                                  lambda: self.files.export_mesh_dialog(False),
                                  tip="Export the union of the visible primitives as one mesh")
        self.act_export_parts = A("Export mesh (&per primitive)…",
                                  lambda: self.files.export_mesh_dialog(True),
                                  tip="Export each visible primitive as its own part")
        self.act_export_txt = A("Export official &txt…", self.files.export_txt_dialog,
                                tip="Write SweepNet's primitive_parameters.txt format")
        self.act_export_step = A("One solid per &primitive…",
                                 lambda: self.files.export_step_dialog(False),
                                 tip="Export each visible primitive as a smooth, named, "
                                     "coloured CAD solid in one STEP file")
        self.act_export_step_union = A("&Fused into one solid…",
                                       lambda: self.files.export_step_dialog(True),
                                       tip="Export the union of the visible primitives as "
                                           "one smooth CAD solid in a STEP file")
        self.act_screenshot = A("Save scree&nshot…", self.screenshot_dialog,
                                tip="Save the 3D view as a PNG image")
        self.act_quit = A("&Quit", self.close, QKeySequence.StandardKey.Quit)

        self.act_undo = A("&Undo", self.stack.undo, QKeySequence.StandardKey.Undo)
        self.act_redo = A("&Redo", self.stack.redo, ["Ctrl+Shift+Z", "Ctrl+Y"])
        self.act_add = A("&Add primitive", self.add_primitive, "Ctrl+Shift+N",
                         "Add a straight primitive at the origin")
        self.act_duplicate = A("&Duplicate primitive", self.duplicate_primitive, "Ctrl+D",
                               "Duplicate the selected primitive")
        self.act_delete = A("De&lete primitive", self.delete_primitive,
                            QKeySequence.StandardKey.Delete, "Delete the selected primitive")
        self.act_add.setIconText("Add")
        self.act_duplicate.setIconText("Duplicate")
        self.act_delete.setIconText("Delete")

        self.act_show_shape = A("Show target &shape", self.toggle_shape, "T",
                                "Show or hide the target shape")
        self.act_show_shape.setCheckable(True)
        self.act_show_shape.setChecked(True)
        self.act_reset_camera = A("&Fit view", self.scene.reset_camera, "F",
                                  "Reset the camera to show everything")
        self.act_heatmap = A("&Heat map of the error", self.toggle_heatmap, tip=(
            "Colour the target by its distance to the primitives: red missed, blue excess"))
        self.act_heatmap.setCheckable(True)
        self.act_refit = A("&Refit selection", self.refit_selection, tip=(
            "Fit the selected primitives to what the others leave uncovered; the others "
            "stay exactly as they are"))
        self.act_help = A("&Mouse and keys", self.show_help, QKeySequence.StandardKey.HelpContents)
        self._make_editing_actions()

    def _make_menus(self) -> None:
        bar = self.menuBar()
        file_menu = bar.addMenu("&File")
        file_menu.addAction(self.act_new)
        file_menu.addAction(self.act_open_shape)
        file_menu.addAction(self.act_open_params)
        self.recent_menu = file_menu.addMenu("Recent &files")
        self.recent_menu.aboutToShow.connect(
            lambda: self.files.fill_recent_menu(self.recent_menu))
        file_menu.addSeparator()
        file_menu.addAction(self.act_save)
        file_menu.addAction(self.act_save_as)
        file_menu.addSeparator()
        file_menu.addAction(self.act_export_union)
        file_menu.addAction(self.act_export_parts)
        step_menu = file_menu.addMenu("Export &STEP (CAD solids)")
        step_menu.addAction(self.act_export_step)
        step_menu.addAction(self.act_export_step_union)
        file_menu.addAction(self.act_export_txt)
        file_menu.addAction(self.act_screenshot)
        file_menu.addSeparator()
        file_menu.addAction(self.act_close)
        file_menu.addAction(self.act_quit)
        edit_menu = bar.addMenu("&Edit")
        for a in (self.act_undo, self.act_redo, None, self.act_add, self.act_duplicate,
                  self.act_delete):
            edit_menu.addSeparator() if a is None else edit_menu.addAction(a)
        edit_menu.addSeparator()
        edit_menu.addAction(self.act_refit)
        view_menu = bar.addMenu("&View")
        view_menu.addAction(self.act_show_shape)
        view_menu.addAction(self.act_reset_camera)
        view_menu.addAction(self.act_heatmap)
        self.view_menu = view_menu
        self._add_editing_menus(edit_menu, view_menu)
        help_menu = bar.addMenu("&Help")
        help_menu.addAction(self.act_help)

    def _make_toolbar(self) -> None:
        tb = self.addToolBar("Main")
        tb.setObjectName("main-toolbar")
        tb.setMovable(False)
        self.act_open_shape.setIconText("Open shape")
        self.act_open_params.setIconText("Open params")
        for a in (self.act_open_shape, self.act_open_params, self.act_save, None, self.act_undo,
                  self.act_redo, None, self.act_add, self.act_duplicate, self.act_delete, None):
            tb.addSeparator() if a is None else tb.addAction(a)
        self.shape_check = QCheckBox("Target")
        self.shape_check.setChecked(True)
        self.shape_check.setToolTip("Show the target shape (T)")
        self.shape_check.toggled.connect(self.set_shape_visible)
        tb.addWidget(self.shape_check)
        self.opacity_slider = QSlider(Qt.Orientation.Horizontal)
        self.opacity_slider.setRange(0, 100)
        self.opacity_slider.setValue(round(self.scene.shape_opacity * 100))
        self.opacity_slider.setFixedWidth(110)
        self.opacity_slider.setToolTip("Opacity of the target shape")
        self.opacity_slider.valueChanged.connect(lambda v: self.scene.set_shape_opacity(v / 100))
        tb.addWidget(QLabel(" opacity "))
        tb.addWidget(self.opacity_slider)
        tb.addSeparator()
        tb.addAction(self.act_reset_camera)

    def _make_docks(self) -> None:
        report = self.show_status
        self.list_panel = PrimitiveListPanel(
            self.doc, self.stack, [self.act_add, self.act_duplicate, self.act_delete], report)
        self.props_panel = PropertiesPanel(self.doc, self.stack, report)
        self.fit_panel = FitPanel()
        self.fit_panel.start_requested.connect(self.start_fit)
        self.fit_panel.cancel_requested.connect(self.cancel_fit)
        self.fit_panel.refit_requested.connect(lambda: self.refit_selection())

        def dock(title: str, widget: QWidget, area: Qt.DockWidgetArea) -> QDockWidget:
            d = QDockWidget(title, self)
            d.setObjectName(title.lower())
            d.setWidget(widget)
            d.setFeatures(QDockWidget.DockWidgetFeature.DockWidgetMovable
                          | QDockWidget.DockWidgetFeature.DockWidgetFloatable)
            self.addDockWidget(area, d)
            return d

        left = Qt.DockWidgetArea.LeftDockWidgetArea
        self.list_dock = dock("Primitives", self.list_panel, left)
        self.fit_dock = dock("Fit", self.fit_panel, left)
        scroll = QScrollArea()
        scroll.setWidgetResizable(True)
        scroll.setWidget(self.props_panel)
        scroll.setMinimumWidth(self.props_panel.sizeHint().width() + 24)
        self.props_dock = dock("Properties", scroll, Qt.DockWidgetArea.RightDockWidgetArea)
        self.resizeDocks([self.list_dock, self.fit_dock], [330, 520], Qt.Orientation.Vertical)
        self.resizeDocks([self.list_dock], [310], Qt.Orientation.Horizontal)

    def _make_status_bar(self) -> None:
        self.metrics_label = QLabel("")
        self.metrics_label.setMinimumWidth(380)
        self.metrics_label.setAlignment(Qt.AlignmentFlag.AlignRight | Qt.AlignmentFlag.AlignVCenter)
        self.statusBar().addPermanentWidget(self.metrics_label)

    def showEvent(self, event: Any) -> None:  # noqa: N802 (Qt API)
        super().showEvent(event)
        if not self._antialiasing_checked:
            self._antialiasing_checked = True
            QTimer.singleShot(0, self._check_antialiasing)
            if self.preload_fit:
                # torch takes seconds to import: start now, in the background, so that it
                # is normally there by the time the user presses Start.
                QTimer.singleShot(0, preload_fit_api)

    def _check_antialiasing(self) -> None:
        """FXAA costs ~50 ms a frame on software GL (Xvfb, VMs) but nothing on a GPU."""
        try:
            caps = self.plotter.render_window.ReportCapabilities().lower()
        except Exception:
            return
        if caps and not any(name in caps for name in SOFTWARE_GL):
            self.plotter.enable_anti_aliasing("fxaa")
            self.scene.request_render()

    # -- user feedback (tests replace report_error and ask_save_changes) -------------------
    def report_error(self, title: str, message: str) -> None:
        """Show an error; the app goes on."""
        QMessageBox.critical(self, title, message)

    def ask_save_changes(self) -> str:
        """'save', 'discard' or 'cancel' for unsaved changes."""
        box = QMessageBox(QMessageBox.Icon.Warning, APP_NAME,
                          f"Save changes to {self.doc.display_name()}?",
                          QMessageBox.StandardButton.Save | QMessageBox.StandardButton.Discard
                          | QMessageBox.StandardButton.Cancel, self)
        box.setDefaultButton(QMessageBox.StandardButton.Save)
        answer = box.exec()
        return {QMessageBox.StandardButton.Save: "save",
                QMessageBox.StandardButton.Discard: "discard"}.get(
                    QMessageBox.StandardButton(answer), "cancel")

    def ask_keep_primitives(self, shape_name: str) -> str:
        """'keep', 'discard' or 'cancel': what happens to the primitives shown when another
        shape is opened."""
        n = len(self.doc)
        box = QMessageBox(QMessageBox.Icon.Question, APP_NAME,
                          f"Keep the {n} primitive{'s' if n != 1 else ''} for {shape_name}?",
                          QMessageBox.StandardButton.NoButton, self)
        box.setInformativeText("Keep: edit them against the new shape (saving then records "
                               f"{shape_name} as their shape). Discard: start without "
                               "primitives.")
        keep = box.addButton("Keep", QMessageBox.ButtonRole.AcceptRole)
        discard = box.addButton("Discard", QMessageBox.ButtonRole.DestructiveRole)
        box.addButton(QMessageBox.StandardButton.Cancel)
        box.setDefaultButton(keep)
        box.exec()
        clicked = box.clickedButton()
        return "keep" if clicked is keep else "discard" if clicked is discard else "cancel"

    def ask_recover(self, recovery: Recovery) -> bool:
        """Whether to recover the unsaved edits an editor that is gone left behind."""
        box = QMessageBox(QMessageBox.Icon.Question, APP_NAME, recovery.question(),
                          QMessageBox.StandardButton.Yes | QMessageBox.StandardButton.No, self)
        box.setInformativeText("SweepEdit did not close normally. No: the edits stay "
                               "recoverable until this session autosaves its own.")
        box.setDefaultButton(QMessageBox.StandardButton.Yes)
        return box.exec() == QMessageBox.StandardButton.Yes

    def view_failed(self, exc: BaseException) -> None:
        """A view could not follow a change of the document (a defect in the view): the
        change stands and can be undone, the other views have followed it; the details
        go to stderr and a line to the status bar, never a dialog in the middle of a
        drag."""
        traceback.print_exception(exc, file=sys.stderr)
        self.show_status(f"The view could not show that change ({type(exc).__name__}: "
                         f"{exc}); the change is kept, and Ctrl+Z undoes it.", 15000)

    def show_status(self, message: str, timeout_ms: int = 6000) -> None:
        self.statusBar().showMessage(message, timeout_ms)

    def show_help(self) -> None:
        QMessageBox.information(self, f"{APP_NAME}: mouse and keys", HELP_TEXT)

    def _update_title(self) -> None:
        parts = [self.doc.display_name()]
        if self.doc.path is not None and self.doc.shape_path is not None:
            parts = [self.doc.path.name, f"on {self.doc.shape_path.name}"]
        self.setWindowTitle(f"{' '.join(parts)}[*] — {APP_NAME}")
        self.setWindowModified(self.doc.dirty)

    @property
    def fitting(self) -> bool:
        return self.fit_control.running

    def _update_actions(self) -> None:
        fitting = self.fitting
        has_sel = self.doc.selection is not None
        has_prims = len(self.doc) > 0
        self.act_undo.setEnabled(self.stack.can_undo and not fitting)
        self.act_redo.setEnabled(self.stack.can_redo and not fitting)
        # The menu names the step; the toolbar button keeps its width ("Undo").
        self.act_undo.setText(f"&Undo {self.stack.undo_text}".rstrip())
        self.act_redo.setText(f"&Redo {self.stack.redo_text}".rstrip())
        self.act_undo.setIconText("Undo")
        self.act_redo.setIconText("Redo")
        self.act_add.setEnabled(not fitting)
        self.act_new.setEnabled(not fitting)
        self.act_close.setEnabled(not fitting)
        self.act_duplicate.setEnabled(has_sel and not fitting)
        self.act_delete.setEnabled(has_sel and not fitting)
        self.act_refit.setEnabled(has_sel and not fitting and self.doc.shape is not None)
        for a in (self.act_open_shape, self.act_open_params):
            a.setEnabled(not fitting)
        for a in (self.act_save, self.act_save_as, self.act_export_txt):
            a.setEnabled(not fitting)
        for a in (self.act_export_union, self.act_export_parts, self.act_export_step,
                  self.act_export_step_union):
            a.setEnabled(has_prims and not fitting)
        self.list_panel.tree.setEnabled(not fitting)
        self._update_editing_actions()

    # -- files (sweepedit.app.file_control; tests and the CLI call these) ------------------
    def open_path(self, path: str | Path) -> bool:
        return self.files.open_path(path)

    def open_shape(self, path: str | Path, ask: bool = True) -> bool:
        return self.files.open_shape(path, ask)

    def open_params(self, path: str | Path, ask: bool = True) -> bool:
        return self.files.open_params(path, ask)

    def save_to(self, path: str | Path) -> bool:
        return self.files.save_to(path)

    def export_mesh(self, path: str | Path, per_primitive: bool = False) -> bool:
        return self.files.export_mesh(path, per_primitive)

    def export_step(self, path: str | Path, union: bool = False) -> bool:
        return self.files.export_step(path, union)

    def recent_files(self) -> list[str]:
        return self.files.recent_files()

    def offer_recovery(self, answer: bool | None = None) -> bool:
        return self.files.offer_recovery(answer)

    # -- screenshots ----------------------------------------------------------------------
    def screenshot_dialog(self) -> bool:
        start = self.doc.path or self.doc.shape_path
        suggestion = str(start.with_suffix(".png")) if start else "sweepedit.png"
        name, _ = QFileDialog.getSaveFileName(self, "Save screenshot", suggestion, "PNG (*.png)")
        if not name:
            return False
        return self.save_screenshot(name)

    def view_image(self) -> QImage:
        """The 3D view as rendered now."""
        self.scene.render_now()
        return self.plotter.grabFramebuffer()

    def window_image(self) -> QImage:
        """The whole window as shown. Qt's grab leaves a native 3D view out (VTK draws
        that window itself), so the view's frame is painted into its place."""
        image = self.grab().toImage()
        painter = QPainter(image)
        painter.drawImage(QRect(self.plotter.mapTo(self, QPoint(0, 0)), self.plotter.size()),
                          self.view_image())
        painter.end()
        return image

    def save_screenshot(self, path: str | Path, full_window: bool = False) -> bool:
        """Write the 3D view (or the whole window) as a PNG, atomically."""
        path = Path(path)
        try:
            image = self.window_image() if full_window else self.view_image()
            from sweepedit.io.params import atomic_write_bytes

            atomic_write_bytes(path, _png_bytes(image))
        except Exception as exc:
            self.report_error("Cannot save screenshot", save_failure_text(exc, path))
            return False
        self.show_status(f"Saved {path}")
        return True

    # -- drag and drop --------------------------------------------------------------------
    def dragEnterEvent(self, event: QDragEnterEvent) -> None:  # noqa: N802 (Qt API)
        if any(u.isLocalFile() for u in event.mimeData().urls()):
            event.acceptProposedAction()

    def dropEvent(self, event: QDropEvent) -> None:  # noqa: N802 (Qt API)
        paths = [Path(u.toLocalFile()) for u in event.mimeData().urls() if u.isLocalFile()]
        event.acceptProposedAction()
        # Shapes first, so that parameters dropped together with their shape get metrics.
        for p in sorted(paths, key=is_parameter_file):
            QTimer.singleShot(0, lambda p=p: self.open_path(p))

    # -- editing --------------------------------------------------------------------------
    def _push(self, command: Any) -> bool:
        if self.fitting:
            return False
        try:
            self.stack.push(command)
        except SweepeditError as exc:
            self.show_status(str(exc))
            return False
        return True

    def add_primitive(self) -> None:
        self._push(AddPrimitive(new_primitive(self.doc)))

    def duplicate_primitive(self) -> None:
        if self.doc.selection is not None:
            self._push(duplicate_primitive(self.doc, self.doc.selection))

    def delete_primitive(self) -> None:
        """Delete the selected primitives (one undo step)."""
        indices = list(self.doc.selected_indices)
        if len(indices) == 1:
            self._push(DeletePrimitive(indices[0]))
        elif indices:
            self._push(DeletePrimitives(indices))

    # -- multi-selection, control points, mirror, camera presets ---------------------------
    def _make_editing_actions(self) -> None:
        A = self._action
        self.act_select_all = A("Select &all", self.select_all, QKeySequence.StandardKey.SelectAll,
                                "Select every primitive")
        self.act_insert_cp = A("&Insert control point", lambda: self.scene.insert_control_point(),
                               "I", "Add a control point to the selected primitive's axis "
                               "(right-click the axis to choose where)")
        self.act_delete_cp = A("Delete control &point", lambda: self.scene.delete_control_point(),
                               "Shift+Del", "Delete the control point under the cursor "
                               "(at least 3 stay)")
        self.act_hide = A("&Hide / show selection", lambda: self.toggle_selection("visible"),
                          "H", "Hide the selected primitives (or show them if all are hidden)")
        self.act_lock = A("Loc&k / unlock selection", lambda: self.toggle_selection("locked"),
                          "L", "Lock the selected primitives (or unlock them if all are locked)")
        self.act_mirror = [A(f"Mirror &{c}", lambda a=a: self.mirror_selection(a),
                             f"Ctrl+Alt+{c}",  # Ctrl+Shift+Z is Redo
                             f"Add mirrored copies of the selection through the {c} = 0 plane "
                             "of the shape's frame")
                           for a, c in enumerate("XYZ")]
        self.act_symmetric = A("S&ymmetric editing", self.toggle_symmetric, "Shift+M",
                               "Edit a mirrored pair together: an edit of one is mirrored "
                               "onto the other")
        self.act_symmetric.setCheckable(True)
        keypad = Qt.KeyboardModifier.KeypadModifier
        ctrl = Qt.KeyboardModifier.ControlModifier

        def keys(key: Qt.Key, modifiers: Any = keypad) -> QKeySequence:
            return QKeySequence(modifiers | key)

        presets = (("&Front", "front", keys(Qt.Key.Key_1)),
                   ("&Back", "back", keys(Qt.Key.Key_1, keypad | ctrl)),
                   ("&Right", "right", keys(Qt.Key.Key_3)),
                   ("&Left", "left", keys(Qt.Key.Key_3, keypad | ctrl)),
                   ("&Top", "top", keys(Qt.Key.Key_7)),
                   ("Botto&m", "bottom", keys(Qt.Key.Key_7, keypad | ctrl)),
                   ("&Isometric", "isometric", keys(Qt.Key.Key_9)))
        self.act_views = {name: A(text, lambda name=name: self.scene.view_preset(name), key,
                                  f"Look at everything from the {name}")
                          for text, name, key in presets}
        self.act_ortho = A("&Orthographic", self.toggle_orthographic, keys(Qt.Key.Key_5),
                           "Orthographic (or perspective) projection")
        self.act_ortho.setCheckable(True)
        self.act_frame_selection = A("Frame &selection", self.scene.frame_selection,
                                     keys(Qt.Key.Key_Period),
                                     "Fit the view to the selected primitives")
        self.mouse.menu_actions = [None, *self.act_mirror, self.act_symmetric, None,
                                   self.act_hide, self.act_lock, self.act_frame_selection]

    def _add_editing_menus(self, edit_menu: Any, view_menu: Any) -> None:
        edit_menu.addSeparator()
        edit_menu.addAction(self.act_select_all)
        edit_menu.addAction(self.act_hide)
        edit_menu.addAction(self.act_lock)
        edit_menu.addSeparator()
        edit_menu.addAction(self.act_insert_cp)
        edit_menu.addAction(self.act_delete_cp)
        edit_menu.addSeparator()
        mirror_menu = edit_menu.addMenu("&Mirror")
        for a in self.act_mirror:
            mirror_menu.addAction(a)
        edit_menu.addAction(self.act_symmetric)
        camera_menu = view_menu.addMenu("&Camera")
        for a in self.act_views.values():
            camera_menu.addAction(a)
        camera_menu.addSeparator()
        camera_menu.addAction(self.act_ortho)
        camera_menu.addAction(self.act_frame_selection)

    def _update_editing_actions(self) -> None:
        editable = not self.fitting
        has_sel = bool(self.doc.selected_indices)
        for a in (self.act_hide, self.act_lock, *self.act_mirror):
            a.setEnabled(has_sel and editable)
        for a in (self.act_insert_cp, self.act_delete_cp):
            a.setEnabled(self.doc.selection is not None and editable)
        self.act_select_all.setEnabled(len(self.doc) > 0 and editable)
        self.act_delete.setText("De&lete primitives" if len(self.doc.selected_indices) > 1
                                else "De&lete primitive")
        self.act_delete.setIconText("Delete")

    def select_all(self) -> None:
        self.doc.set_selection(range(len(self.doc)), primary=self.doc.selection)

    def toggle_selection(self, field: str) -> None:
        """Hide or lock the whole selection in one undo step (show or unlock when every
        selected primitive already is)."""
        indices = list(self.doc.selected_indices)
        if not indices:
            return
        value = not all(getattr(self.doc.primitive(i), field) for i in indices)
        self.stack.close_merge()
        self._push(set_field_many(self.doc, indices, field, value))

    def mirror_selection(self, axis: int) -> None:
        """Mirrored copies of the selection through the x, y or z plane (one undo step)."""
        indices = list(self.doc.selected_indices)
        if not indices:
            self.show_status("Select the primitives to mirror first.")
            return
        self.stack.close_merge()
        if self._push(mirror_selection(self.doc, indices, axis)):
            self.show_status(f"Mirrored {len(indices)} primitive(s) through the "
                             f"{'XYZ'[axis]} = 0 plane; Shift+M edits each pair together")

    def toggle_symmetric(self) -> None:
        self.stack.symmetric = self.act_symmetric.isChecked()
        self.stack.close_merge()
        self.show_status("Symmetric editing on: an edit of one of a mirrored pair is made to "
                         "both" if self.stack.symmetric else "Symmetric editing off")

    def toggle_orthographic(self) -> None:
        self.scene.set_orthographic(self.act_ortho.isChecked())

    def toggle_shape(self) -> None:
        self.set_shape_visible(self.act_show_shape.isChecked())

    def toggle_heatmap(self) -> None:
        self.set_heatmap_visible(self.act_heatmap.isChecked())

    def set_heatmap_visible(self, visible: bool) -> bool:
        """Show or hide the heat map of the error (needs a target shape)."""
        shown = self.heatmap.set_visible(visible)
        if visible and not shown:
            self.show_status("Open a shape first: the heat map colours the target.")
        self.act_heatmap.setChecked(self.heatmap.visible)
        return shown

    def refit_selection(self, indices: list[int] | None = None) -> bool:
        """Refit the selected primitives (or `indices`) in the background, the others held
        exactly as they are; one undo step when it is applied."""
        if indices is None:
            indices = list(self.doc.selected_indices)
        if not indices:
            self.show_status("Select the primitives to refit first.")
            return False
        locked = [self.doc.primitive(i).name for i in indices if self.doc.primitive(i).locked]
        if locked:
            self.show_status(f"{locked[0]} is locked: unlock it to refit it.")
            return False
        return self.start_fit(self.fit_panel.values(), refit=sorted(indices))

    def set_shape_visible(self, visible: bool) -> None:
        self.scene.set_shape_visible(visible)
        for w in (self.act_show_shape, self.shape_check):
            if w.isChecked() != visible:
                w.blockSignals(True)
                w.setChecked(visible)
                w.blockSignals(False)

    # -- metrics --------------------------------------------------------------------------
    def _schedule_metrics(self) -> None:
        if self.doc.shape is None:
            self.metrics.cancel()
            self.metrics_label.setText("Open a shape to see IoU / CD")
            return
        if not len(self.doc):
            self.metrics.cancel()
            self.metrics_label.setText("No primitives")
            return
        self.metrics.request(lambda: (self.doc.abstraction, self.doc.shape))
        self._on_metrics_busy(True)

    def _on_metrics(self, result: dict) -> None:
        self.last_metrics = result
        f1 = result.get("f1_0.05")
        nan = float("nan")
        text = f"IoU {result.get('iou', nan):.3f}   CD-L1 {result.get('cd_l1', nan):.4f}"
        if f1 is not None:
            text += f"   F1@0.05 {f1:.3f}"
        self.metrics_label.setText(text)
        self.metrics_label.setToolTip(
            "Against the target shape, with a reduced sample count for speed:\n"
            + "\n".join(f"{k}: {v:.5g}" if isinstance(v, float) else f"{k}: {v}"
                        for k, v in result.items()))

    def _on_metrics_failed(self, message: str) -> None:
        self.metrics_label.setText("Metrics unavailable")
        self.metrics_label.setToolTip(message)

    def _on_metrics_busy(self, busy: bool) -> None:
        text = self.metrics_label.text().removesuffix("  …")
        self.metrics_label.setText(text + ("  …" if busy else ""))

    # -- fitting (sweepedit.app.fit_control runs it) --------------------------------------
    def start_fit(self, values: dict[str, Any], refit: list[int] | None = None) -> bool:
        """Start a background fit with the fit panel's values (or refit the primitives
        `refit`, the others held); False if it cannot start."""
        return self.fit_control.start(values, refit)

    def cancel_fit(self) -> None:
        self.fit_control.cancel()

    def _on_fit_running(self, running: bool) -> None:
        self.props_panel.set_editable(not running)
        self._update_actions()
        if running:
            self.metrics.cancel()

    # -- closing --------------------------------------------------------------------------
    def closeEvent(self, event: QCloseEvent) -> None:  # noqa: N802 (Qt API)
        if not self.files.maybe_save():
            event.ignore()
            return
        self.fit_control.shutdown()
        self.files.shutdown()
        self.metrics.shutdown()
        self.heatmap.close()
        self.scene.close()
        for panel in (self.list_panel, self.props_panel):
            panel.document_links.disconnect_all()
        self._links.disconnect_all()
        self.autosave.shutdown()  # a clean exit leaves no recovery file
        self.plotter.close()
        event.accept()
