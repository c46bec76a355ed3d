"""The fit's loss curves, drawn with QPainter on a log scale."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np
from PySide6.QtCore import QPointF, QRectF, Qt
from PySide6.QtGui import QColor, QFont, QPainter, QPen, QPolygonF
from PySide6.QtWidgets import QSizePolicy, QWidget

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

