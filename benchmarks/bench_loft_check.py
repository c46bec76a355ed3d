"""Our test that a loft through slices does not cross itself (geometry/loft.py,
loft_is_embedded) against OpenCascade's (io/step_export.py, crosses_itself), on every
loft that STEP export checks while it builds the folding primitives of the files given.

    .venv/bin/python benchmarks/bench_loft_check.py [--params DIR] [--fits DIR] [--out F]

Each loft that reaches the crossing check (valid, within its volume, read back from
STEP text) is checked both ways; the export itself goes on as it would (OpenCascade's
check only where ours cannot vouch). Prints and writes the counts of (OpenCascade finds
a crossing, ours vouches) and the seconds of each. A loft ours vouches for and
OpenCascade does not is listed by primitive: each needs a look (see BENCHMARKS.md).
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
from sweepedit.io import step_export
from sweepedit.io.params import read_abstraction


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--params", type=Path, default=Path("../shared/sweepnet_params"))
    parser.add_argument("--fits", type=Path, default=None)
    parser.add_argument("--out", type=Path, default=Path("loft_check.json"))
    args = parser.parse_args()
    files = sorted(args.params.glob("*.txt"))
    if args.fits is not None:
        files += sorted(args.fits.glob("*.json"))

    rows: list[dict[str, Any]] = []
    current: dict[str, Any] = {}
    as_written, ours = step_export._as_written, step_export.loft_is_embedded

    def remember_solid(solid: Any, what: str) -> Any:
        current["solid"] = as_written(solid, what)
        return current["solid"]

    def both_checks(loft: Any, planes: Any) -> bool:
        start = time.perf_counter()
        vouched = ours(loft, planes)
        ours_s = time.perf_counter() - start
        start = time.perf_counter()
        crosses = step_export.crosses_itself(current["solid"])
        rows.append({"primitive": current["name"], "occ_crosses": crosses,
                     "ours_vouches": vouched, "ours_s": ours_s,
                     "occ_s": time.perf_counter() - start,
                     "planes": type(planes).__name__})
        return vouched

    step_export._as_written = remember_solid
    step_export.loft_is_embedded = both_checks
    for path in files:
        for index, primitive in enumerate(read_abstraction(path).visible()):
            if not folds_onto_itself(primitive):
                continue
            current["name"] = f"{path.name} #{index}"
            with contextlib.suppress(step_export.StepExportError):
                step_export.primitive_solid(primitive, index)
    counts = Counter((r["occ_crosses"], r["ours_vouches"]) for r in rows)
    summary = {
        "lofts": len(rows),
        "occ_crosses_ours_refuses": counts[(True, False)],
        "occ_passes_ours_vouches": counts[(False, True)],
        "occ_passes_ours_refuses": counts[(False, False)],
        "occ_crosses_ours_vouches": [r["primitive"] for r in rows
                                     if r["occ_crosses"] and r["ours_vouches"]],
        "ours_median_s": statistics.median(r["ours_s"] for r in rows) if rows else None,
        "ours_max_s": max((r["ours_s"] for r in rows), default=None),
        "occ_median_s": statistics.median(r["occ_s"] for r in rows) if rows else None,
    }
    print(json.dumps(summary, indent=1))
    args.out.write_text(json.dumps({"summary": summary, "lofts": rows}, indent=1))


if __name__ == "__main__":
    main()
