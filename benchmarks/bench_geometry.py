"""Geometry benchmark: mesher per primitive, union of 8 (display tubes, and the solid that
export writes), exact inside test on 64^3.

    .venv/bin/python benchmarks/bench_geometry.py [--params DIR]

DIR: the official SweepNet parameter files (39.txt and ant.txt are used); by default
../shared/sweepnet_params beside the checkout.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import numpy as np

from sweepedit.geometry.inside import grid_points, inside_union
from sweepedit.geometry.mesher import sweep_mesh, sweep_meshes, union_mesh
from sweepedit.geometry.solid import solid_union
from sweepedit.io.params import read_abstraction


def timed(fn, repeat: int) -> list[float]:
    out = []
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        out.append(time.perf_counter() - t)
    return out


DEFAULT_PARAMS = Path(__file__).resolve().parents[2] / "shared" / "sweepnet_params"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--params", type=Path, default=DEFAULT_PARAMS)
    params = parser.parse_args().params
    if not (params / "39.txt").is_file() or not (params / "ant.txt").is_file():
        sys.exit(f"bench_geometry: {params} does not hold 39.txt and ant.txt; "
                 "pass --params DIR")
    prims = [p for f in ("39.txt", "ant.txt") for p in read_abstraction(params / f).primitives]
    eight = prims[:8]
    one = eight[0]
    sweep_mesh(one)  # warm caches
    single = timed(lambda: sweep_mesh(one, 64, 48, split_caps=True), 300)
    batch = timed(lambda: sweep_meshes(eight, 64, 48), 100)
    meshes = sweep_meshes(eight, 64, 48)
    union = timed(lambda: union_mesh(meshes), 10)
    solid = timed(lambda: solid_union(eight), 5)
    grid = grid_points(64)
    inside = timed(lambda: inside_union(grid, eight), 5)
    print(f"mesher, one primitive 64x48 (display):  median {statistics.median(single)*1e3:.2f} ms")
    print(f"mesher, 8 primitives batched 64x48:     median {statistics.median(batch)*1e3/8:.2f} ms "
          f"per primitive")
    print(f"union of 8 display tubes (manifold3d):  median {statistics.median(union)*1e3:.0f} ms")
    print(f"solid union of 8 (export, solid.py):    median {statistics.median(solid)*1e3:.0f} ms")
    print(f"exact inside, 64^3 grid, 8 primitives:  median {statistics.median(inside):.2f} s")
    print(f"(inside fraction {inside_union(grid, eight).mean():.3f}, "
          f"{np.sum([len(m.faces) for m in meshes])} faces)")


if __name__ == "__main__":
    main()
