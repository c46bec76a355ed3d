"""The public API's costs (issue 48): how long `import sweepedit` takes, and whether
`sweepedit.fit` on a shape already loaded is as fast as the `sweepedit fit` command.

    .venv/bin/python benchmarks/bench_api.py [--shapes NAME ...] [--primitives 8]

For each bundled shape (default: six of the benchmark set), alternating: the command
`sweepedit fit SHAPE -o OUT.json --quiet` in a fresh process (its whole wall time, and the
fit's own seconds from the file's record), then `sweepedit.fit(shape, K, progress=False)`
in this process on a shape loaded beforehand (wall time of the call). Both must give the
same parameters (same seed). Run it alone on an idle machine: two torch processes on two
cores slow each other several times over. Markdown on stdout.
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

DEFAULT_SHAPES = ("cactus", "spot", "knot1", "hammer", "ant", "glyph_G")


def import_seconds(runs: int = 7) -> list[float]:
    """Wall seconds of `import sweepedit` in fresh interpreters (the interpreter's own
    start-up, measured with an empty -c, taken off)."""
    def timed(code: str) -> float:
        start = time.perf_counter()
        subprocess.run([sys.executable, "-c", code], check=True)
        return time.perf_counter() - start

    out = []
    for _ in range(runs):
        out.append(timed("import sweepedit") - timed("pass"))
    return out


def main() -> int:
    import sweepedit

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--shapes", nargs="+", default=list(DEFAULT_SHAPES))
    parser.add_argument("--primitives", type=int, default=8)
    args = parser.parse_args()

    imports = import_seconds()
    print(f"`import sweepedit`: median {statistics.median(imports) * 1000:.0f} ms, "
          f"max {max(imports) * 1000:.0f} ms over {len(imports)} fresh interpreters\n")
    print("| shape | command whole (s) | command fit (s) | sweepedit.fit (s) | same parameters |")
    print("|---|---:|---:|---:|---|")
    rows = []
    sweepedit.fit(sweepedit.example("cactus"), 1, progress=False)  # torch and numba warm
    with tempfile.TemporaryDirectory() as tmp:
        for name in args.shapes:
            path = sweepedit.example(name)
            out = Path(tmp) / f"{name}.json"
            start = time.perf_counter()
            subprocess.run([sys.executable, "-m", "sweepedit.cli", "fit", str(path), "-o",
                            str(out), "-k", str(args.primitives), "--quiet"], check=True,
                           stdout=subprocess.DEVNULL)
            whole = time.perf_counter() - start
            command = sweepedit.load(out)
            shape = sweepedit.load_shape(path)
            start = time.perf_counter()
            fitted = sweepedit.fit(shape, args.primitives, progress=False)
            api = time.perf_counter() - start
            same = len(command.primitives) == len(fitted.primitives) and all(
                np.array_equal(a.control_points, b.control_points)
                for a, b in zip(command.primitives, fitted.primitives, strict=True))
            rows.append((whole, command.fit["seconds"], api))
            print(f"| {name} | {whole:.2f} | {command.fit['seconds']:.2f} | {api:.2f} | "
                  f"{'yes' if same else 'NO'} |", flush=True)
    whole, fit_only, api = (statistics.median(c) for c in zip(*rows, strict=True))
    print(f"| **median** | {whole:.2f} | {fit_only:.2f} | {api:.2f} | |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
