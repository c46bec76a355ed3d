"""Blender export (sweepedit/io/blend_export.py and the add-on in
sweepedit/resources/blender/sweepedit_blender): curve objects that Blender evaluates to
the primitives' solids, an exact round trip, edits that come back, the approximation
report and the add-on's operators. Skipped only where no Blender runner is found."""

from __future__ import annotations

import json
import os
import stat
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from sweepedit.errors import SweepeditError
from sweepedit.geometry.inside import grid_points, inside_primitive
from sweepedit.geometry.model import Abstraction, Normalization, SweepPrimitive, folds_onto_itself
from sweepedit.geometry.volumes import closed_form_volume
from sweepedit.io import blend_export
from sweepedit.io.blend_export import blend_meshes, export_blend, find_blender, read_blend
from sweepedit.io.occupancy import winding_numbers
from sweepedit.io.params import abstraction_to_json, write_abstraction

ROOT = Path(__file__).resolve().parents[1]


def _runner() -> blend_export.BlenderRunner | None:
    try:
        return find_blender()
    except SweepeditError:
        return None


RUNNER = _runner()
needs_blender = pytest.mark.skipif(RUNNER is None, reason="no Blender runner: "
                                   + blend_export.HOW_TO_GET)


def _primitives() -> list[SweepPrimitive]:
    return [
        SweepPrimitive(np.array([[-0.3, 0.0, 0.0], [0.0, 0.01, 0.0], [0.3, 0.0, 0.02]]),
                       a=0.1, b=0.05, degree=2.0, name="straight", color="#e4572e"),
        SweepPrimitive(np.array([[-0.35, -0.15, 0.0], [-0.15, 0.15, 0.05], [0.05, -0.05, 0.15],
                                 [0.2, 0.15, 0.0], [0.35, 0.0, 0.1]]),
                       a=0.05, b=0.03, degree=1.6, scaling=(0.3, -0.4), name="bent",
                       color="#29335c"),
        SweepPrimitive(np.array([[0.0, -0.3, -0.2], [0.05, 0.0, 0.1], [0.0, 0.3, 0.2]]),
                       a=0.15, b=0.1, degree=0.6, name="star", color="#17bebb"),
        SweepPrimitive(np.array([[0.0, 0.0, -0.4], [0.02, 0.01, 0.0], [0.0, 0.0, 0.4]]),
                       a=0.12, b=0.06, degree=4.0, scaling=(-0.3, 0.2), name="boxy",
                       color="#a8c686", locked=True),
        SweepPrimitive(np.array([[-0.2, -0.2, 0.0], [0.3, 0.0, 0.0], [-0.2, 0.2, 0.0]]),
                       a=0.15, b=0.08, degree=2.0, name="folded", color="#6a4c93",
                       visible=False),
    ]


def _abstraction() -> Abstraction:
    return Abstraction(_primitives(), normalization=Normalization([1.0, -2.0, 0.5], 3.0),
                       source={"path": "shape.ply"}, fit={"seconds": 1.5},
                       extras={"note": "kept"})


def _blender_script(code: str, tmp_path: Path, *args: str,
                    env: dict[str, str] | None = None) -> subprocess.CompletedProcess:
    """Run a bpy script with the runner that export_blend uses."""
    script = tmp_path / "script.py"
    script.write_text(textwrap.dedent(code), encoding="utf-8")
    assert RUNNER is not None
    if RUNNER.kind == "python":
        cmd = [RUNNER.executable, str(script), *args]
    else:
        cmd = [RUNNER.executable, "-b", "--factory-startup", "--python-exit-code", "1",
               "--python", str(script), "--", *args]
    full_env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    full_env.update(env or {})
    proc = subprocess.run(cmd, capture_output=True, text=True, env=full_env, timeout=300)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return proc


ARGS = ("import sys\n"
        "argv = sys.argv[sys.argv.index('--') + 1:] if '--' in sys.argv else sys.argv[1:]\n")


@pytest.fixture(scope="module")
def exported(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, blend_export.BlendReport]:
    if RUNNER is None:
        pytest.skip("no Blender runner")
    path = tmp_path_factory.mktemp("blend") / "shapes.blend"
    target = (np.array([[0, 0, 0], [0.1, 0, 0], [0, 0.1, 0], [0, 0, 0.1]], dtype=float),
              np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]]))
    report = export_blend(_abstraction(), path, target_mesh=target)
    return path, report


@pytest.fixture(scope="module")
def meshes(exported: tuple[Path, blend_export.BlendReport]) -> dict[str, tuple]:
    return {name: (v, f) for name, v, f in blend_meshes(exported[0])}


# --------------------------------------------------------------------------- no Blender


def test_without_a_runner_the_error_says_how_to_get_one(tmp_path: Path,
                                                        monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(blend_export, "_bpy_here", lambda: None)
    monkeypatch.setattr(blend_export, "_setup_python", lambda: None)
    monkeypatch.setattr(blend_export, "_blender_on_path", lambda: None)
    monkeypatch.setenv("SWEEPEDIT_BLENDER", str(tmp_path / "no-such-blender"))
    with pytest.raises(SweepeditError) as err:
        export_blend(_abstraction(), tmp_path / "x.blend")
    message = str(err.value)
    assert "\n" not in message
    assert "no-such-blender" in message and "scripts/setup.sh" in message
    monkeypatch.delenv("SWEEPEDIT_BLENDER")
    with pytest.raises(SweepeditError, match=r"setup\.sh.*blender.*PATH.*SWEEPEDIT_BLENDER"):
        find_blender()
    assert not (tmp_path / "x.blend").exists()


def test_a_missing_folder_is_named_before_blender_runs(tmp_path: Path) -> None:
    with pytest.raises(SweepeditError, match="does not exist"):
        export_blend(_abstraction(), tmp_path / "nowhere" / "x.blend")


# --------------------------------------------------------------------------- with Blender


@needs_blender
def test_objects_names_colours_and_properties(exported, tmp_path: Path) -> None:
    path, _ = exported
    proc = _blender_script(ARGS + """
        import bpy, json
        bpy.ops.wm.open_mainfile(filepath=argv[0])
        out = {}
        for ob in bpy.data.objects:
            if ob.type != "CURVE" or "sweepedit_primitive" not in ob:
                continue
            cu = ob.data
            sp = cu.splines[0]
            out[ob.name] = {
                "collection": [c.name for c in ob.users_collection],
                "colour": list(ob.active_material.diffuse_color),
                "props": {k: (list(v) if hasattr(v, "__len__") and not isinstance(v, str)
                              else v) for k, v in ob.items()},
                "spline": [sp.type, sp.order_u, sp.use_endpoint_u, len(sp.points)],
                "bevel": [cu.bevel_mode, cu.bevel_object.name, cu.use_fill_caps],
                "taper": [cu.taper_object.name, cu.taper_radius_mode],
                "twist": cu.twist_mode, "hidden": ob.hide_viewport}
        out["_targets"] = [ob.name for ob in bpy.data.objects if ob.get("sweepedit_target")]
        print("RESULT" + json.dumps(out))
    """.replace("\n        ", "\n"), tmp_path, str(path))
    found = json.loads(next(ln[6:] for ln in proc.stdout.splitlines() if ln.startswith("RESULT")))
    names = [p.name for p in _primitives()]
    assert sorted(k for k in found if not k.startswith("_")) == sorted(names)
    assert found["_targets"] == ["shapes target"]
    for i, prim in enumerate(_primitives()):
        ob = found[prim.name]
        assert "shapes" in ob["collection"]
        rgb = [int(prim.color[j:j + 2], 16) / 255 for j in (1, 3, 5)]
        linear = [c / 12.92 if c <= 0.04045 else ((c + 0.055) / 1.055) ** 2.4 for c in rgb]
        assert np.allclose(ob["colour"][:3], linear, atol=1e-6)
        props = ob["props"]
        assert props["sweepedit_primitive"] == i
        assert props["sweepedit_control_points"] == prim.control_points.ravel().tolist()
        assert (props["sweepedit_a"], props["sweepedit_b"], props["sweepedit_degree"]) == (
            prim.a, prim.b, prim.degree)
        assert json.loads(props["sweepedit_scaling"]) == list(prim.scaling)
        assert ob["spline"] == ["NURBS", 3, True, prim.n_control_points]
        assert ob["bevel"] == ["OBJECT", f"{prim.name} bevel", True]
        assert ob["taper"] == [f"{prim.name} taper", "OVERRIDE"]
        assert ob["twist"] == "MINIMUM"
        assert ob["hidden"] == (not prim.visible)


@needs_blender
def test_blender_meshes_match_the_exact_solids(meshes) -> None:
    grid = grid_points(64)
    for prim in _primitives():
        if folds_onto_itself(prim):
            continue
        vertices, faces = meshes[prim.name]
        ours = np.abs(winding_numbers(vertices, faces, grid)) > 0.5
        exact = inside_primitive(grid, prim)
        iou = (ours & exact).sum() / (ours | exact).sum()
        assert iou >= 0.98, (prim.name, iou)
        tri = vertices[faces]
        volume = np.einsum("ij,ij->", tri[:, 0], np.cross(tri[:, 1], tri[:, 2])) / 6.0
        assert volume > 0, prim.name  # faces point outwards
        assert abs(volume / closed_form_volume(prim) - 1.0) < 0.01, prim.name


@needs_blender
def test_round_trip_is_exact(exported, tmp_path: Path) -> None:
    path, _ = exported
    back = read_blend(path)
    assert abstraction_to_json(back) == abstraction_to_json(_abstraction())
    framed = tmp_path / "framed.blend"
    export_blend(_abstraction(), framed, original_frame=True)
    assert abstraction_to_json(read_blend(framed)) == abstraction_to_json(_abstraction())


@needs_blender
def test_edits_in_blender_come_back(exported, tmp_path: Path) -> None:
    path, _ = exported
    edited = tmp_path / "edited.blend"
    _blender_script(ARGS + """
        import bpy
        bpy.ops.wm.open_mainfile(filepath=argv[0])
        bent = bpy.data.objects["bent"]
        p = bent.data.splines[0].points[2]
        p.co = (p.co[0] + 0.05, p.co[1], p.co[2], p.co[3])
        bpy.data.objects["straight"].location.x += 0.1
        for p in bpy.data.objects["boxy bevel"].data.splines[0].points:
            p.co = (p.co[0] * 1.5, p.co[1], p.co[2], p.co[3])
        bpy.data.objects["star"].name = "renamed"
        bpy.ops.wm.save_as_mainfile(filepath=argv[1])
    """.replace("\n        ", "\n"), tmp_path, str(path), str(edited))
    back = {p.name: p for p in read_blend(edited).primitives}
    prims = {p.name: p for p in _primitives()}
    moved = prims["bent"].control_points.copy()
    moved[2, 0] += 0.05
    assert np.allclose(back["bent"].control_points, moved, atol=1e-6)
    assert np.allclose(back["straight"].control_points,
                       prims["straight"].control_points + np.array([0.1, 0, 0]), atol=1e-6)
    assert back["boxy"].a == pytest.approx(1.5 * prims["boxy"].a, rel=1e-6)
    assert back["boxy"].b == pytest.approx(prims["boxy"].b, rel=1e-6)
    assert back["boxy"].degree == prims["boxy"].degree
    assert np.array_equal(back["renamed"].control_points, prims["star"].control_points)


@needs_blender
def test_the_report_names_approximated_and_folding_primitives(exported) -> None:
    _, report = exported
    notes = {p.name: p for p in report.primitives}
    assert not notes["straight"].approximated and notes["straight"].profile == "ellipse"
    for name in ("bent", "star", "boxy"):
        assert notes[name].approximated and 0 < notes[name].profile_error < 5e-3
    assert [p.name for p in report.folding] == ["folded"]
    lines = report.lines()
    assert any(ln.startswith("star: profile drawn as a polygon") for ln in lines)
    assert any(ln.startswith("folded:") and "inside-out" in ln for ln in lines)


FAKE_SWEEPEDIT = """\
#!{python}
import json, sys
args = sys.argv[1:]
assert args[0] == "fit" and args[1].endswith(".ply") and "--progress-json" in args, args
with open(args[1], "rb") as f:
    assert f.read(3) == b"ply"
out = args[args.index("-o") + 1]
for i in range(3):
    print(json.dumps({{"event": "progress", "fraction": i / 3, "stage": "refine",
                      "seconds_left": None, "primitives": 1}}), flush=True)
with open(out, "w") as f:
    f.write({doc!r})
print(json.dumps({{"event": "done", "output": out, "primitives": 1, "metrics": {{}}}}))
"""


@needs_blender
def test_the_addon_installs_and_its_operators_run(tmp_path: Path) -> None:
    zip_path = subprocess.run(
        [sys.executable, str(ROOT / "scripts" / "build_blender_addon.py"), "--out",
         str(tmp_path / "dist")], capture_output=True, text=True, check=True).stdout.strip()
    params = tmp_path / "params.json"
    abstraction = Abstraction(_primitives()[:2],
                              normalization=Normalization([1.0, 2.0, 3.0], 2.0))
    write_abstraction(abstraction, params)
    fake = tmp_path / "fake-sweepedit"
    fake_doc = json.dumps(abstraction_to_json(Abstraction(
        _primitives()[:1], normalization=Normalization([0.0, 0.0, 0.5], 2.0))))
    fake.write_text(FAKE_SWEEPEDIT.format(python=sys.executable, doc=fake_doc),
                    encoding="utf-8")
    fake.chmod(fake.stat().st_mode | stat.S_IXUSR)
    proc = _blender_script(ARGS + """
        import bpy, json
        zip_path, params, exported, fake = argv
        bpy.ops.wm.read_factory_settings(use_empty=True)
        bpy.ops.extensions.package_install_files(filepath=zip_path, repo="user_default",
                                                 enable_on_install=True)
        result = {"ops": [op.get_rna_type().identifier for op in (
            bpy.ops.import_scene.sweepedit_json, bpy.ops.export_scene.sweepedit_json,
            bpy.ops.object.sweepedit_abstract)],
                  "addons": list(bpy.context.preferences.addons.keys())}
        bpy.ops.import_scene.sweepedit_json(filepath=params)
        result["imported"] = sorted(o.name for o in bpy.data.objects
                                    if "sweepedit_primitive" in o)
        bpy.ops.object.select_all(action="DESELECT")
        bpy.data.objects["bent"].select_set(True)
        bpy.ops.export_scene.sweepedit_json(filepath=exported)
        bpy.ops.mesh.primitive_cube_add(size=2.0, location=(5.0, 0.0, 0.0))
        cube = bpy.context.active_object
        bpy.ops.object.sweepedit_abstract(executable=fake)
        ob = bpy.data.objects["straight.001"]
        p = ob.matrix_world @ ob.data.splines[0].points[0].co.xyz
        result["fitted"] = [c.name for c in bpy.data.collections]
        result["fitted_point"] = list(p)
        print("RESULT" + json.dumps(result))
    """.replace("\n        ", "\n"), tmp_path, zip_path, str(params),
        str(tmp_path / "exported.json"), str(fake),
        env={"BLENDER_USER_RESOURCES": str(tmp_path / "blender-user")})
    found = json.loads(next(ln[6:] for ln in proc.stdout.splitlines() if ln.startswith("RESULT")))
    assert found["ops"] == ["IMPORT_SCENE_OT_sweepedit_json", "EXPORT_SCENE_OT_sweepedit_json",
                            "OBJECT_OT_sweepedit_abstract"]
    assert "bl_ext.user_default.sweepedit" in found["addons"]
    assert found["imported"] == ["bent", "straight"]
    exported_doc = json.loads((tmp_path / "exported.json").read_text(encoding="utf-8"))
    assert [p["name"] for p in exported_doc["primitives"]] == ["bent"]
    assert exported_doc["primitives"][0]["control_points"] == (
        _primitives()[1].control_points.tolist())
    assert exported_doc["normalization"] == {"center": [1.0, 2.0, 3.0], "scale": 2.0}
    assert "Cube sweeps" in found["fitted"]
    # the fake fit's normalisation (centre (0, 0, 0.5), scale 2) on the cube at x = 5
    expected = np.array([-0.3, 0.0, 0.0]) * 2.0 + [0.0, 0.0, 0.5] + [5.0, 0.0, 0.0]
    assert np.allclose(found["fitted_point"], expected, atol=1e-5)


@needs_blender
def test_blenders_axis_is_sweepedits_axis(exported, tmp_path: Path) -> None:
    """Blender's endpoint NURBS of order 3 evaluates to the clamped quadratic B-spline,
    at evenly spaced t (resolution_u points per knot span)."""
    from sweepedit.geometry.sweep import axis_points

    path, _ = exported
    proc = _blender_script(ARGS + """
        import bpy, json
        bpy.ops.wm.open_mainfile(filepath=argv[0])
        out = {}
        for name in ("straight", "bent"):
            ob = bpy.data.objects[name]
            ob.data.bevel_mode = "ROUND"
            ob.data.bevel_depth = 0.0
            ob.data.taper_object = None
            me = ob.evaluated_get(bpy.context.evaluated_depsgraph_get()).to_mesh()
            out[name] = [list(v.co) for v in me.vertices]
        print("RESULT" + json.dumps(out))
    """.replace("\n        ", "\n"), tmp_path, str(path))
    found = json.loads(next(ln[6:] for ln in proc.stdout.splitlines() if ln.startswith("RESULT")))
    for prim in _primitives()[:2]:
        points = np.array(found[prim.name])
        t = np.linspace(0.0, 1.0, len(points))
        assert len(points) >= 64
        assert np.allclose(points, axis_points(prim.control_points[None], t)[0], atol=1e-6)


@needs_blender
def test_the_command_line_exports_and_reads_back_blend(tmp_path: Path, capsys) -> None:
    """`sweepedit export PARAMS -o X.blend --target SHAPE` and `sweepedit convert X.blend
    Y.json`: the parameters come back exactly, through the same API as code uses."""
    import sweepedit
    from sweepedit.cli import main

    params = tmp_path / "in.json"
    write_abstraction(_abstraction(), params)
    blend = tmp_path / "out.blend"
    cactus = ROOT / "resources" / "examples" / "cactus.off"
    assert main(["export", str(params), "-o", str(blend), "--target", str(cactus)]) == 0
    err = capsys.readouterr().err
    assert "star: profile drawn as a polygon" in err and "folded: " in err  # never silently
    back = tmp_path / "back.json"
    assert main(["convert", str(blend), str(back)]) == 0
    assert abstraction_to_json(sweepedit.load(back)) == abstraction_to_json(_abstraction())
    with pytest.raises(SweepeditError, match="--per-primitive"):
        sweepedit.export(params, tmp_path / "x.blend", per_primitive=True)
