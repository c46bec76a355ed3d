"""sweepedit's fits beside Marching-Primitives' on the same shapes: the means of the four
quality figures, the median primitive count and, per shape, how often sweepedit used
fewer primitives than the peer. Markdown on stdout, for BENCHMARKS.md.

    .venv/bin/python benchmarks/peer_table.py --peer bench-out/peer/val_auto.csv \\
        "K = 8=bench-out/val_k8/table.json" "K = 16=bench-out/val_k16/table.json" \\
        "auto=bench-out/peer/val_auto.csv"

--peer: a CSV of Marching-Primitives rows, as benchmarks/bench_peer.py writes it (rows
with method "mp") or as ../shared/anchors/marching_primitives_30.csv holds them (no
method column). Each other argument is NAME=FILE: a `sweepedit bench` JSON, or a
bench_peer CSV whose "sweepedit" rows are taken. Only the shapes both sides fitted count;
the table says how many.
"""

from __future__ import annotations

import argparse
import csv
import json
import statistics
from collections.abc import Sequence
from pathlib import Path

FIGURES = ("iou", "cd_l1", "f1_0.05", "f1_0.01")
HEADERS = ("IoU", "CD-L1", "F1@0.05", "F1@0.01")
Rows = dict[str, dict[str, float]]


def read_rows(path: Path, method: str) -> Rows:
    """{shape: {figure: value, "n_primitives": n, "seconds": s}} of one method's ok rows."""
    if path.suffix == ".json":
        rows = json.loads(path.read_text())["rows"]
        return {r["shape"]: {k: float(r["metrics"][k]) for k in (*FIGURES, "n_primitives")}
                | {"seconds": float(r["metrics"]["seconds"])}
                for r in rows if r.get("metrics")}
    out: Rows = {}
    with path.open(newline="") as f:
        for r in csv.DictReader(f):
            if r.get("method", method) != method or r.get("status", "ok") != "ok":
                continue
            seconds = r.get("whole_seconds") or r.get("fit_seconds") or "nan"
            out[r["shape"]] = {k: float(r[k]) for k in (*FIGURES, "n_primitives")} | {
                "seconds": float(seconds)}
    return out


def table(peer: Rows, runs: Sequence[tuple[str, Rows]]) -> str:
    """The Markdown table: one row per run, the peer's last."""
    lines = ["| method | shapes | " + " | ".join(HEADERS)
             + " | median primitives | fewer primitives than MP |",
             "|---|---|" + "---|" * (len(HEADERS) + 2)]
    for name, rows in [*runs, ("Marching-Primitives", peer)]:
        shapes = sorted(set(rows) & set(peer))
        if not shapes:
            continue
        means = [statistics.fmean(rows[s][k] for s in shapes) for k in FIGURES]
        median = statistics.median(rows[s]["n_primitives"] for s in shapes)
        fewer = sum(rows[s]["n_primitives"] < peer[s]["n_primitives"] for s in shapes)
        share = "" if rows is peer else f"{fewer} of {len(shapes)} ({fewer / len(shapes):.0%})"
        cells = [f"{v:.4f}" if k == "cd_l1" else f"{v:.3f}" for k, v in zip(FIGURES, means,
                                                                            strict=True)]
        lines.append(f"| {name} | {len(shapes)} | " + " | ".join(cells)
                     + f" | {median:g} | {share} |")
    return "\n".join(lines) + "\n"


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--peer", required=True, type=Path, help="Marching-Primitives rows (CSV)")
    p.add_argument("runs", nargs="+", help="NAME=FILE: sweepedit bench JSON or bench_peer CSV")
    args = p.parse_args(argv)
    runs = []
    for item in args.runs:
        name, sep, file = item.rpartition("=")
        if not sep:
            p.error(f"expected NAME=FILE, got {item!r}")
        runs.append((name, read_rows(Path(file), "sweepedit")))
    print(table(read_rows(args.peer, "mp"), runs), end="")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
