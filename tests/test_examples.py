"""The scripts in examples/ run as a user would run them."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import trimesh

ROOT = Path(__file__).resolve().parents[1]
CACTUS = ROOT / "resources" / "examples" / "cactus.off"


def run_example(name: str, *args: str | Path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, str(ROOT / "examples" / name), *map(str, args)],
                          capture_output=True, text=True, timeout=300)


@pytest.mark.slow
def test_abstract_folder_tables_every_shape_and_reports_the_bad_one(tmp_path: Path) -> None:
    folder = tmp_path / "shapes"
    folder.mkdir()
    shutil.copy(CACTUS, folder / "cactus.off")
    trimesh.creation.capsule(height=1.0, radius=0.3).export(folder / "capsule.stl")
    (folder / "broken.obj").write_text("v 0 0 0\nf 1 2 3\n")
    (folder / "notes.md").write_text("not a shape")  # not a shape file: skipped
    out = tmp_path / "params"
    done = run_example("abstract_folder.py", folder, "--primitives", "2", "--out", out)
    assert done.returncode == 1, done.stderr  # one file failed
    rows = [line for line in done.stdout.splitlines() if line.startswith("| ")][1:]
    assert [r.split("|")[1].strip() for r in rows] == ["broken.obj", "cactus.off",
                                                       "capsule.stl"]
    assert "failed: " in rows[0] and "broken.obj" in rows[0]
    capsule_iou = float(rows[2].split("|")[3])
    assert capsule_iou > 0.9  # a capsule is one sweep
    assert sorted(p.name for p in out.iterdir()) == ["cactus.json", "capsule.json"]


@pytest.mark.slow
def test_edit_and_export_thickens_and_writes(tmp_path: Path) -> None:
    out = tmp_path / "thick.glb"
    done = run_example("edit_and_export.py", CACTUS, out, "--primitives", "2")
    assert done.returncode == 0, done.stderr
    assert out.is_file()
    ratio = float(done.stdout.split("volume x")[1].split()[0])
    assert 1.2 < ratio <= 1.2**2 + 0.01  # each profile's area grows 1.44 times; overlaps
    bad = run_example("edit_and_export.py", tmp_path / "missing.obj", out)
    assert bad.returncode == 2 and "missing.obj: no such file" in bad.stderr
    assert "Traceback" not in bad.stderr
