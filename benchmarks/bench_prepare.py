"""Per-shape preparation time: load + normalise + voxelise + samples + skeleton.

    python benchmarks/bench_prepare.py [SHAPES_DIR] [--repeat N] [--png DIR]

Prints one line per shape of the manifest (seconds for load_shape, for compute_skeleton,
and their sum, the best of N runs) and the median total. With --png, also renders each
shape with its skeleton (not timed).
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

from sweepedit.analysis.skeleton import compute_skeleton
from sweepedit.io.shapes import load_shape

DEFAULT_SHAPES = Path(__file__).resolve().parents[1].parent / "shared" / "shapes"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("shapes", nargs="?", type=Path, default=DEFAULT_SHAPES)
    parser.add_argument("--repeat", type=int, default=1, help="runs per shape (best kept)")
    parser.add_argument("--png", type=Path, default=None, help="folder for renders")
    args = parser.parse_args(argv)

    manifest = json.loads((args.shapes / "manifest.json").read_text())
    totals = []
    print(f"{'shape':14s} {'load':>6s} {'skel':>6s} {'total':>6s}  faces  branches")
    for entry in manifest:
        path = args.shapes / entry["file"]
        best = None
        for _ in range(max(1, args.repeat)):
            t0 = time.perf_counter()
            shape = load_shape(path)
            t1 = time.perf_counter()
            skeleton = compute_skeleton(shape.occupancy)
            t2 = time.perf_counter()
            if best is None or t2 - t0 < best[2]:
                best = (t1 - t0, t2 - t1, t2 - t0)
        assert best is not None
        totals.append(best[2])
        print(f"{entry['name']:14s} {best[0]:6.2f} {best[1]:6.2f} {best[2]:6.2f} "
              f"{len(shape.surface.faces):6d}  {len(skeleton.branches)}", flush=True)
        if args.png is not None:
            from sweepedit.analysis.render import render_shape

            render_shape(shape, skeleton, args.png / f"{entry['name']}.png")
    print(f"median {statistics.median(totals):.2f} s, max {max(totals):.2f} s, "
          f"total {sum(totals):.1f} s over {len(totals)} shapes")
    return 0


if __name__ == "__main__":
    sys.exit(main())
