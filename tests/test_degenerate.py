"""Degenerate shapes fail fast (issue 18): the corpus in tests/data/degenerate, through the
API (`load_shape`, `fit_abstraction`) and the CLI (`sweepedit fit`, `sweepedit inspect`).

Each error case must give one line naming the file and the problem within 2 s (exit
status 2); each case with a correct answer must load as that answer (an analytic box or
volume), whatever the size or place of its coordinates.
"""

from __future__ import annotations

import importlib
import json
import time
from pathlib import Path

import numpy as np
import pytest
import trimesh

from sweepedit import errors
from sweepedit.cli import main
from sweepedit.io import occupancy as occ
from sweepedit.io.shapes import Shape, load_shape

CORPUS = Path(__file__).parent / "data" / "degenerate"
CASES = json.loads((CORPUS / "cases.json").read_text())["cases"]
ERRORS = sorted(name for name, case in CASES.items() if "error" in case)
LOADS = sorted(name for name, case in CASES.items() if "loads" in case)
FAIL_FAST_S = 3.0  # a refusal, not a fit: ms idle; room for a loaded runner
R = occ.DEFAULT_RESOLUTION


def test_the_corpus_is_complete():
    files = {p.name for p in CORPUS.iterdir() if p.suffix not in (".py", ".json", ".md")}
    assert files == set(CASES), "every file has a case and every case a file"


@pytest.fixture(scope="module")
def warm_cli() -> None:
    """Import what `fit` and `inspect` import, so that timings measure the work only."""
    for module in ("tqdm", "sweepedit.analysis.metrics", "sweepedit.analysis.skeleton",
                   "sweepedit.fitting.fit", "sweepedit.io.params", "sweepedit.io.shapes"):
        importlib.import_module(module)


def _box_cells(extents: list[float]) -> np.ndarray:
    """(R, R, R) bool: the cell centres inside the normalised box of these extents
    (centred at the origin), counted analytically."""
    c = occ.cell_coordinates(R)
    inside = [np.abs(c) < e / 2 for e in extents]
    return inside[0][:, None, None] & inside[1][None, :, None] & inside[2][None, None, :]


@pytest.mark.parametrize("name", ERRORS)
def test_error_cases_through_the_api(name: str):
    case = CASES[name]
    path = CORPUS / name
    start = time.perf_counter()
    with pytest.raises(errors.FileFormatError) as info:
        load_shape(path)
    elapsed = time.perf_counter() - start
    assert type(info.value) is getattr(errors, case["error"])
    assert info.value.path == str(path)
    assert str(info.value).startswith(f"{path}: ") and case["message"] in str(info.value)
    assert "\n" not in str(info.value)
    assert elapsed < FAIL_FAST_S, f"{name}: {elapsed:.2f} s"


@pytest.mark.parametrize("name", ERRORS)
def test_error_cases_through_the_cli(name: str, tmp_path: Path, capsys, warm_cli):
    case = CASES[name]
    path = CORPUS / name
    out = tmp_path / "out.json"
    for argv in (["fit", str(path), "-o", str(out), "--quiet"], ["inspect", str(path)]):
        start = time.perf_counter()
        status = main(argv)
        elapsed = time.perf_counter() - start
        captured = capsys.readouterr()
        lines = captured.err.strip().splitlines()
        assert status == 2, (argv, captured.err)
        assert len(lines) == 1 and lines[0].startswith("sweepedit: error: "), captured.err
        assert str(path) in lines[0] and case["message"] in lines[0]
        assert elapsed < FAIL_FAST_S, f"{argv[0]} {name}: {elapsed:.2f} s"
    assert not out.exists()


@pytest.mark.parametrize("name", LOADS)
def test_cases_with_an_answer_load_as_it(name: str):
    case = CASES[name]
    shape = load_shape(CORPUS / name, n_samples=2000)
    if case["loads"] == "box":
        # Normalised: the same cells whatever the size and place of the coordinates.
        assert np.array_equal(shape.winding_occupancy, _box_cells(case["extents"]))
        assert np.array_equal(shape.occupancy, shape.winding_occupancy)
        assert shape.normalization.scale == pytest.approx(case["scale"], rel=1e-12)
        assert np.allclose(shape.normalization.center, case["center"], rtol=1e-12,
                           atol=1e-9 * case["scale"])
        # Back in the file's frame, the corners are the file's up to float64 steps there.
        corners = shape.normalization.to_original(shape.surface.bounds)
        half = np.array(case["extents"]) * case["scale"] / 2
        expected = np.array([np.subtract(case["center"], half), np.add(case["center"], half)])
        step = np.spacing(np.max(np.abs(case["center"])))
        assert np.allclose(corners, expected, rtol=0, atol=1e-9 * case["scale"] + 4 * step)
    else:
        volume = shape.winding_occupancy.sum() / R**3
        assert volume == pytest.approx(case["volume"], rel=0.03)


def test_inspect_reports_the_tiny_and_huge_boxes(capsys, warm_cli):
    for name, scale in (("tiny_box.off", "1e-12"), ("huge_box.off", "1e+12")):
        assert main(["inspect", str(CORPUS / name)]) == 0
        out = capsys.readouterr().out
        assert f"scale {scale}" in out and "watertight True, components 1" in out


def test_fit_refuses_a_shape_that_encloses_nothing_at_once(warm_cli):
    """A Shape built without load_shape (as the app or a script may): the fit's own
    check stops it before any work (it used to fit for 41 s and end in a traceback)."""
    from sweepedit.fitting.fit import FitSettings, fit_abstraction
    from sweepedit.geometry.model import Normalization

    triangle = trimesh.Trimesh([[-0.5, -0.5, 0.0], [0.5, -0.5, 0.0], [0.0, 0.5, 0.0]],
                               [[0, 1, 2]])
    grids, samples = occ.voxelize_mesh(triangle, R, n_samples=2000)
    assert grids.occupancy.any() and not grids.winding_occupancy.any()
    shape = Shape(path=Path("triangle.off"), kind="mesh", normalization=Normalization(),
                  surface=triangle, occupancy=grids.occupancy,
                  winding_occupancy=grids.winding_occupancy, samples=samples)
    start = time.perf_counter()
    with pytest.raises(errors.DegenerateShapeError, match=r"triangle.off: .*0 of the 64"):
        fit_abstraction(shape, FitSettings(primitives=2))
    assert time.perf_counter() - start < 2.0  # refused before any fitting


def test_fit_of_a_box_1e_12_across_keeps_its_frame(tmp_path: Path, capsys):
    """Normalisation copes with tiny coordinates end to end: the parameter file is in the
    normalised frame with the box's own centre and scale beside it."""
    out = tmp_path / "tiny.json"
    # Few fixed steps (the result does not depend on the machine's load); the time limit
    # only takes the quick metrics.
    assert main(["fit", str(CORPUS / "tiny_box.off"), "-o", str(out), "--quiet",
                 "--primitives", "2", "--refine-iterations", "40", "--residual-rounds", "0",
                 "--time-limit", "60"]) == 0
    capsys.readouterr()
    doc = json.loads(out.read_text())
    assert doc["normalization"]["scale"] == pytest.approx(1e-12, rel=1e-12)
    assert np.allclose(doc["normalization"]["center"], [-2e-12] * 3, rtol=1e-12)
    # A box by sweeps is not exact, but far from nothing: the protocol's IoU.
    assert doc["fit"]["metrics"]["iou"] > 0.6
