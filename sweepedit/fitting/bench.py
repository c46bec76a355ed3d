"""The quality table and contact sheet of a set of fits (`sweepedit bench` and `batch`).

The fitting itself runs through `sweepedit.batch` (one code path for both commands);
this module turns its rows into the Markdown table (per shape, then means and medians),
the seconds per stage, the JSON record and the contact sheet.
"""

from __future__ import annotations

import json
import math
import statistics
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

from sweepedit.errors import DegenerateShapeError
from sweepedit.fitting.fit import FitSettings
from sweepedit.io.params import atomic_write_text

if TYPE_CHECKING:
    from sweepedit.io.shapes import Shape

COLUMNS = ("iou", "cd_l1", "f1_0.05", "f1_0.01", "n_primitives", "seconds")
# Grid and samples of a shape loaded only to be drawn under its abstraction.
_SHEET_RESOLUTION = 16
_SHEET_SAMPLES = 256


@dataclass
class BenchRow:
    shape: str
    metrics: dict[str, float]
    error: str | None = None
    # Seconds per stage of the fit (load, voxelise, skeleton, warm start, ...).
    stages: dict[str, float] = field(default_factory=dict)


def summary_stats(rows: Sequence[BenchRow]) -> dict[str, dict[str, float]]:
    """{"mean": {column: value}, "median": {...}} over the rows without an error;
    non-finite values (a distance to nothing) are left out."""
    ok = [r for r in rows if r.error is None]
    out: dict[str, dict[str, float]] = {"mean": {}, "median": {}}
    for col in COLUMNS:
        values = [float(r.metrics[col]) for r in ok
                  if col in r.metrics and math.isfinite(float(r.metrics[col]))]
        if values:
            out["mean"][col] = statistics.fmean(values)
            out["median"][col] = statistics.median(values)
    return out


_HEAD = ("| shape | IoU | CD-L1 | F1@0.05 | F1@0.01 | primitives | seconds |\n"
         "|---|---|---|---|---|---|---|\n")


def _summary_lines(rows: Sequence[BenchRow]) -> list[str]:
    summary = summary_stats(rows)
    lines = []
    for name in ("mean", "median"):
        s = summary[name]
        if len(s) == len(COLUMNS):
            lines.append(f"| **{name}** | {s['iou']:.3f} | {s['cd_l1']:.4f} | "
                         f"{s['f1_0.05']:.3f} | {s['f1_0.01']:.3f} | "
                         f"{s['n_primitives']:.1f} | {s['seconds']:.1f} |")
    return lines


def settings_line(settings: FitSettings) -> str:
    network = (f"network stage {settings.iterations} iterations (sweeper {settings.sweeper})"
               if settings.method == "network" else "no network stage")
    limit = f", time limit {settings.time_limit:g} s" if settings.time_limit else ""
    return (f"K = {settings.primitives}, method {settings.method} ({network}), "
            f"{settings.refine_steps} refinement steps, {settings.restarts} restart(s), "
            f"seed {settings.seed}{limit}")


def format_table(rows: Sequence[BenchRow], settings: FitSettings) -> str:
    """A Markdown table of the rows, then the means and medians, then seconds per stage."""
    lines = []
    for r in rows:
        if r.error:
            lines.append(f"| {r.shape} | error: {r.error} | | | | | |")
            continue
        m = r.metrics
        lines.append(f"| {r.shape} | {m['iou']:.3f} | {m['cd_l1']:.4f} | {m['f1_0.05']:.3f} | "
                     f"{m['f1_0.01']:.3f} | {int(m['n_primitives'])} | {m['seconds']:.1f} |")
    lines += _summary_lines(rows)
    return (settings_line(settings) + "\n\n" + _HEAD + "\n".join(lines) + "\n"
            + format_stage_table(rows))


def format_means(rows: Sequence[BenchRow]) -> str:
    """Only the means and medians (for jobs too long to print shape by shape)."""
    ok = sum(r.error is None for r in rows)
    lines = _summary_lines(rows)
    if not lines:
        return f"no shape fitted ({len(rows)} failed)\n"
    return f"{ok} shape(s) fitted, {len(rows) - ok} failed\n\n" + _HEAD + "\n".join(lines) + "\n"


def format_stage_table(rows: Sequence[BenchRow]) -> str:
    """A Markdown table of the median seconds per stage over the shapes that have them."""
    names: list[str] = []
    for r in rows:
        names += [n for n in r.stages if n not in names]
    if not names:
        return ""
    lines = ["", "| stage | median s | mean s |", "|---|---|---|"]
    for name in names:
        values = [r.stages.get(name, 0.0) for r in rows if r.stages]
        lines.append(f"| {name} | {statistics.median(values):.2f} | "
                     f"{statistics.fmean(values):.2f} |")
    return "\n".join(lines) + "\n"


def write_bench_json(path: str | Path, rows: Sequence[BenchRow], settings: FitSettings) -> None:
    """The settings, the rows and their means and medians as JSON, atomically."""
    atomic_write_text(path, json.dumps(
        {"settings": {k: v for k, v in vars(settings).items() if k != "weights"},
         "rows": [vars(r) for r in rows], "summary": summary_stats(rows)}, indent=1,
        default=str))


def contact_sheet(items: Sequence[tuple[str, Path, Path]], path_png: str | Path,
                  max_tiles: int | None = None) -> tuple[Path, int]:
    """Draw (name, shape file, parameter file) items as one sheet of tiles, each
    abstraction over its shape; at most `max_tiles` of them, evenly spread over the list.
    Returns the path and the number of tiles drawn."""
    from sweepedit.analysis.render import render_contact_sheet
    from sweepedit.io.params import read_abstraction
    chosen = list(items)
    if max_tiles is not None and len(chosen) > max_tiles:
        step = len(chosen) / max_tiles
        chosen = [chosen[int(i * step)] for i in range(max_tiles)]
    tiles = [(name, _sheet_shape(shape), read_abstraction(params))
             for name, shape, params in chosen]
    return render_contact_sheet(tiles, path_png), len(tiles)


def _sheet_shape(path: Path) -> Shape:
    """The shape to draw under a tile. A coarse load is enough to draw its surface (its
    grids are not used); a shape thinner than a coarse cell, which the coarse grid calls
    degenerate, is loaded at the fit's resolution instead (it was fitted at that one)."""
    from sweepedit.io.shapes import load_shape

    try:
        return load_shape(path, resolution=_SHEET_RESOLUTION, n_samples=_SHEET_SAMPLES)
    except DegenerateShapeError:
        return load_shape(path, n_samples=_SHEET_SAMPLES)
