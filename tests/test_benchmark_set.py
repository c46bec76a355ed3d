"""The benchmark set bundled with sweepedit: what the manifest says is what ships, every
licence allows shipping, every shape loads, and an installed package carries it."""

from __future__ import annotations

import json
import re
import shutil
from pathlib import Path

import pytest

from sweepedit.errors import FileFormatError
from sweepedit.io.benchmark_set import ALLOWED_LICENCES, BENCHMARK_DIR, benchmark_shapes
from sweepedit.io.shapes import SUPPORTED_EXTENSIONS, load_shape

ROOT = Path(__file__).resolve().parents[1]
# Files of the folder that are not shapes.
DOCUMENTS = {"manifest.json", "README.md"}


def _plain(text: str) -> str:
    """'CC-BY-4.0' and 'CC BY 4.0' alike."""
    return re.sub(r"[\s-]", "", text.lower())


def _manifest() -> list[dict]:
    return json.loads((BENCHMARK_DIR / "manifest.json").read_text(encoding="utf-8"))


def test_manifest_lists_exactly_the_files_present() -> None:
    listed = [entry["file"] for entry in _manifest()]
    assert len(listed) == len(set(listed))
    present = {p.name for p in BENCHMARK_DIR.iterdir() if p.is_file()} - DOCUMENTS
    assert set(listed) == present
    names = [entry["name"] for entry in _manifest()]
    assert len(names) == len(set(names))
    # Nothing in the folder that a recursive shape walker (batch) would take for a shape.
    for path in BENCHMARK_DIR.rglob("*"):
        if path.is_file() and path.suffix.lower() in SUPPORTED_EXTENSIONS:
            assert path.parent == BENCHMARK_DIR and path.name in listed, path


def test_every_licence_allows_shipping() -> None:
    entries = _manifest()
    for entry in entries:
        for key in ("name", "file", "source", "original", "licence", "attribution"):
            assert isinstance(entry.get(key), str) and entry[key], (entry.get("name"), key)
        assert entry["licence"] in ALLOWED_LICENCES, entry["name"]
        if entry["licence"].startswith("CC-BY"):
            assert " by " in entry["attribution"], entry["name"]  # names the author
        text = entry.get("licence_text", "")
        if text and not text.startswith("https://"):
            assert (BENCHMARK_DIR / text).is_file(), text
    # The licences that require their notice to travel with the copy have it here.
    assert {"MIT", "Bitstream-Vera"} <= {e["licence"] for e in entries}
    assert "Permission is hereby granted" in (
        BENCHMARK_DIR / "LICENSES" / "LICENSE-PyVista").read_text(encoding="utf-8")
    assert "Bitstream Vera" in (
        BENCHMARK_DIR / "LICENSES" / "LICENSE-DejaVu").read_text(encoding="utf-8")


def test_readme_lists_every_shape_with_its_licence() -> None:
    readme = (BENCHMARK_DIR / "README.md").read_text(encoding="utf-8")
    rows = {line.split("|")[1].strip().strip("`"): line for line in readme.splitlines()
            if line.startswith("| `")}
    for entry in _manifest():
        assert entry["file"] in rows, entry["file"]
        licence_cell = rows[entry["file"]].split("|")[3]
        assert _plain(entry["licence"]) == _plain(licence_cell), entry["file"]


@pytest.mark.slow
def test_every_shape_loads() -> None:
    shapes = benchmark_shapes()
    assert len(shapes) == len(_manifest())
    for shape in shapes:
        loaded = load_shape(shape.path, resolution=16, n_samples=256)
        assert loaded.kind == "mesh", shape.name
        # A real solid: something inside, and not the whole cube.
        assert 0.0 < loaded.occupancy.mean() < 0.5, shape.name


def test_bench_defaults_to_the_bundled_set() -> None:
    from sweepedit.cli import build_parser

    parser = build_parser()
    assert Path(parser.parse_args(["bench"]).shapes) == BENCHMARK_DIR
    # No command's help points a user at a folder outside the repository.
    commands = parser._subparsers._group_actions[0].choices  # type: ignore[union-attr]
    for name, sub in commands.items():
        assert "../shared" not in sub.format_help(), name


def _copy_set(tmp_path: Path) -> Path:
    folder = tmp_path / "set"
    folder.mkdir()
    for name in ("manifest.json", "cactus.off"):
        shutil.copy(BENCHMARK_DIR / name, folder / name)
    entries = [e for e in _manifest() if e["file"] == "cactus.off"]
    (folder / "manifest.json").write_text(json.dumps(entries), encoding="utf-8")
    return folder


def test_benchmark_shapes_reads_a_manifest(tmp_path: Path) -> None:
    folder = _copy_set(tmp_path)
    (shape,) = benchmark_shapes(folder)
    assert shape.name == "cactus" and shape.path == folder / "cactus.off"
    assert shape.licence == "CC0-1.0"


@pytest.mark.parametrize("change, message", [
    (lambda e: e.update(licence="GPL-3.0"), "GPL-3.0"),
    (lambda e: e.update(file="missing.off"), "missing.off"),
    (lambda e: e.update(file="../cactus.off"), "file name"),
    (lambda e: e.pop("attribution"), "attribution"),
])
def test_benchmark_shapes_refuses_a_bad_manifest(tmp_path: Path, change, message: str) -> None:
    folder = _copy_set(tmp_path)
    entries = json.loads((folder / "manifest.json").read_text(encoding="utf-8"))
    change(entries[0])
    (folder / "manifest.json").write_text(json.dumps(entries), encoding="utf-8")
    with pytest.raises(FileFormatError, match=message):
        benchmark_shapes(folder)
    with pytest.raises(FileFormatError, match="no benchmark manifest"):
        benchmark_shapes(tmp_path)


@pytest.mark.slow
def test_a_built_wheel_carries_the_set_and_the_schema(tmp_path: Path) -> None:
    """What `pip install` gets: build the wheel from a copy of the package and look in."""
    import subprocess
    import sys
    import zipfile

    source = tmp_path / "src"
    source.mkdir()
    for name in ("pyproject.toml", "README.md"):
        shutil.copy(ROOT / name, source / name)
    shutil.copytree(ROOT / "sweepedit", source / "sweepedit",
                    ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))
    subprocess.run([sys.executable, "-m", "pip", "wheel", "-q", "--no-deps",
                    "--no-build-isolation", str(source), "-w", str(tmp_path / "dist")],
                   check=True, capture_output=True, timeout=240)
    (wheel,) = (tmp_path / "dist").glob("sweepedit-*.whl")
    names = set(zipfile.ZipFile(wheel).namelist())
    for path in BENCHMARK_DIR.rglob("*"):
        if path.is_file():
            assert path.relative_to(ROOT).as_posix() in names, path.name
    assert "sweepedit/io/params.schema.json" in names
