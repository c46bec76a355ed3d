"""The benchmark set that ships with sweepedit: 19 shapes whose licences allow it.

The shapes live inside the package (sweepedit/resources/benchmark/, declared as package
data), so `sweepedit bench` finds them in a clone and after `pip install` alike. Their
manifest.json says for each where it comes from and under which licence; README.md
there lists the same for people. Only licences that allow redistribution are shipped
(ALLOWED_LICENCES); shapes that are research-only, GPL or of unknown licence are not.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from sweepedit.errors import FileFormatError

__all__ = ["ALLOWED_LICENCES", "BENCHMARK_DIR", "BenchmarkShape", "benchmark_shapes"]

# Not importlib.resources: bench and batch need a real folder to hand to their file
# walkers, and setuptools installs package data as plain files beside the modules.
BENCHMARK_DIR = Path(__file__).resolve().parents[1] / "resources" / "benchmark"
MANIFEST_NAME = "manifest.json"

# Licence identifiers a manifest may use (SPDX where one exists): each allows copying
# the file with the project, given the attribution the manifest records.
ALLOWED_LICENCES = frozenset({"CC0-1.0", "public-domain", "MIT", "BSD-2-Clause",
                              "BSD-3-Clause", "CC-BY-3.0", "CC-BY-4.0", "Bitstream-Vera"})
_REQUIRED = ("name", "file", "source", "original", "licence", "attribution")


@dataclass(frozen=True)
class BenchmarkShape:
    """One shape of the bundled set: `path` is the file; the rest is its manifest entry."""

    name: str
    path: Path
    source: str
    original: str
    licence: str
    attribution: str
    tag: str = ""


def benchmark_shapes(folder: str | Path = BENCHMARK_DIR) -> list[BenchmarkShape]:
    """The shapes of a benchmark folder's manifest.json, in manifest order.

    Raises FileFormatError (naming the manifest) when it is missing or malformed, an entry
    lacks a field, names a file that is not there, or has a licence outside
    ALLOWED_LICENCES.
    """
    folder = Path(folder)
    manifest = folder / MANIFEST_NAME
    try:
        entries = json.loads(manifest.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise FileFormatError(manifest, "no benchmark manifest here") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise FileFormatError(manifest, f"cannot read the manifest ({exc})") from exc
    if not isinstance(entries, list):
        raise FileFormatError(manifest, "expected a JSON list of shape entries")
    return [_entry(manifest, i, e) for i, e in enumerate(entries)]


def _entry(manifest: Path, index: int, entry: Any) -> BenchmarkShape:
    where = f"entry {index + 1}"
    if not isinstance(entry, dict):
        raise FileFormatError(manifest, f"{where}: expected an object")
    for key in _REQUIRED:
        if not isinstance(entry.get(key), str) or not entry[key]:
            raise FileFormatError(manifest, f"{where}: missing or empty text field {key!r}")
    if entry["licence"] not in ALLOWED_LICENCES:
        raise FileFormatError(manifest, f"{where} ({entry['name']}): licence "
                              f"{entry['licence']!r} is not one that allows shipping the "
                              f"shape ({', '.join(sorted(ALLOWED_LICENCES))})")
    # A bare file name: the manifest describes its own folder, nothing outside it.
    if Path(entry["file"]).name != entry["file"]:
        raise FileFormatError(manifest, f"{where}: 'file' must be a file name in the "
                              f"manifest's folder, got {entry['file']!r}")
    path = manifest.parent / entry["file"]
    if not path.is_file():
        raise FileFormatError(manifest, f"{where}: {entry['file']} is not in {manifest.parent}")
    return BenchmarkShape(name=entry["name"], path=path, source=entry["source"],
                          original=entry["original"], licence=entry["licence"],
                          attribution=entry["attribution"], tag=str(entry.get("tag", "")))
