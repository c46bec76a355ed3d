"""The end of a job: the table of means and medians, summary.md and the contact sheet
(the same table and sheet as `sweepedit bench`, from sweepedit.fitting.bench)."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from sweepedit.batch.jobs import JobOutcome
from sweepedit.batch.summary import params_path
from sweepedit.fitting.bench import BenchRow, contact_sheet, format_table
from sweepedit.fitting.fit import FitSettings
from sweepedit.io.params import atomic_write_text

TABLE_NAME = "summary.md"
SHEET_NAME = "contact_sheet.png"


def bench_rows(outcomes: Sequence[JobOutcome]) -> list[BenchRow]:
    """The bench table's rows of a job's outcomes (failed ones carry their reason)."""
    rows = []
    for o in outcomes:
        if o.status != "ok":
            rows.append(BenchRow(o.name, {}, error=o.error or o.status))
            continue
        metrics = {**o.metrics, "n_primitives": float(o.primitives), "seconds": o.seconds}
        rows.append(BenchRow(o.name, metrics, stages=dict(o.stages)))
    return rows


def write_table(outdir: Path, outcomes: Sequence[JobOutcome], settings: FitSettings) -> Path:
    """OUTDIR/summary.md: every shape, then the means and medians and seconds per stage."""
    path = outdir / TABLE_NAME
    atomic_write_text(path, format_table(bench_rows(outcomes), settings))
    return path


def draw_sheet(outdir: Path, outcomes: Sequence[JobOutcome], path_png: Path,
               max_tiles: int | None) -> tuple[Path, int] | None:
    """The contact sheet of the ok shapes (at most max_tiles, spread over the job), or
    None when there is none."""
    items = [(o.name, Path(o.input), params_path(outdir, o.name))
             for o in outcomes if o.status == "ok"]
    if not items:
        return None
    return contact_sheet(items, path_png, max_tiles)
