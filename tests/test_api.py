"""The public API (`import sweepedit`): each input kind against the file loaders and the
command line, the metrics against known shapes, exports against analytic volumes, and
Ctrl-C in a real process."""

from __future__ import annotations

import json
import math
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import trimesh

import sweepedit
from sweepedit.cli import main
from sweepedit.geometry.model import Abstraction as ModelAbstraction
from sweepedit.geometry.model import Normalization, SweepPrimitive

CACTUS = Path(__file__).resolve().parents[1] / "resources" / "examples" / "cactus.off"


def cylinder_abstraction(radius: float = 0.2) -> sweepedit.Abstraction:
    """One straight primitive along z through the unit box: a cylinder of the radius,
    length 1 (the normalised frame of a cylinder mesh of that radius and length 1)."""
    prim = SweepPrimitive([[0, 0, -0.5], [0, 0, 0], [0, 0, 0.5]], a=radius, b=radius,
                          degree=2.0, scaling=(0.0, 0.0), name="post", color="#29335c")
    return sweepedit.Abstraction([prim], Normalization([1.0, -2.0, 3.0], 4.0))


def test_import_is_light_and_names_load_on_use() -> None:
    code = ("import sys, sweepedit\n"
            "heavy = [m for m in ('numpy', 'torch', 'trimesh', 'pyvista') if m in sys.modules]\n"
            "assert not heavy, heavy\n"
            "assert callable(sweepedit.fit) and 'sweepedit.api' in sys.modules\n"
            "assert 'torch' not in sys.modules  # only a fit loads torch\n"
            "print(sorted(sweepedit.__all__))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout
    for name in ("load_shape", "fit", "load", "evaluate", "inside", "export", "Abstraction"):
        assert f"'{name}'" in out
    with pytest.raises(AttributeError, match="no attribute 'nope'"):
        _ = sweepedit.nope
    # __all__ is spelled out for linters: it must name exactly what loads on use.
    assert set(sweepedit.__all__) == {*sweepedit._API, *sweepedit._ELSEWHERE, "__version__"}
    assert all(getattr(sweepedit, name) is not None for name in sweepedit.__all__)


def test_load_shape_from_memory_matches_the_file(tmp_path: Path) -> None:
    from_file = sweepedit.load_shape(CACTUS)
    mesh = trimesh.load(CACTUS, process=False)
    from_trimesh = sweepedit.load_shape(mesh)
    assert from_trimesh.kind == "mesh"
    np.testing.assert_array_equal(from_trimesh.winding_occupancy, from_file.winding_occupancy)
    np.testing.assert_allclose(from_trimesh.normalization.center,
                               from_file.normalization.center)
    assert from_trimesh.normalization.scale == pytest.approx(from_file.normalization.scale)

    import pyvista as pv

    mesh.export(tmp_path / "cactus.ply")  # PyVista reads no .off
    from_pyvista = sweepedit.load_shape(pv.read(tmp_path / "cactus.ply"))
    assert from_pyvista.kind == "mesh"
    agree = np.mean(from_pyvista.winding_occupancy == from_file.winding_occupancy)
    assert agree == 1.0

    assert sweepedit.load_shape(from_file) is from_file


def test_points_and_voxels_from_memory_match_their_files(tmp_path: Path) -> None:
    sphere = trimesh.creation.icosphere(subdivisions=4, radius=2.0)
    points, _ = trimesh.sample.sample_surface_even(sphere, 4000, seed=1)
    path = tmp_path / "sphere.xyz"
    np.savetxt(path, points)
    from_file = sweepedit.load_shape(path)
    from_array = sweepedit.load_shape(np.loadtxt(path))
    assert from_array.kind == from_file.kind == "points"
    np.testing.assert_array_equal(from_array.occupancy, from_file.occupancy)

    grid = np.zeros((24, 24, 24), dtype=bool)
    grid[2:22, 8:16, 10:14] = True
    np.save(tmp_path / "bar.npy", grid)
    voxels = sweepedit.load_shape(grid)
    assert voxels.kind == "voxels"
    np.testing.assert_array_equal(voxels.occupancy,
                                  sweepedit.load_shape(tmp_path / "bar.npy").occupancy)
    # The bar fills x over the whole box: 20 of 20 voxels, normalised to [-0.5, 0.5].
    assert voxels.normalization.scale == pytest.approx(20.0)


def test_load_shape_refuses_what_it_cannot_use() -> None:
    with pytest.raises(sweepedit.SweepeditError, match=r"shape \(4, 2\)"):
        sweepedit.load_shape(np.zeros((4, 2)))
    with pytest.raises(sweepedit.SweepeditError, match="cannot load a dict"):
        sweepedit.load_shape({"points": []})
    with pytest.raises(sweepedit.FileFormatError, match="NaN"):
        sweepedit.load_shape(np.full((100, 3), np.nan))
    flat = np.random.default_rng(0).uniform(size=(200, 3))
    flat[:, 2] = 0.0
    with pytest.raises(sweepedit.FileFormatError, match="one plane"):
        sweepedit.load_shape(flat)
    with pytest.raises(sweepedit.FileFormatError, match="points: "):  # named as the data
        sweepedit.load_shape(flat)
    with pytest.raises(sweepedit.SweepeditError, match="no bundled shape named 'nope'"):
        sweepedit.example("nope")


def test_evaluate_a_known_cylinder() -> None:
    """An abstraction that is the shape (up to the mesh's facets) scores as such."""
    cylinder = trimesh.creation.cylinder(radius=0.8, height=4.0, sections=256)
    metrics = sweepedit.evaluate(cylinder_abstraction(radius=0.2), cylinder, n_samples=20_000)
    assert isinstance(metrics, sweepedit.Metrics)
    assert metrics.iou > 0.98
    # Two independent sets of 20,000 samples of one surface (area 1.5) lie ~0.004 apart.
    assert metrics.cd_l1 < 0.006
    assert metrics.f1_0_01 > 0.97 and metrics.primitives == 1  # the samples set the floor
    assert set(metrics.to_dict()) == {"iou", "cd_l1", "cd_l2", "f1_0.05", "f1_0.01",
                                      "n_primitives"}
    thin = sweepedit.evaluate(cylinder_abstraction(radius=0.1), cylinder, n_samples=20_000)
    assert thin.iou == pytest.approx(0.25, abs=0.02)  # (0.1 / 0.2)^2 of the volume
    assert thin.cd_l1 > 10 * metrics.cd_l1 and thin.f1_0_01 < 0.5  # sides 0.1 apart


def test_inside_in_either_frame() -> None:
    abstraction = cylinder_abstraction()
    points = np.array([[0.0, 0.0, 0.0], [0.19, 0.0, 0.3], [0.21, 0.0, 0.0], [0.0, 0.0, 0.6]])
    expected = [True, True, False, False]
    assert sweepedit.inside(abstraction, points).tolist() == expected
    original = abstraction.normalization.to_original(points)
    assert sweepedit.inside(abstraction, original, original_frame=True).tolist() == expected
    with pytest.raises(ValueError, match="points"):
        sweepedit.inside(abstraction, np.zeros((3, 2)))


def test_meshes_in_memory_have_the_analytic_volume() -> None:
    abstraction = cylinder_abstraction()
    exact = math.pi * 0.2**2 * 1.0
    union = abstraction.to_trimesh()
    assert union.is_watertight
    assert union.volume == pytest.approx(exact, rel=0.01)
    scene = abstraction.to_trimesh(per_primitive=True, original_frame=True)
    (name, geometry), = scene.geometry.items()
    assert name == "post"
    assert geometry.volume == pytest.approx(exact * 4.0**3, rel=0.01)  # scale 4
    assert tuple(geometry.visual.face_colors[0, :3]) == (0x29, 0x33, 0x5C)
    poly = abstraction.to_pyvista()
    assert poly.volume == pytest.approx(exact, rel=0.01)
    blocks = abstraction.to_pyvista(per_primitive=True)
    assert blocks.keys() == ["post"]
    with pytest.raises(sweepedit.SweepeditError, match="no primitives"):
        sweepedit.Abstraction().to_trimesh()


def test_export_by_extension_and_round_trip(tmp_path: Path) -> None:
    abstraction = cylinder_abstraction()
    written = abstraction.export(tmp_path / "c.json")
    again = sweepedit.load(written[0])
    assert isinstance(again, sweepedit.Abstraction)
    np.testing.assert_array_equal(again.primitives[0].control_points,
                                  abstraction.primitives[0].control_points)
    np.testing.assert_array_equal(again.normalization.center, [1.0, -2.0, 3.0])
    (mesh_path,) = sweepedit.export(written[0], tmp_path / "c.stl", original_frame=True)
    assert trimesh.load(mesh_path).volume == pytest.approx(math.pi * 0.04 * 64, rel=0.01)
    with pytest.raises(sweepedit.SweepeditError, match=r"cannot write meshes as '\.xyz'"):
        abstraction.export(tmp_path / "c.xyz")
    with pytest.raises(sweepedit.SweepeditError, match="--union is for STEP"):
        abstraction.export(tmp_path / "c.glb", union=True)
    with pytest.raises(sweepedit.SweepeditError, match="stations"):
        abstraction.export(tmp_path / "c.json", stations=12)
    # A plain model abstraction is accepted wherever an Abstraction is.
    model = ModelAbstraction(abstraction.primitives, abstraction.normalization)
    assert sweepedit.inside(model, np.zeros((1, 3))).tolist() == [True]


def test_plot_renders_a_picture(tmp_path: Path) -> None:
    from PIL import Image

    out = cylinder_abstraction().plot(screenshot=tmp_path / "c.png", window_size=(200, 150))
    image = np.asarray(Image.open(out).convert("RGB"))
    assert image.shape == (150, 200, 3)
    # The primitive's colour #29335c is drawn (shaded): dark blue pixels exist.
    blue = (image[..., 2] > image[..., 0] + 30) & (image[..., 0] < 120)
    assert blue.sum() > 100


def test_fit_settings_are_checked() -> None:
    with pytest.raises(TypeError, match=r"unknown fit setting.*colour"):
        sweepedit.fit_settings(8, colour="red")
    with pytest.raises(sweepedit.SweepeditError, match="count or 'auto'"):
        sweepedit.fit_settings("many")
    auto = sweepedit.fit_settings("auto", max_primitives=5, tolerance=0.01)
    assert auto.auto and auto.primitives == 5 and auto.tolerance == 0.01
    assert sweepedit.fit_settings(3, restarts=2).restarts == 2


@pytest.mark.slow
def test_fit_from_code_gives_the_command_lines_parameters(tmp_path: Path, capsys) -> None:
    """One path: the same shape, settings and seed through `sweepedit fit` and
    `sweepedit.fit` give the same parameters, bit for bit."""
    out = tmp_path / "cli.json"
    assert main(["fit", str(CACTUS), "-o", str(out), "-k", "3", "--quiet"]) == 0
    seen: list[str] = []
    abstraction = sweepedit.fit(trimesh.load(CACTUS, process=False), 3,
                                progress=lambda p: seen.append(p.stage))
    assert "refinement" in seen and seen[0] == "warm start"
    cli = sweepedit.load(out)
    assert len(cli.primitives) == len(abstraction.primitives)
    for a, b in zip(cli.primitives, abstraction.primitives, strict=True):
        np.testing.assert_allclose(a.control_points, b.control_points, rtol=0, atol=1e-12)
        assert (a.a, a.b, a.degree) == pytest.approx((b.a, b.b, b.degree), abs=1e-12)
    record = abstraction.fit
    assert record["cancelled"] is False and record["seconds"] > 0
    metrics = json.loads(json.dumps(cli.fit["metrics"]))
    assert metrics["iou"] == pytest.approx(sweepedit.evaluate(abstraction, CACTUS).iou)
    assert capsys.readouterr().err == ""  # progress=callable draws no bar


@pytest.mark.slow
def test_ctrl_c_in_a_script_keeps_the_best_so_far(tmp_path: Path) -> None:
    """A real SIGINT to a Python process inside sweepedit.fit: the fit stops and returns
    its best abstraction, marked cancelled, and the script goes on."""
    script = tmp_path / "fit.py"
    script.write_text(
        "import sys, sweepedit\n"
        "def progress(p):\n"
        "    if p.stage == 'refinement':\n"
        "        print('refining', flush=True)\n"
        f"a = sweepedit.fit({str(CACTUS)!r}, 4, progress=progress, refine_iterations=20000)\n"
        "print('returned', a.fit['cancelled'], len(a.primitives), flush=True)\n")
    proc = subprocess.Popen([sys.executable, str(script)], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 120
    while proc.stdout.readline().strip() != "refining":
        assert proc.poll() is None and time.monotonic() < deadline, proc.stderr.read()
    time.sleep(0.5)
    proc.send_signal(signal.SIGINT)
    stdout, stderr = proc.communicate(timeout=120)
    assert proc.returncode == 0, stderr[-2000:]
    assert "Traceback" not in stderr
    assert "cancelling, keeping the best result so far" in stderr
    returned = [line for line in stdout.splitlines() if line.startswith("returned")]
    assert returned and returned[0].split()[1] == "True" and int(returned[0].split()[2]) >= 1
