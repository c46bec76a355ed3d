"""The `sweepedit` command: subcommands end to end, and bad input as clear errors."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import trimesh

from sweepedit.cli import main
from sweepedit.geometry.inside import inside_union
from sweepedit.geometry.model import Abstraction, Normalization, SweepPrimitive
from sweepedit.io.params import read_abstraction, write_abstraction


@pytest.fixture
def params_file(tmp_path: Path) -> Path:
    prims = [
        SweepPrimitive([[-0.3, 0, 0], [0, 0.2, 0], [0.3, 0, 0]], a=0.08, b=0.05, degree=2.0,
                       scaling=(0.1, -0.2), name="arch", color="#e4572e"),
        SweepPrimitive([[0, -0.3, -0.2], [0, -0.3, 0], [0, -0.3, 0.2]], a=0.05, b=0.05,
                       degree=4.0, scaling=(0.0, 0.0), name="post", color="#29335c"),
    ]
    path = tmp_path / "two.json"
    write_abstraction(Abstraction(prims, Normalization([1.0, 2.0, 3.0], 10.0)), path)
    return path


def run(*args: str) -> int:
    return main([str(a) for a in args])


def test_export_union_is_watertight_and_per_primitive_writes_each(params_file: Path,
                                                                  tmp_path: Path) -> None:
    out = tmp_path / "union.stl"
    assert run("export", params_file, "-o", out) == 0
    mesh = trimesh.load(out)
    assert mesh.is_watertight and mesh.volume > 0
    assert run("export", params_file, "-o", tmp_path / "part.ply", "--per-primitive") == 0
    assert sorted(p.name for p in tmp_path.glob("part_*.ply")) == ["part_00.ply", "part_01.ply"]
    assert run("export", params_file, "-o", tmp_path / "orig.obj", "--original-frame") == 0
    orig = trimesh.load(tmp_path / "orig.obj")
    # original = normalised * 10 + (1, 2, 3): the union's centre moves accordingly
    np.testing.assert_allclose(orig.bounds, mesh.bounds * 10 + [1, 2, 3], atol=1e-3)


def test_convert_round_trip(params_file: Path, tmp_path: Path) -> None:
    txt, back = tmp_path / "p.txt", tmp_path / "back.json"
    assert run("convert", params_file, txt) == 0
    assert run("convert", txt, back) == 0
    a, b = read_abstraction(params_file), read_abstraction(back)
    for p, q in zip(a.primitives, b.primitives, strict=True):
        np.testing.assert_array_equal(p.control_points, q.control_points)
        assert (p.a, p.b, p.degree, p.scaling) == (q.a, q.b, q.degree, q.scaling)


def test_inside_matches_the_exact_test(params_file: Path, tmp_path: Path) -> None:
    pts = np.random.default_rng(0).uniform(-0.5, 0.5, (2000, 3))
    np.save(tmp_path / "pts.npy", pts)
    assert run("inside", params_file, tmp_path / "pts.npy", "-o", tmp_path / "occ.npy") == 0
    occ = np.load(tmp_path / "occ.npy")
    expected = inside_union(pts, read_abstraction(params_file).primitives)
    np.testing.assert_array_equal(occ, expected)


@pytest.mark.parametrize(
    ("content", "needle"),
    [
        ('{"format": "sweepedit.abstraction", "version": 1, "primit', "malformed JSON"),
        ('{"format": "sweepedit.abstraction", "version": 7, "primitives": []}', "version"),
    ],
)
def test_bad_parameter_files_give_one_line_errors(tmp_path: Path, capsys, content: str,
                                                  needle: str) -> None:
    bad = tmp_path / "bad.json"
    bad.write_text(content)
    assert run("export", bad, "-o", tmp_path / "x.obj") == 2
    err = capsys.readouterr().err
    assert "bad.json" in err and needle in err and "Traceback" not in err
    assert not (tmp_path / "x.obj").exists()


def test_bad_points_and_unknown_mesh_format(params_file: Path, tmp_path: Path, capsys) -> None:
    np.save(tmp_path / "flat.npy", np.zeros((4, 2)))
    assert run("inside", params_file, tmp_path / "flat.npy", "-o", tmp_path / "o.npy") == 2
    assert "(N, 3)" in capsys.readouterr().err
    assert run("export", params_file, "-o", tmp_path / "mesh.xyz") == 2
    assert "cannot write meshes" in capsys.readouterr().err


def test_eval_prints_json_last(tmp_path: Path, shared_dir: Path, capsys) -> None:
    # The official result for "eight" under the quality protocol (docs/quality.md): IoU 0.64,
    # CD-L1 0.0178, F1@0.05 0.97.
    code = run("eval", shared_dir / "sweepnet_params" / "eight.txt",
               shared_dir / "shapes" / "eight.stl", "--json")
    assert code == 0
    metrics = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert metrics["n_primitives"] == 5
    assert metrics["iou"] == pytest.approx(0.64, abs=0.01)
    assert metrics["cd_l1"] == pytest.approx(0.0178, abs=0.0005)
    assert metrics["f1_0.05"] == pytest.approx(0.97, abs=0.01)


def test_help_for_every_subcommand() -> None:
    for sub in ("export", "convert", "inside", "eval", "inspect", "fit", "bench",
                "train-sweeper", "gui"):
        proc = subprocess.run([sys.executable, "-m", "sweepedit.cli", sub, "--help"],
                              capture_output=True, text=True, timeout=60)
        assert proc.returncode == 0 and "usage" in proc.stdout, sub


def test_missing_file_is_a_clear_error(capsys) -> None:
    assert run("export", "/nonexistent/p.json", "-o", "/tmp/x.obj") == 2
    assert "/nonexistent/p.json" in capsys.readouterr().err


@pytest.mark.parametrize("sweeper", ["analytic", "neural"])
def test_inside_with_soft_sweepers_agrees_with_exact(params_file: Path, tmp_path: Path,
                                                     sweeper: str) -> None:
    pts = np.random.default_rng(1).uniform(-0.5, 0.5, (4000, 3))
    np.save(tmp_path / "pts.npy", pts)
    out = tmp_path / f"{sweeper}.npy"
    assert run("inside", params_file, tmp_path / "pts.npy", "-o", out, "--sweeper",
               sweeper) == 0
    soft = np.load(out)
    assert soft.dtype == np.float32 and soft.min() >= 0.0 and soft.max() <= 1.0
    exact = inside_union(pts, read_abstraction(params_file).primitives)
    hard = soft > 0.5
    assert (hard & exact).sum() / (hard | exact).sum() >= 0.9


@pytest.mark.parametrize(
    "args",
    [
        ["export", "{params}", "-o", "{tmp}/m.stl", "--profile-points", "30"],
        ["export", "{params}", "-o", "{tmp}/m.stl", "--stations", "1"],
        ["export", "{params}", "-o", "{tmp}/m.stl", "--stations", "many"],
        ["eval", "{params}", "{tmp}/shape.stl", "--samples", "0"],
        ["fit", "{tmp}/shape.stl", "-o", "{tmp}/o.json", "--primitives", "0"],
        ["fit", "{tmp}/shape.stl", "-o", "{tmp}/o.json", "--primitives", "many"],
        ["fit", "{tmp}/shape.stl", "-o", "{tmp}/o.json", "-k", "auto", "--max-primitives", "0"],
    ],
)
def test_bad_option_values_are_usage_errors(params_file: Path, tmp_path: Path, capsys,
                                            args: list[str]) -> None:
    argv = [a.format(params=params_file, tmp=tmp_path) for a in args]
    with pytest.raises(SystemExit) as exit_info:
        main(argv)
    assert exit_info.value.code == 2
    err = capsys.readouterr().err
    assert "error: argument --" in err and "Traceback" not in err
    assert list(tmp_path.iterdir()) == [params_file]


def test_bad_fit_settings_fail_before_any_work(tmp_path: Path, capsys) -> None:
    # Settings are checked first: the shape (here not even there) is not read and no
    # progress bar is drawn.
    shape = tmp_path / "shape.obj"
    assert run("fit", shape, "-o", tmp_path / "p.json", "--surface-weight", "-1") == 2
    err = capsys.readouterr().err
    assert "surface weight must be >= 0" in err and "fitting" not in err
    assert list(tmp_path.iterdir()) == []


def test_fit_refuses_outputs_it_cannot_write_before_fitting(tmp_path: Path, capsys,
                                                           monkeypatch) -> None:
    # A missing folder for the parameters or the mesh, or a mesh format that does not
    # exist, must fail before the shape is read and the fit runs, not after a minute's fit.
    from sweepedit.fitting import fit

    def no_fit(*args, **kwargs):
        raise AssertionError("the fit ran")

    monkeypatch.setattr(fit, "fit_abstraction", no_fit)
    shape = tmp_path / "not_read.obj"  # not there: reading it would be another error
    missing = tmp_path / "missing"
    for extra, needle in (((), f"{missing / 'p.json'}: the folder {missing} does not exist"),
                          (("--mesh", missing / "m.glb"),
                           f"{missing / 'm.glb'}: the folder {missing} does not exist"),
                          (("--mesh", tmp_path / "m.foo"), "cannot write meshes as '.foo'")):
        out = missing / "p.json" if not extra else tmp_path / "p.json"
        assert run("fit", shape, "-o", out, *extra) == 2
        err = capsys.readouterr().err
        assert err.startswith("sweepedit: error: ") and needle in err, err
        assert len(err.strip().splitlines()) == 1
    assert list(tmp_path.iterdir()) == []


def test_unwritable_output_names_the_output_not_a_temporary_file(params_file: Path,
                                                                  tmp_path: Path,
                                                                  capsys) -> None:
    target = tmp_path / "no_such_folder" / "m.stl"
    assert run("export", params_file, "-o", target) == 2
    err = capsys.readouterr().err
    assert err.strip() == (f"sweepedit: error: {target}: the folder {target.parent} "
                           "does not exist")
    # the parameter writer, whose atomic write fails in the folder: the same words
    assert run("convert", params_file, tmp_path / "no_such_folder" / "p.txt") == 2
    assert f"the folder {target.parent} does not exist" in capsys.readouterr().err
    (tmp_path / "taken.obj").mkdir()  # a folder where the file should go
    assert run("export", params_file, "-o", tmp_path / "taken.obj") == 2
    err = capsys.readouterr().err
    assert "taken.obj" in err and ".tmp" not in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["taken.obj", "two.json"]
    assert list((tmp_path / "taken.obj").iterdir()) == []


def test_points_that_are_not_numbers(params_file: Path, tmp_path: Path, capsys) -> None:
    np.save(tmp_path / "words.npy", np.array([["a", "b", "c"]]))
    np.savez(tmp_path / "pts.npz", points=np.zeros((2, 3)))
    (tmp_path / "mesh.off").write_text("OFF\n0 0 0\n")
    for name, needle in (("words.npy", "expected numbers"), ("pts.npz", "archive"),
                         ("mesh.off", "not a .npy array"), ("absent.npy", "no such file")):
        assert run("inside", params_file, tmp_path / name, "-o", tmp_path / "o.npy") == 2
        err = capsys.readouterr().err
        assert name in err and needle in err and "Traceback" not in err
    assert not (tmp_path / "o.npy").exists()


def test_inspect_reports_what_was_loaded(tmp_path: Path, capsys) -> None:
    # A torus of tube radius 1 about a circle of radius 3: normalised by its longest side 8.
    torus = trimesh.creation.torus(major_radius=3.0, minor_radius=1.0)
    torus.export(tmp_path / "torus.ply")
    png = tmp_path / "torus.png"
    assert run("inspect", tmp_path / "torus.ply", "--screenshot", png) == 0
    out = capsys.readouterr().out
    assert f"{len(torus.vertices)} vertices, {len(torus.faces)} faces" in out
    assert "watertight True, components 1" in out
    fraction = 2 * np.pi**2 * (3 / 8) * (1 / 8) ** 2  # tube volume / cube volume
    shown = float(out.split("occupancy")[1].split(",")[1].split("%")[0]) / 100
    assert shown == pytest.approx(fraction, rel=0.05)
    assert "skeleton     1 branches, 0 junctions" in out
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"

    d = np.random.default_rng(0).normal(size=(3000, 3))
    np.savetxt(tmp_path / "ball.xyz", d / np.linalg.norm(d, axis=1, keepdims=True))
    assert run("inspect", tmp_path / "ball.xyz") == 0
    out = capsys.readouterr().out
    assert "(points)" in out and "points       3000 input points" in out
    assert "grid surface" in out and "skeleton     1 branches" in out


def test_eval_json_is_strict_json_without_primitives(tmp_path: Path, capsys) -> None:
    empty = tmp_path / "none.json"
    empty.write_text('{"format": "sweepedit.abstraction", "version": 1, "primitives": []}')
    box = tmp_path / "box.stl"
    trimesh.creation.box(extents=(1.0, 0.5, 0.5)).export(box)
    assert run("eval", empty, box, "--json", "--samples", "2000") == 0
    last = capsys.readouterr().out.strip().splitlines()[-1]

    def refuse(token: str) -> None:
        raise ValueError(token)

    metrics = json.loads(last, parse_constant=refuse)  # no NaN / Infinity tokens
    assert metrics == {"iou": 0.0, "cd_l1": None, "cd_l2": None, "f1_0.05": 0.0,
                       "f1_0.01": 0.0, "n_primitives": 0}


def test_fit_options_default_to_fit_settings() -> None:
    # The CLI states its defaults without importing torch; they must be FitSettings'.
    from sweepedit.cli import _fit_settings, build_parser
    from sweepedit.fitting.fit import FitSettings

    args = build_parser().parse_args(["fit", "shape.obj", "-o", "out.json"])
    assert _fit_settings(args) == FitSettings()
    args = build_parser().parse_args(["fit", "shape.obj", "-o", "out.json",
                                      "--surface-weight", "0", "--min-gain", "0.01"])
    assert (_fit_settings(args).surface_weight, _fit_settings(args).min_gain) == (0.0, 0.01)
    # --primitives auto: the cap is --max-primitives, its default fit.py's.
    from sweepedit.fitting.fit import AUTO_MAX_PRIMITIVES

    auto = _fit_settings(build_parser().parse_args(["fit", "s.obj", "-o", "o.json",
                                                    "--primitives", "auto"]))
    assert auto == FitSettings(primitives=AUTO_MAX_PRIMITIVES, auto=True)
    assert auto.rounds > FitSettings().rounds
    capped = _fit_settings(build_parser().parse_args(
        ["fit", "s.obj", "-o", "o.json", "-k", "AUTO", "--max-primitives", "12",
         "--tolerance", "0.02"]))
    assert (capped.primitives, capped.auto, capped.tolerance) == (12, True, 0.02)


def test_per_primitive_export_that_fails_leaves_no_files(params_file: Path, tmp_path: Path,
                                                         monkeypatch, capsys) -> None:
    import sweepedit.io.mesh_export as mesh_export
    from sweepedit.errors import SweepeditError

    real = mesh_export.solid_mesh

    def fails_on_the_second(prim: SweepPrimitive, *args, **kwargs):
        if prim.name == "post":
            raise SweepeditError("post: cannot mesh")
        return real(prim, *args, **kwargs)

    monkeypatch.setattr(mesh_export, "solid_mesh", fails_on_the_second)
    assert run("export", params_file, "-o", tmp_path / "part.ply", "--per-primitive") != 0
    assert "post: cannot mesh" in capsys.readouterr().err
    assert list(tmp_path.glob("part*")) == []


def test_a_closed_output_pipe_ends_quietly() -> None:
    # `sweepedit inspect SHAPE | head -0`: the reader is gone before the first write.
    shape = Path(__file__).resolve().parents[1] / "resources" / "examples" / "cactus.off"
    read_end, write_end = os.pipe()
    os.close(read_end)
    try:
        proc = subprocess.run([sys.executable, "-m", "sweepedit.cli", "inspect", str(shape)],
                              stdout=write_end, stderr=subprocess.PIPE, text=True, timeout=60)
    finally:
        os.close(write_end)
    assert proc.returncode == 141
    assert proc.stderr == ""


def test_fit_time_limit_returns_in_time_with_a_valid_file(tmp_path: Path, capsys) -> None:
    import time

    from sweepedit.cli import _fit_settings, build_parser

    cactus = Path(__file__).resolve().parents[1] / "resources" / "examples" / "cactus.off"
    out = tmp_path / "cactus.json"
    start = time.perf_counter()
    assert run("fit", cactus, "-o", out, "--time-limit", "3", "--quiet") == 0
    elapsed = time.perf_counter() - start
    abstraction = read_abstraction(out)
    # The limit cut the fit short (a full one runs several times as long), and the command
    # returned soon after it: loading, the best result's scoring and the write add about a
    # second idle; the bound leaves room for a loaded 2-core runner.
    assert abstraction.fit["timed_out"] is True
    assert elapsed <= 3 + 2.0, elapsed  # idle: 3.0-3.1 s
    assert len(abstraction) >= 1
    for p in abstraction.primitives:
        p.validate()
    assert abstraction.fit["time_limit"] is not None
    args = build_parser().parse_args(["fit", "s.obj", "-o", "o.json", "--method", "network",
                                      "--device", "cpu", "--time-limit", "2.5"])
    settings = _fit_settings(args)
    assert (settings.method, settings.device, settings.time_limit) == ("network", "cpu", 2.5)


def test_fit_progress_text_names_the_stage_and_the_time_left() -> None:
    from types import SimpleNamespace

    from sweepedit.api import fit_progress_text

    p = SimpleNamespace(stage="residual round 1 of 2", stage_fraction=0.4, seconds_left=3.2,
                        restart=0, abstraction=Abstraction([]))
    desc, postfix = fit_progress_text(p)
    assert desc == "residual round 1 of 2"
    assert "40% of stage" in postfix and "~3 s left" in postfix


@pytest.mark.slow
def test_ctrl_c_during_a_fit_keeps_the_best_so_far(tmp_path: Path) -> None:
    """A real SIGINT to a real `sweepedit fit` in the middle of refinement: one notice,
    the best abstraction so far written and reported, exit 0, no traceback, no abort."""
    import signal
    import time

    out = tmp_path / "cactus.json"
    example = Path(__file__).resolve().parents[1] / "resources" / "examples" / "cactus.off"
    # Far more steps than run before the signal, so the fit is surely under way.
    proc = subprocess.Popen([sys.executable, "-m", "sweepedit.cli", "fit", str(example), "-o",
                             str(out), "--refine-iterations", "20000", "--time-limit", "300"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 120
    line = ""
    while "refinement" not in line and time.monotonic() < deadline:
        line = proc.stderr.read(64)  # the progress bar names its stage
        assert line or proc.poll() is None, "the fit ended before it was interrupted"
    time.sleep(1.0)
    proc.send_signal(signal.SIGINT)
    stdout, stderr = proc.communicate(timeout=120)
    assert proc.returncode == 0, stderr[-2000:]
    assert "Traceback" not in stderr and "terminate called" not in stderr
    assert stderr.count("cancelling, keeping the best result so far") == 1
    assert "cancelled, best so far" in stdout
    assert read_abstraction(out).primitives
