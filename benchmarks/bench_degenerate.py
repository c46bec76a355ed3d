"""Degenerate shapes through the CLI (issue 18): how fast each case of the corpus fails.

    .venv/bin/python benchmarks/bench_degenerate.py [--repeat 3]

For every file of tests/data/degenerate (cases.json says what each must give) runs
`sweepedit fit FILE -o OUT.json` and `sweepedit inspect FILE` in this process, after the
imports are warm (torch included), and prints the exit status, the seconds (best of
--repeat) and the one line of the error, or for the cases with an answer that they
loaded. Fits of the loading cases are not run (they are ordinary fits).
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import io
import json
import sys
import tempfile
import time
from pathlib import Path

from sweepedit.cli import main as sweepedit

CORPUS = Path(__file__).resolve().parents[1] / "tests" / "data" / "degenerate"


def _run(argv: list[str]) -> tuple[int, float, str]:
    err = io.StringIO()
    start = time.perf_counter()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        status = sweepedit(argv)
    return status, time.perf_counter() - start, err.getvalue().strip()


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=3, help="runs per case (best kept)")
    args = parser.parse_args(argv)
    for module in ("torch", "sweepedit.fitting.fit", "sweepedit.analysis.metrics",
                   "sweepedit.analysis.skeleton", "sweepedit.io.params", "sweepedit.io.shapes",
                   "tqdm"):
        importlib.import_module(module)
    cases = json.loads((CORPUS / "cases.json").read_text())["cases"]
    wrong = 0
    print(f"{'file':24s} {'expected':22s} {'fit s':>7s} {'inspect s':>10s}  result")
    with tempfile.TemporaryDirectory() as tmp:
        for name, case in cases.items():
            path = str(CORPUS / name)
            commands = [["inspect", path]]
            if "error" in case:
                commands.insert(0, ["fit", path, "-o", str(Path(tmp) / "out.json"), "--quiet"])
            timings, lines, statuses = [], [], []
            for command in commands:
                runs = [_run(command) for _ in range(args.repeat)]
                statuses.append(runs[0][0])
                timings.append(min(r[1] for r in runs))
                lines.append(runs[0][2])
            expected = case.get("error", "loads")
            ok = (all(s == 2 and case["message"] in line for s, line in zip(statuses, lines,
                                                                            strict=True))
                  if "error" in case else statuses == [0])
            wrong += not ok
            fit = f"{timings[0]:7.2f}" if "error" in case else f"{'-':>7s}"
            shown = lines[0].removeprefix("sweepedit: error: ") if "error" in case else "loaded"
            print(f"{name:24s} {expected:22s} {fit} {timings[-1]:10.2f}  "
                  f"{'ok' if ok else 'WRONG'}: {shown}", flush=True)
    print(f"{len(cases)} cases, {len(cases) - wrong} as cases.json says")
    return 1 if wrong else 0


if __name__ == "__main__":
    sys.exit(main())
