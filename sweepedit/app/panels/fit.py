"""The fit panel: settings, start and cancel, progress and the loss plot."""

from __future__ import annotations

import math
from typing import Any

from PySide6.QtCore import Signal
from PySide6.QtGui import QFont
from PySide6.QtWidgets import (
    QCheckBox,
    QComboBox,
    QDoubleSpinBox,
    QFormLayout,
    QHBoxLayout,
    QLabel,
    QProgressBar,
    QPushButton,
    QSpinBox,
    QVBoxLayout,
    QWidget,
)

from sweepedit.app.widgets.loss_plot import LossPlot
from sweepedit.app.worker import FitUpdate

# The fit panel's method choice: (shown text, FitSettings.method).
FIT_METHODS = (("direct (fast)", "direct"), ("network (paper)", "network"))
PROGRESS_STEPS = 1000
# FitSettings' automatic count: the most it may use (AUTO_MAX_PRIMITIVES) and the
# tolerance (DEFAULT_TOLERANCE), written out: reading them would import torch.
AUTO_MAX_PRIMITIVES = 32
DEFAULT_TOLERANCE = 0.008


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
             "time_limit": None, "device": "auto", "auto": False,
             "tolerance": DEFAULT_TOLERANCE}
        d.update(defaults or {})
        self.primitives = QSpinBox()
        self.primitives.setRange(1, 64)
        self.primitives.setValue(int(d["primitives"]))
        self.auto = QCheckBox("auto")
        self.auto.setToolTip("let the shape decide how many: primitives are added where the "
                             "shape is missed until the surfaces agree within the tolerance "
                             "(95% of each within it of the other), up to the number beside")
        self.tolerance = QDoubleSpinBox()
        self.tolerance.setRange(0.001, 0.1)
        self.tolerance.setDecimals(3)
        self.tolerance.setSingleStep(0.001)
        self.tolerance.setValue(float(d["tolerance"]))
        self.tolerance.setToolTip("with auto: how close the surfaces must come, as a share of "
                                  "the shape's longest side")
        # The count asked for, kept while auto shows its cap instead.
        self._fixed_count = int(d["primitives"])
        self.auto.setChecked(bool(d["auto"]))
        self._show_count_mode()
        self.auto.toggled.connect(self._on_auto_toggled)
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
        form.addRow("Primitives", row(self.primitives, self.auto, "tolerance", self.tolerance))
        form.addRow("Method", row(self.method, "on", self.device))
        form.addRow("Iterations", row(self.iterations, "refine", self.refine_iterations))
        form.addRow("Sweeper", row(self.sweeper, "time limit", self.time_limit))
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

    def _show_count_mode(self) -> None:
        auto = self.auto.isChecked()
        self.primitives.setPrefix("at most " if auto else "")
        self.primitives.setToolTip(
            "the most primitives the automatic count may use (unlocked ones)" if auto
            else "how many primitives the fit may use (unlocked ones)")

    def _on_auto_toggled(self, auto: bool) -> None:
        """The spin box shows the cap with auto and the count asked for without; each
        is remembered while the other shows."""
        if auto:
            self._fixed_count = self.primitives.value()
            self.primitives.setValue(AUTO_MAX_PRIMITIVES)
        else:
            self.primitives.setValue(self._fixed_count)
        self._show_count_mode()
        self._enable_inputs()

    def values(self) -> dict[str, Any]:
        """The settings as FitSettings fields (make_settings turns them into one)."""
        return {"primitives": self.primitives.value(), "auto": self.auto.isChecked(),
                "tolerance": self.tolerance.value(), "method": self.method.currentData(),
                "time_limit": self.time_limit.value() or None,
                "device": self.device.currentText(), "iterations": self.iterations.value(),
                "refine_iterations": (None if self.refine_iterations.value() < 0
                                      else self.refine_iterations.value()),
                "sweeper": self.sweeper.currentText(), "seed": self.seed.value(),
                "restarts": self.restarts.value()}

    def _inputs(self) -> tuple[QWidget, ...]:
        return (self.primitives, self.auto, self.tolerance, self.method, self.time_limit,
                self.device, self.iterations, self.refine_iterations, self.sweeper, self.seed,
                self.restarts)

    def _enable_inputs(self) -> None:
        running = self.cancel_button.isEnabled()
        for w in self._inputs():
            w.setEnabled(not running)
        # Only the network stage has iterations and a choice of sweeper.
        network = self.method.currentData() == "network"
        self.tolerance.setEnabled(not running and self.auto.isChecked())
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
