"""OUTDIR/summary.csv, and which shapes a rerun can skip.

A shape is done when its outputs are complete and valid for this job:
OUTDIR/<name>.json reads back with sweepedit's reader, its fit record was made by the
same job (settings, mesh format, metric samples: `JobSpec.fingerprint`) from the same
input file (size and modification time), and OUTDIR/<name>.<mesh format> is there. The
driver writes the mesh first and the parameter file last, both atomically, so the
parameter file is the commit point; its record holds everything a summary row holds, so
a row lost with a killed driver is rebuilt from it, and a done shape is never refitted
and its files never touched. summary.csv itself is derived: rewritten (atomically) as
shapes finish and at the end.
"""

from __future__ import annotations

import csv
import io
import math
from collections.abc import Sequence
from pathlib import Path

from sweepedit.batch.inputs import ShapeInput
from sweepedit.batch.jobs import RECORD_KEY, JobOutcome, JobSpec, input_stamp
from sweepedit.errors import SweepeditError
from sweepedit.io.params import atomic_write_text, read_abstraction

SUMMARY_NAME = "summary.csv"
METRIC_COLUMNS = ("iou", "cd_l1", "cd_l2", "f1_0.05", "f1_0.01")
COLUMNS = ("shape", "status", *METRIC_COLUMNS, "primitives", "seconds", "timed_out",
           "node", "input", "error")


def params_path(outdir: Path, name: str) -> Path:
    return outdir / f"{name}.json"


def mesh_path(outdir: Path, name: str, mesh_format: str) -> Path:
    return outdir / f"{name}.{mesh_format}"


def summary_text(outcomes: Sequence[JobOutcome]) -> str:
    """The CSV text of the rows: one per shape, metrics with 6 significant digits."""
    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    writer.writerow(COLUMNS)
    for o in outcomes:
        ok = o.status == "ok"
        metrics = [_number(o.metrics.get(c)) if ok else "" for c in METRIC_COLUMNS]
        writer.writerow([o.name, o.status, *metrics, o.primitives if ok else "",
                         f"{o.seconds:.2f}" if ok else "", int(o.timed_out) if ok else "",
                         o.node, o.input, o.error])
    return buffer.getvalue()


def _number(value: float | None) -> str:
    if value is None:
        return ""
    return f"{value:.6g}" if math.isfinite(value) else str(value)


def write_summary(outdir: Path, outcomes: Sequence[JobOutcome]) -> Path:
    path = outdir / SUMMARY_NAME
    atomic_write_text(path, summary_text(outcomes))
    return path


def read_summary(path: str | Path) -> list[dict[str, str]]:
    """The rows of a summary.csv as dicts by column name."""
    with open(path, encoding="utf-8", newline="") as handle:
        return list(csv.DictReader(handle))


def completed(outdir: Path, shape: ShapeInput, spec: JobSpec) -> JobOutcome | None:
    """The outcome of a shape whose outputs in `outdir` are complete and valid for this
    job (see the module docstring), rebuilt from its parameter file; None otherwise."""
    params = params_path(outdir, shape.name)
    mesh = mesh_path(outdir, shape.name, spec.mesh_format)
    try:
        if not params.is_file() or mesh.stat().st_size == 0:
            return None
        abstraction = read_abstraction(params)
        stamp = input_stamp(shape.path)
    except (OSError, SweepeditError):
        return None
    fit = abstraction.fit or {}
    record = fit.get(RECORD_KEY)
    metrics = fit.get("metrics")
    if not isinstance(record, dict) or not isinstance(metrics, dict):
        return None
    if (record.get("job") != spec.fingerprint()
            or any(record.get(k) != v for k, v in stamp.items())):
        return None
    try:
        stages = {"load": float(record.get("load_seconds", 0.0)),
                  **{k: float(v) for k, v in (fit.get("stage_seconds") or {}).items()}}
        values = {k: float(v) for k, v in metrics.items() if v is not None}
        return JobOutcome(shape.name, str(shape.path), "ok", metrics=values,
                          primitives=len(abstraction.primitives),
                          seconds=float(metrics.get("seconds", 0.0)),
                          timed_out=bool(fit.get("timed_out", False)), stages=stages,
                          node=str(record.get("node", "")))
    except (TypeError, ValueError):
        return None
