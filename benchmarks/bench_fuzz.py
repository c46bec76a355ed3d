"""Fuzzing campaign over every format sweepedit reads (issue 18).

    .venv/bin/python benchmarks/bench_fuzz.py [--cases 500] [--seed 0] [--resolution 64]
                                              [--formats obj,ply_ascii] [--keep DIR]

Mutates a real seed file of each format (tests/fuzzing.py: truncations, flipped and
overwritten bytes, deleted and repeated runs, huge header counts, wrong JSON types) and
reads every case in a worker process limited to 2 GiB above its start-up memory. Prints,
per format, how many cases loaded, how many gave sweepedit's own error naming the file,
and how many failed (another exception, over 5 s, out of memory, a crash or a hang),
the slowest case and the peak memory; then every failure, one line each, and the case's
file kept under --keep. Exit status 1 if any case failed.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
import zlib
from collections import Counter
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from fuzzing import (
    FORMATS,
    RandomChooser,
    Worker,
    describe,
    kind_of,
    mutate,
    write_seeds,
)

RESULTS = ("loaded", "error", "other exception", "unnamed error", "slow", "memory", "crash",
           "hang")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", type=int, default=500, help="cases per format (500)")
    parser.add_argument("--seed", type=int, default=0, help="of the random campaign (0)")
    parser.add_argument("--formats", default=",".join(FORMATS),
                        help="comma-separated subset of: " + ", ".join(FORMATS))
    parser.add_argument("--resolution", type=int, default=64,
                        help="grid that shapes load on (64, the default of load_shape)")
    parser.add_argument("--keep", type=Path, default=Path("bench-out/fuzz-failures"),
                        help="folder for the files of failed cases")
    args = parser.parse_args(argv)
    formats = [f for f in args.formats.split(",") if f]
    unknown = set(formats) - set(FORMATS)
    if unknown:
        parser.error(f"unknown formats: {', '.join(sorted(unknown))}")

    worker = Worker()
    failures: list[str] = []
    totals: Counter[str] = Counter()
    started = time.perf_counter()
    header = f"{'format':12s}" + "".join(f"{r:>16s}" for r in RESULTS) + \
        f"{'slowest s':>11s}{'peak MiB':>10s}"
    print(header)
    with tempfile.TemporaryDirectory() as tmp:
        seeds = write_seeds(Path(tmp) / "seeds")
        for fmt in formats:
            seed = seeds[fmt].read_bytes()
            target = Path(tmp) / f"case{seeds[fmt].suffix}"
            counts: Counter[str] = Counter()
            slowest = peak = 0.0
            for case in range(args.cases):
                chooser = RandomChooser(zlib.crc32(f"{args.seed}:{fmt}:{case}".encode()))
                data, names = mutate(seed, fmt, chooser)
                target.write_bytes(data)
                outcome = worker.run(target, kind_of(fmt), args.resolution)
                counts[outcome.result] += 1
                slowest = max(slowest, outcome.seconds)
                peak = max(peak, outcome.peak_rss_mib)
                if not outcome.ok:
                    args.keep.mkdir(parents=True, exist_ok=True)
                    kept = args.keep / f"{fmt}_{case}{seeds[fmt].suffix}"
                    kept.write_bytes(data)
                    failures.append(f"{describe(outcome, fmt, names)} [{kept}]")
            totals.update(counts)
            print(f"{fmt:12s}" + "".join(f"{counts[r]:16d}" for r in RESULTS)
                  + f"{slowest:11.2f}{peak:10.0f}", flush=True)
    worker.close()
    print(f"{'all':12s}" + "".join(f"{totals[r]:16d}" for r in RESULTS))
    print(f"{sum(totals.values())} cases in {time.perf_counter() - started:.0f} s; "
          f"{len(failures)} failed")
    for line in failures:
        print("FAIL", line)
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
