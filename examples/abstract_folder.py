"""Abstract every shape in a folder and print a table of metrics (Markdown).

    python examples/abstract_folder.py FOLDER [--primitives K|auto] [--out OUTDIR]

Each shape's parameters go to OUTDIR/<name>.json (default: beside nothing, not saved).
A file that cannot be read is a row with its error; the others go on. For whole datasets,
on many cores or a Ray cluster, `sweepedit batch` does the same with resuming and retries.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import sweepedit
from sweepedit.io.shapes import SUPPORTED_EXTENSIONS


def abstract_folder(folder: Path, primitives: int | str, out: Path | None) -> list[dict]:
    """One row per shape file in `folder` (sorted): name, metrics or error, seconds."""
    rows = []
    for path in sorted(p for p in folder.iterdir() if p.suffix.lower() in SUPPORTED_EXTENSIONS):
        started = time.perf_counter()
        try:
            shape = sweepedit.load_shape(path)
            abstraction = sweepedit.fit(shape, primitives, progress=False)
            metrics = sweepedit.evaluate(abstraction, shape)
        except sweepedit.SweepeditError as exc:
            rows.append({"shape": path.name, "error": str(exc)})
            continue
        if out is not None:
            abstraction.save(out / f"{path.stem}.json")
        rows.append({"shape": path.name, "primitives": metrics.primitives, "iou": metrics.iou,
                     "cd_l1": metrics.cd_l1, "f1_0.05": metrics.f1_0_05,
                     "f1_0.01": metrics.f1_0_01, "seconds": time.perf_counter() - started})
    return rows


def markdown(rows: list[dict]) -> str:
    lines = ["| shape | primitives | IoU | CD-L1 | F1@0.05 | F1@0.01 | seconds |",
             "|---|---:|---:|---:|---:|---:|---:|"]
    for r in rows:
        if "error" in r:
            lines.append(f"| {r['shape']} | failed: {r['error']} ||||||")
        else:
            lines.append(f"| {r['shape']} | {r['primitives']} | {r['iou']:.3f} | "
                         f"{r['cd_l1']:.4f} | {r['f1_0.05']:.3f} | {r['f1_0.01']:.3f} | "
                         f"{r['seconds']:.1f} |")
    return "\n".join(lines)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("folder", type=Path)
    parser.add_argument("--primitives", default="8", help="a count, or auto (8)")
    parser.add_argument("--out", type=Path, default=None, help="folder for the parameters")
    args = parser.parse_args()
    primitives = args.primitives if args.primitives == "auto" else int(args.primitives)
    if args.out is not None:
        args.out.mkdir(parents=True, exist_ok=True)
    rows = abstract_folder(args.folder, primitives, args.out)
    print(markdown(rows))
    return 1 if any("error" in r for r in rows) else 0


if __name__ == "__main__":
    sys.exit(main())
