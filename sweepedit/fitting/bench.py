"""`sweepedit bench`: fit every shape of a folder and tabulate the quality protocol."""

from __future__ import annotations

import json
import statistics
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from sweepedit.errors import SweepeditError
from sweepedit.fitting.fit import FitSettings, fit_abstraction
from sweepedit.io.params import atomic_write_text, write_abstraction

SHAPE_EXTENSIONS = {".obj", ".ply", ".stl", ".off", ".glb", ".gltf", ".binvox", ".npy", ".npz",
                    ".xyz", ".pts"}
COLUMNS = ("iou", "cd_l1", "f1_0.05", "f1_0.01", "n_primitives", "seconds")


@dataclass
class BenchRow:
    shape: str
    metrics: dict[str, float]
    error: str | None = None
    # Seconds per stage of the fit (load, voxelise, skeleton, warm start, ...).
    stages: dict[str, float] = field(default_factory=dict)


def shape_files(folder: str | Path) -> list[Path]:
    """The shape files of a folder, sorted by name."""
    folder = Path(folder)
    if not folder.is_dir():
        raise SweepeditError(f"{folder}: not a folder of shapes")
    files = sorted(p for p in folder.iterdir() if p.suffix.lower() in SHAPE_EXTENSIONS)
    if not files:
        raise SweepeditError(f"{folder}: no shape files in it")
    return files


def _summary(rows: list[BenchRow]) -> dict[str, dict[str, float]]:
    ok = [r for r in rows if r.error is None]
    out: dict[str, dict[str, float]] = {"mean": {}, "median": {}}
    for col in COLUMNS:
        values = [float(r.metrics[col]) for r in ok]
        if values:
            out["mean"][col] = statistics.fmean(values)
            out["median"][col] = statistics.median(values)
    return out


def format_table(rows: list[BenchRow], settings: FitSettings) -> str:
    """A Markdown table of the rows, then the means and medians."""
    head = ("| shape | IoU | CD-L1 | F1@0.05 | F1@0.01 | primitives | seconds |\n"
            "|---|---|---|---|---|---|---|\n")
    lines = []
    for r in rows:
        if r.error:
            lines.append(f"| {r.shape} | error: {r.error} | | | | | |")
            continue
        m = r.metrics
        lines.append(f"| {r.shape} | {m['iou']:.3f} | {m['cd_l1']:.4f} | {m['f1_0.05']:.3f} | "
                     f"{m['f1_0.01']:.3f} | {int(m['n_primitives'])} | {m['seconds']:.1f} |")
    summary = _summary(rows)
    for name in ("mean", "median"):
        s = summary[name]
        if s:
            lines.append(f"| **{name}** | {s['iou']:.3f} | {s['cd_l1']:.4f} | {s['f1_0.05']:.3f} | "
                         f"{s['f1_0.01']:.3f} | {s['n_primitives']:.1f} | {s['seconds']:.1f} |")
    network = (f"network stage {settings.iterations} iterations (sweeper {settings.sweeper})"
               if settings.method == "network" else "no network stage")
    limit = f", time limit {settings.time_limit:g} s" if settings.time_limit else ""
    settings_line = (f"K = {settings.primitives}, method {settings.method} ({network}), "
                     f"{settings.refine_steps} refinement steps, {settings.restarts} restart(s), "
                     f"seed {settings.seed}{limit}\n\n")
    return settings_line + head + "\n".join(lines) + "\n" + format_stage_table(rows)


def format_stage_table(rows: list[BenchRow]) -> str:
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


def run_bench(shapes_dir: str | Path, out_file: str | Path, settings: FitSettings,
              progress: Callable[[int, int, str], None] | None = None) -> list[BenchRow]:
    """Fit each shape, write OUT (Markdown table), OUT.json, per-shape parameter files in
    OUT's folder under params/, and a contact sheet OUT.png. Returns the rows."""
    from sweepedit.analysis.metrics import evaluate
    from sweepedit.analysis.render import render_contact_sheet
    from sweepedit.io.shapes import load_shape

    out_file = Path(out_file)
    params_dir = out_file.parent / "params"
    params_dir.mkdir(parents=True, exist_ok=True)
    files = shape_files(shapes_dir)
    rows: list[BenchRow] = []
    sheet: list[tuple[str, object, object]] = []
    for i, path in enumerate(files):
        if progress:
            progress(i, len(files), path.name)
        try:
            start = time.perf_counter()
            shape = load_shape(path)
            loaded = time.perf_counter()
            result = fit_abstraction(shape, settings)
            seconds = time.perf_counter() - start
            metrics = evaluate(result.abstraction, shape, seed=settings.seed)
            metrics["seconds"] = seconds
            stages = {"load": loaded - start, **result.stage_seconds}
            result.abstraction.fit = {**(result.abstraction.fit or {}), "metrics": metrics}
            write_abstraction(result.abstraction, params_dir / f"{path.stem}.json")
            rows.append(BenchRow(path.stem, metrics, stages=stages))
            sheet.append((path.stem, shape, result.abstraction))
        except SweepeditError as exc:
            rows.append(BenchRow(path.stem, {}, error=str(exc)))
    if progress:
        progress(len(files), len(files), "")
    atomic_write_text(out_file, format_table(rows, settings))
    atomic_write_text(out_file.with_suffix(".json"), json.dumps(
        {"settings": {k: v for k, v in vars(settings).items() if k != "weights"},
         "rows": [vars(r) for r in rows], "summary": _summary(rows)}, indent=1))
    if sheet:
        render_contact_sheet(sheet, out_file.with_suffix(".png"))
    return rows
