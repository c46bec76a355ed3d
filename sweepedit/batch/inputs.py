"""What `sweepedit batch INPUT...` fits: shape files, folders, globs and lists, expanded.

- a shape file is taken as it is (any format `sweepedit.io.shapes.load_shape` reads);
- a folder is walked recursively for the shape formats, skipping hidden entries and the
  output folder; `.txt` files inside folders are not taken (a folder's READMEs and
  licences are text too), name a `.txt` point cloud directly or in a list instead;
- a glob (`data/**/*.obj`, quoted so that the shell leaves it alone) expands like Python's
  `glob` with `recursive=True`;
- a list: a `.csv` (the column `path`, `shape` or `file` when the first row is a header,
  else the first column) or a `.txt` whose first entry is not a row of numbers (else it
  is a point cloud), one shape per line, `#` comments allowed, relative paths taken from
  the list's folder. A listed file that is missing becomes a failed row, not an error for
  the whole job.

Each shape gets an output name: its file stem, or for stems that clash, its path under
the common folder joined with "__" (and the extension, when still needed).
"""

from __future__ import annotations

import csv
import glob
import os
from collections import defaultdict
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from sweepedit.errors import SweepeditError
from sweepedit.io.shapes import SUPPORTED_EXTENSIONS

# Shape formats that a folder walk takes (everything load_shape reads except .txt).
FOLDER_EXTENSIONS = tuple(e for e in SUPPORTED_EXTENSIONS if e != ".txt")
_LIST_COLUMNS = ("path", "shape", "file")
_GLOB_CHARS = "*?["


@dataclass(frozen=True)
class ShapeInput:
    """One shape of a job: the file and the name of its outputs (OUTDIR/<name>.json)."""

    path: Path
    name: str


def expand_inputs(inputs: Sequence[str | Path], exclude: str | Path | None = None
                  ) -> list[ShapeInput]:
    """The shapes named by INPUT arguments, in order, each once, with unique names.

    `exclude`: a folder whose contents are never taken (the output folder). Raises
    SweepeditError for an argument that names nothing (no such path, a glob without
    matches, a folder without shapes) and when there is no shape at all.
    """
    skip = Path(exclude).resolve() if exclude is not None else None
    paths: list[Path] = []
    for item in inputs:
        paths += _expand_one(str(item), skip)
    unique: dict[Path, Path] = {}
    for path in paths:
        unique.setdefault(path.resolve(), path)
    if not unique:
        raise SweepeditError("no shapes to fit in the given inputs")
    files = list(unique.values())
    return [ShapeInput(p, n) for p, n in zip(files, unique_names(files), strict=True)]


def _expand_one(item: str, skip: Path | None) -> list[Path]:
    path = Path(item)
    if path.is_dir():
        found = _walk(path, skip)
        if not found:
            raise SweepeditError(f"{item}: no shape files in this folder "
                                 f"({' '.join(FOLDER_EXTENSIONS)})")
        return found
    if path.is_file():
        if path.suffix.lower() == ".csv" or (path.suffix.lower() == ".txt"
                                             and _is_list(path)):
            return _read_list(path)
        return [path]
    if any(c in item for c in _GLOB_CHARS):
        matches = sorted(glob.glob(item, recursive=True))
        found = []
        for match in matches:
            m = Path(match)
            if m.is_dir():
                found += _walk(m, skip)
            elif m.suffix.lower() in SUPPORTED_EXTENSIONS and not _inside(m, skip):
                found.append(m)
        if not found:
            raise SweepeditError(f"{item}: the pattern matches no shape file")
        return found
    raise SweepeditError(f"{item}: no such file or folder")


def _inside(path: Path, folder: Path | None) -> bool:
    return folder is not None and path.resolve().is_relative_to(folder)


def _walk(folder: Path, skip: Path | None) -> list[Path]:
    """Shape files under a folder, recursively, sorted by path; hidden entries skipped."""
    found = []
    for root, dirs, files in os.walk(folder):
        here = Path(root)
        dirs[:] = sorted(d for d in dirs if not d.startswith(".")
                         and not _inside(here / d, skip))
        found += [here / f for f in sorted(files)
                  if not f.startswith(".") and Path(f).suffix.lower() in FOLDER_EXTENSIONS]
    return found


def _is_list(path: Path) -> bool:
    """A .txt is a list of shapes unless its first entry is a row of numbers (a cloud)."""
    try:
        with open(path, encoding="utf-8", errors="replace") as handle:
            for line in handle:
                text = line.strip()
                if not text or text.startswith("#"):
                    continue
                try:
                    [float(t) for t in text.replace(",", " ").split()]
                except ValueError:
                    return True
                return False
    except OSError as exc:
        raise SweepeditError(f"{path}: cannot read ({exc.strerror or exc})") from None
    return True  # an empty list


def _read_list(path: Path) -> list[Path]:
    """The shapes of a .txt or .csv list, relative paths from the list's folder."""
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise SweepeditError(f"{path}: cannot read the list ({exc})") from None
    lines = [ln for ln in text.splitlines() if ln.strip() and not ln.lstrip().startswith("#")]
    if path.suffix.lower() == ".csv":
        rows = [r for r in csv.reader(lines) if r]
        column = 0
        if rows:
            header = [c.strip().lower() for c in rows[0]]
            named = [c for c in _LIST_COLUMNS if c in header]
            if named:
                column = header.index(named[0])
                rows = rows[1:]
        entries = [r[column].strip() for r in rows if len(r) > column and r[column].strip()]
    else:
        entries = [ln.strip() for ln in lines]
    if not entries:
        raise SweepeditError(f"{path}: the list names no shapes")
    return [p if p.is_absolute() else path.parent / p for p in map(Path, entries)]


def unique_names(paths: Sequence[Path]) -> list[str]:
    """An output name per path: the stem, or where stems clash the path below the clashing
    files' common folder joined with "__" (plus "_ext" if that still clashes)."""
    names = [p.stem for p in paths]
    groups: dict[str, list[int]] = defaultdict(list)
    for i, name in enumerate(names):
        groups[name].append(i)
    for indices in groups.values():
        if len(indices) < 2:
            continue
        resolved = [paths[i].resolve() for i in indices]
        common = Path(os.path.commonpath([str(r.parent) for r in resolved]))
        for i, r in zip(indices, resolved, strict=True):
            rel = r.relative_to(common)
            names[i] = "__".join([*rel.parts[:-1], rel.stem])
    counts: dict[str, int] = defaultdict(int)
    for name in names:
        counts[name] += 1
    return [f"{n}_{p.suffix.lower().lstrip('.')}" if counts[n] > 1 else n
            for n, p in zip(names, paths, strict=True)]
