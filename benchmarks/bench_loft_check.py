"""Our verdict on whether a loft through slices crosses itself (geometry/loft.py,
loft_verdict) against OpenCascade's check of its solid (io/step/checks.py,
crosses_itself), on every loft that STEP export judges while it builds the folding
primitives of the files given.

    .venv/bin/python benchmarks/bench_loft_check.py [--params DIR] [--fits DIR] [--out F]

Each loft is sewn into a solid and read back from STEP text as the export does, and
checked both ways; the export itself goes on as it would (OpenCascade's check only where
ours cannot tell). Prints and writes the counts of (OpenCascade finds a crossing, our
verdict) and the seconds of each, and the lofts where OpenCascade's raw check raised an
alarm that crosses_itself dismissed (a face meeting itself at one point of it). Where
ours tells and OpenCascade disagrees, the loft is listed by primitive: each needs a look
(see BENCHMARKS.md).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import statistics
import time
from collections import Counter
from pathlib import Path
from typing import Any

from sweepedit.geometry.model import folds_onto_itself
from sweepedit.io.params import read_abstraction
from sweepedit.io.step import StepExportError, primitive_solid
from sweepedit.io.step import solids as step_solids
from sweepedit.io.step.checks import is_crossing, self_interference
from sweepedit.io.step.writer import as_written


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--params", type=Path, default=Path("../shared/sweepnet_params"))
    parser.add_argument("--fits", type=Path, default=None)
    parser.add_argument("--out", type=Path, default=Path("bench-out/loft_check.json"))
    args = parser.parse_args()
    files = sorted(args.params.glob("*.txt"))
    if args.fits is not None:
        files += sorted(args.fits.glob("*.json"))

    rows: list[dict[str, Any]] = []
    current: dict[str, Any] = {}
    ours = step_solids.loft_verdict

    def both_checks(loft: Any, planes: Any) -> Any:
        start = time.perf_counter()
        verdict = ours(loft, planes)
        ours_s = time.perf_counter() - start
        try:  # the solid as STEP export would check it
            solid = as_written(
                step_solids._sewn_solid(current["primitive"], loft, None, "loft"), "loft")
        except Exception:  # a loft OpenCascade cannot make a solid of
            return verdict
        start = time.perf_counter()
        found = self_interference(solid)  # crosses_itself, in two
        crosses = any(is_crossing(result) for result in found)
        rows.append({"primitive": current["name"], "occ_crosses": crosses,
                     "occ_alarm": bool(found),
                     "ours": verdict.value, "ours_s": ours_s,
                     "occ_s": time.perf_counter() - start,
                     "planes": type(planes).__name__})
        return verdict

    step_solids.loft_verdict = both_checks  # where _sliced_solids looks it up
    for path in files:
        for index, primitive in enumerate(read_abstraction(path).visible()):
            if not folds_onto_itself(primitive):
                continue
            current["name"] = f"{path.name} #{index}"
            current["primitive"] = primitive
            with contextlib.suppress(StepExportError):
                primitive_solid(primitive, index)
    counts = Counter((r["occ_crosses"], r["ours"]) for r in rows)
    summary = {
        "lofts": len(rows),
        **{f"occ_{'crosses' if occ else 'passes'}_ours_{ours}": n
           for (occ, ours), n in sorted(counts.items())},
        "disagreements": [(r["primitive"], r["occ_crosses"], r["ours"]) for r in rows
                          if r["ours"] != "unknown"
                          and r["occ_crosses"] != (r["ours"] == "crosses")],
        "occ_alarms_dismissed": [(r["primitive"], r["ours"]) for r in rows
                                 if r["occ_alarm"] and not r["occ_crosses"]],
        "ours_median_s": statistics.median(r["ours_s"] for r in rows) if rows else None,
        "ours_max_s": max((r["ours_s"] for r in rows), default=None),
        "occ_median_s": statistics.median(r["occ_s"] for r in rows) if rows else None,
    }
    print(json.dumps(summary, indent=1))
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps({"summary": summary, "lofts": rows}, indent=1))


if __name__ == "__main__":
    main()
