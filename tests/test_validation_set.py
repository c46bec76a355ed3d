"""The validation set (benchmarks/validation/): the manifest describes exactly the files
there, every licence allows shipping them, none of them is a benchmark shape, and every
shape loads as a solid. The checks return their problems as text so that the tests below
can also show that a broken copy of the set is caught."""

from __future__ import annotations

import hashlib
import json
import re
import shutil
from collections.abc import Callable
from pathlib import Path

import pytest

from sweepedit.io.benchmark_set import BENCHMARK_DIR, benchmark_shapes
from sweepedit.io.shapes import SUPPORTED_EXTENSIONS, load_shape

ROOT = Path(__file__).resolve().parents[1]
VALIDATION_DIR = ROOT / "benchmarks" / "validation"
# ../shared/shapes next to the checkout: the 30 benchmark shapes (absent in some checkouts).
SHARED_SHAPES = ROOT.parent / "shared" / "shapes"
# Files of the folder that are not shapes; licence notices live in LICENSES/.
DOCUMENTS = {"manifest.json", "README.md"}
LICENSES_DIR = "LICENSES"
MIN_SHAPES = 15

FIELDS = ("name", "file", "source", "original", "commit", "licence", "attribution", "tag")
TAGS = {"quadruped", "many-limbs", "human", "hand", "tubular", "tool", "mechanical", "organic",
        "other"}
# Licences that allow shipping a file in an MIT-licensed repository (given the attribution
# or notice the manifest records). Not: GPL, share-alike, non-commercial, research-only.
PERMISSIVE = {"CC0-1.0", "public-domain", "CC-BY-3.0", "CC-BY-4.0", "MIT", "BSD-2-Clause",
              "BSD-3-Clause", "Apache-2.0"}
# Licences whose text or notice must travel with the copy: licence_text names a file.
NOTICE_REQUIRED = {"MIT", "BSD-2-Clause", "BSD-3-Clause", "Apache-2.0"}
# The 30 benchmark shapes (BENCHMARKS.md), also when ../shared is absent.
BENCHMARK_NAMES = {
    "ant", "balloondog", "bike_frame", "bone", "bull", "cactus", "camel", "cat", "dino",
    "eight", "elephant", "femur", "fertility", "glyph_8", "glyph_G", "glyph_S", "glyph_at",
    "hammer", "hand", "hand_ok", "handlebar", "horse", "knot1", "koala", "man", "octopus",
    "scorpion", "screwdriver", "spot", "triceratops",
}


def _manifest(folder: Path = VALIDATION_DIR) -> list[dict]:
    return json.loads((folder / "manifest.json").read_text(encoding="utf-8"))


def _sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _shape_files(folder: Path) -> list[Path]:
    return sorted(p for p in folder.iterdir()
                  if p.is_file() and p.suffix.lower() in SUPPORTED_EXTENSIONS)


def _manifest_problems(folder: Path) -> list[str]:
    """What is wrong with the folder's manifest and files (empty when all is well)."""
    problems: list[str] = []
    entries = _manifest(folder)
    if len(entries) < MIN_SHAPES:
        problems.append(f"only {len(entries)} shapes, want at least {MIN_SHAPES}")
    for i, entry in enumerate(entries):
        where = f"entry {i + 1} ({entry.get('name')})"
        for key in FIELDS:
            if not isinstance(entry.get(key), str) or not entry[key].strip():
                problems.append(f"{where}: missing or empty {key!r}")
        if problems and problems[-1].startswith(where):
            continue
        if "modified" not in entry or not (entry["modified"] is None
                                           or isinstance(entry["modified"], str)):
            problems.append(f"{where}: 'modified' must be null or a description")
        if not re.fullmatch(r"[0-9a-f]{40}", entry["commit"]):
            problems.append(f"{where}: commit {entry['commit']!r} is not a git commit id")
        if not re.fullmatch(r"[\w.-]+/[\w.-]+", entry["source"]):
            problems.append(f"{where}: source {entry['source']!r} is not owner/name")
        if entry["tag"] not in TAGS:
            problems.append(f"{where}: tag {entry['tag']!r} not one of {sorted(TAGS)}")
        if not re.fullmatch(r"[a-z0-9_]+", entry["name"]):
            problems.append(f"{where}: name is not lowercase with underscores")
        file = entry["file"]
        if Path(file).name != file or not re.fullmatch(r"[a-z0-9_]+\.[a-z]+", file):
            problems.append(f"{where}: file {file!r} is not a plain file name")
        elif not (folder / file).is_file():
            problems.append(f"{where}: file {file} does not exist")
        elif Path(file).suffix not in (".obj", ".ply", ".stl", ".off"):
            problems.append(f"{where}: {file} is not OBJ, PLY, STL or OFF")
        license_id = entry["licence"]
        if license_id not in PERMISSIVE:
            problems.append(f"{where}: licence {license_id!r} does not allow shipping")
        if license_id.startswith("CC-BY") and len(entry["attribution"]) < 20:
            problems.append(f"{where}: a CC BY shape needs a real attribution")
        text = entry.get("licence_text") or ""
        if license_id in NOTICE_REQUIRED and not text.startswith(f"{LICENSES_DIR}/"):
            problems.append(f"{where}: {license_id} needs its notice in {LICENSES_DIR}/")
        if text and not text.startswith("https://") and not (folder / text).is_file():
            problems.append(f"{where}: licence text {text} does not exist")
    names = [e.get("name") for e in entries]
    files = [e.get("file") for e in entries]
    for what, values in (("name", names), ("file", files)):
        doubles = sorted({v for v in values if values.count(v) > 1})
        if doubles:
            problems.append(f"{what}s listed twice: {doubles}")
    # Nothing unlisted in the folder: documents, listed shapes, and the notices they cite.
    cited = {e.get("licence_text") for e in entries}
    for path in sorted(folder.rglob("*")):
        if not path.is_file():
            continue
        rel = path.relative_to(folder).as_posix()
        if not (rel in DOCUMENTS or rel in files or rel in cited):
            problems.append(f"unlisted file {rel}")
        elif path.suffix.lower() in SUPPORTED_EXTENSIONS and rel not in files:
            # A walker (sweepedit bench/batch) would take it for a shape.
            problems.append(f"{rel} has a shape file's extension")
    return problems


def _overlap_problems(folder: Path, benchmark_folders: list[Path]) -> list[str]:
    """Names or file contents that the validation set shares with the benchmark shapes."""
    problems: list[str] = []
    entries = _manifest(folder)
    taken = {name.lower() for name in BENCHMARK_NAMES}
    digests: dict[str, str] = {}
    for bench in benchmark_folders:
        for path in _shape_files(bench):
            taken.add(path.stem.lower())
            digests[_sha256(path)] = f"{bench.name}/{path.name}"
        manifest = bench / "manifest.json"
        if manifest.is_file():
            taken |= {e["name"].lower() for e in json.loads(manifest.read_text("utf-8"))}
    for entry in entries:
        name, file = entry["name"], entry["file"]
        if name.lower() in taken or Path(file).stem.lower() in taken:
            problems.append(f"{name}: name of a benchmark shape")
        path = folder / file
        if path.is_file() and _sha256(path) in digests:
            problems.append(f"{name}: same bytes as benchmark shape {digests[_sha256(path)]}")
    return problems


# --------------------------------------------------------------------------- the set


def test_manifest_lists_exactly_the_files_present_with_permissive_licences() -> None:
    assert _manifest_problems(VALIDATION_DIR) == []


def test_the_benchmark_set_reader_takes_the_manifest() -> None:
    # `sweepedit bench --shapes benchmarks/validation` and the bundled set share one reader.
    shapes = benchmark_shapes(VALIDATION_DIR)
    assert [s.name for s in shapes] == [e["name"] for e in _manifest()]
    assert all(s.path.is_file() for s in shapes)


def test_no_shape_is_a_bundled_benchmark_shape() -> None:
    assert _overlap_problems(VALIDATION_DIR, [BENCHMARK_DIR]) == []


def test_no_shape_is_one_of_the_30_shared_benchmark_shapes() -> None:
    if not SHARED_SHAPES.is_dir():
        pytest.skip(f"shared shapes folder {SHARED_SHAPES} is absent")
    # The names above are the shared shapes' names (so the name check holds without it).
    assert {p.stem for p in _shape_files(SHARED_SHAPES)} >= BENCHMARK_NAMES
    assert _overlap_problems(VALIDATION_DIR, [SHARED_SHAPES]) == []


def test_readme_lists_every_shape_with_its_licence() -> None:
    readme = (VALIDATION_DIR / "README.md").read_text(encoding="utf-8")
    rows = {line.split("|")[1].strip().strip("`"): line.split("|")
            for line in readme.splitlines() if line.startswith("| `")}
    entries = _manifest()
    assert set(rows) == {e["file"] for e in entries}
    for entry in entries:
        assert rows[entry["file"]][5].strip() == entry["licence"], entry["file"]


def test_licence_notices_are_the_texts() -> None:
    for entry in _manifest():
        if entry["licence"] in NOTICE_REQUIRED:
            text = (VALIDATION_DIR / entry["licence_text"]).read_text(encoding="utf-8")
            assert "Redistribution" in text or "Permission is hereby granted" in text, entry
            assert "Copyright" in text, entry


@pytest.mark.slow
def test_every_shape_loads_as_a_solid() -> None:
    """At the fitting resolution (the default): the sword's blade is thinner than a cell of
    coarser grids."""
    for entry in _manifest():
        shape = load_shape(VALIDATION_DIR / entry["file"], n_samples=256)
        assert shape.kind == "mesh", entry["name"]
        # Encloses a volume by the winding number, and is not the whole cube.
        assert shape.winding_occupancy.sum() >= 2, entry["name"]
        assert 0.0 < shape.occupancy.mean() < 0.5, entry["name"]


# --------------------------------------------------------------------------- the checks


def _copy_set(tmp_path: Path) -> Path:
    folder = tmp_path / "validation"
    shutil.copytree(VALIDATION_DIR, folder)
    return folder


def _edit_manifest(folder: Path, change: Callable[[list[dict]], object]) -> None:
    entries = _manifest(folder)
    change(entries)
    (folder / "manifest.json").write_text(json.dumps(entries), encoding="utf-8")


@pytest.mark.parametrize("change, message", [
    (lambda es: es[0].update(licence="GPL-3.0"), "does not allow shipping"),
    (lambda es: es[0].update(licence="CC-BY-SA-4.0"), "does not allow shipping"),
    (lambda es: es[0].update(licence="CC-BY-NC-4.0"), "does not allow shipping"),
    (lambda es: es[0].update(file="missing.obj"), "does not exist"),
    (lambda es: es[0].update(file="../fox.obj"), "plain file name"),
    (lambda es: es[0].update(attribution=""), "missing or empty 'attribution'"),
    (lambda es: es[0].update(commit="HEAD"), "not a git commit id"),
    (lambda es: es[0].update(tag="animal"), "tag 'animal'"),
    (lambda es: es.pop(), "unlisted file"),
    (lambda es: es.append(dict(es[0])), "listed twice"),
    (lambda es: es.__delitem__(slice(MIN_SHAPES - 1, None)), "want at least"),
    (lambda es: next(e for e in es if e["licence"] == "BSD-3-Clause").pop("licence_text"),
     "needs its notice"),
])
def test_a_broken_manifest_is_caught(tmp_path: Path, change: Callable[[list[dict]], object],
                                    message: str) -> None:
    folder = _copy_set(tmp_path)
    _edit_manifest(folder, change)
    assert any(message in p for p in _manifest_problems(folder)), _manifest_problems(folder)


def test_a_stray_file_is_caught(tmp_path: Path) -> None:
    folder = _copy_set(tmp_path)
    (folder / "LICENSES" / "notes.txt").write_text("1 2 3\n", encoding="utf-8")
    problems = _manifest_problems(folder)
    assert "unlisted file LICENSES/notes.txt" in problems


def test_a_benchmark_shape_is_caught(tmp_path: Path) -> None:
    folder = _copy_set(tmp_path)
    # A benchmark file under a new name, and a new file under a benchmark name.
    shutil.copy(BENCHMARK_DIR / "cactus.off", folder / "fox.obj")
    _edit_manifest(folder, lambda es: es[1].update(name="horse"))
    problems = _overlap_problems(folder, [BENCHMARK_DIR])
    assert any("fox: same bytes as benchmark shape benchmark/cactus.off" in p
               for p in problems), problems
    assert "horse: name of a benchmark shape" in problems
