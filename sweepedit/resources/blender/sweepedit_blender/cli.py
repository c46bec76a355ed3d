"""Headless entry: ``python -m sweepedit_blender COMMAND ...`` in a Python that has bpy,
or ``blender -b --python-expr ... -- COMMAND ...``.

    build IN.json OUT.blend [--target MESH.npz] [--resolution-scale S] [--original-frame]
                            [--collection NAME]
    read IN.blend OUT.json
    mesh IN.blend OUT.npz          (each primitive's evaluated surface, normalised frame)
    render IN.blend OUT.png [--size N]

IN.json is a sweepedit parameter file; it may carry a "sweepedit_blender" object with
what only sweepedit can compute ("folds": one flag per primitive) and defaults for the
options above. Each command prints one line "SWEEPEDIT_REPORT {json}" on stdout (for
build: each primitive's profile, whether it is approximated and by how much, whether it
folds); errors go to stderr as one line and the exit status is 1.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys

REPORT_MARKER = "SWEEPEDIT_REPORT "


def _reset() -> None:
    import bpy
    bpy.ops.wm.read_factory_settings(use_empty=True)


def _save(path: str) -> None:
    import bpy
    bpy.ops.wm.save_as_mainfile(filepath=os.path.abspath(path), check_existing=False)


def _open(path: str) -> None:
    import bpy
    if not os.path.isfile(path):
        raise RuntimeError(f"{path}: no such file")
    bpy.ops.wm.open_mainfile(filepath=os.path.abspath(path), load_ui=False)


def _load_target(path: str) -> tuple[list, list]:
    import numpy as np
    with np.load(path) as data:
        return data["vertices"].tolist(), data["faces"].tolist()


def cmd_build(args: argparse.Namespace) -> dict:
    from . import scene
    with open(args.input, encoding="utf-8") as f:
        doc = json.load(f)
    job = doc.get(scene.JOB_KEY) or {}
    scale = args.resolution_scale or float(job.get("resolution_scale", 1.0))
    original = args.original_frame or bool(job.get("original_frame", False))
    target_path = args.target or job.get("target")
    name = (args.collection or job.get("collection")
            or os.path.splitext(os.path.basename(args.output))[0])
    _reset()
    target = _load_target(target_path) if target_path else None
    _, report = scene.build(doc, name, original_frame=original, resolution_scale=scale,
                            folds=job.get("folds"), target=target)
    _save(args.output)
    report["output"] = args.output
    return report


def cmd_read(args: argparse.Namespace) -> dict:
    from . import scene
    _open(args.input)
    doc, notes = scene.read_objects()
    with open(args.output, "w", encoding="utf-8") as f:
        json.dump(doc, f)
    return {"output": args.output, "primitives": len(doc["primitives"]), "notes": notes}


def cmd_mesh(args: argparse.Namespace) -> dict:
    import bpy
    import numpy as np

    from . import scene
    _open(args.input)
    depsgraph = bpy.context.evaluated_depsgraph_get()
    arrays, names = {}, []
    for i, ob in enumerate(scene.sweep_objects()):
        verts, tris = scene.evaluated_triangles(ob, depsgraph)
        arrays[f"vertices_{i}"] = np.asarray(verts, dtype=np.float64).reshape(-1, 3)
        arrays[f"faces_{i}"] = np.asarray(tris, dtype=np.int64).reshape(-1, 3)
        names.append(ob.name)
    arrays["names"] = np.asarray(json.dumps(names))
    np.savez(args.output, **arrays)
    return {"output": args.output, "objects": names}


def cmd_render(args: argparse.Namespace) -> dict:
    import bpy
    from mathutils import Vector

    from . import scene
    _open(args.input)
    sc = bpy.context.scene
    obs = [ob for ob in sc.objects if ob.type in {"CURVE", "MESH"} and not ob.hide_render
           and scene.PREFIX + "primitive" in ob]
    depsgraph = bpy.context.evaluated_depsgraph_get()
    pts = []
    for ob in obs:
        ev = ob.evaluated_get(depsgraph)
        me = ev.to_mesh()
        pts += [ob.matrix_world @ v.co for v in me.vertices]
        ev.to_mesh_clear()
    lo = Vector([min(p[i] for p in pts) for i in range(3)]) if pts else Vector((-1, -1, -1))
    hi = Vector([max(p[i] for p in pts) for i in range(3)]) if pts else Vector((1, 1, 1))
    centre, size = (lo + hi) / 2, max((hi - lo).length, 1e-6)
    cam_data = bpy.data.cameras.new("sweepedit camera")
    cam = bpy.data.objects.new("sweepedit camera", cam_data)
    sc.collection.objects.link(cam)
    direction = Vector((1.0, -1.4, 0.9)).normalized()
    cam.location = centre + direction * size * 1.3
    cam.rotation_euler = (-direction).to_track_quat("-Z", "Y").to_euler()
    cam_data.lens = 50
    cam_data.clip_end = size * 10
    sc.camera = cam
    sc.render.engine = "BLENDER_WORKBENCH"
    sc.display.shading.light = "STUDIO"
    sc.display.shading.color_type = "MATERIAL"
    sc.render.resolution_x = sc.render.resolution_y = args.size
    sc.render.film_transparent = False
    sc.render.filepath = os.path.abspath(args.output)
    sc.render.image_settings.file_format = "PNG"
    bpy.ops.render.render(write_still=True)
    return {"output": args.output, "objects": len(obs),
            "view_size": size if math.isfinite(size) else None}


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="sweepedit_blender")
    sub = p.add_subparsers(dest="command", required=True)
    b = sub.add_parser("build", help="parameter file -> .blend of curve objects")
    b.add_argument("input")
    b.add_argument("output")
    b.add_argument("--target", help="an .npz (vertices, faces) in the normalised frame")
    b.add_argument("--resolution-scale", type=float, default=None)
    b.add_argument("--original-frame", action="store_true")
    b.add_argument("--collection")
    r = sub.add_parser("read", help=".blend -> parameter file")
    r.add_argument("input")
    r.add_argument("output")
    m = sub.add_parser("mesh", help=".blend -> each primitive's evaluated mesh (.npz)")
    m.add_argument("input")
    m.add_argument("output")
    q = sub.add_parser("render", help=".blend -> a workbench picture (.png)")
    q.add_argument("input")
    q.add_argument("output")
    q.add_argument("--size", type=int, default=640)
    return p


COMMANDS = {"build": cmd_build, "read": cmd_read, "mesh": cmd_mesh, "render": cmd_render}


def main(argv: list[str] | None = None) -> int:
    if argv is None:
        argv = sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else sys.argv[1:]
    args = parser().parse_args(argv)
    try:
        report = COMMANDS[args.command](args)
    except Exception as exc:  # one line for the caller to relay
        print(f"sweepedit_blender {args.command}: {type(exc).__name__}: {exc}"
              .replace("\n", " "), file=sys.stderr)
        if os.environ.get("SWEEPEDIT_BLENDER_DEBUG"):
            raise
        return 1
    sys.stdout.write(REPORT_MARKER + json.dumps(report) + "\n")
    sys.stdout.flush()
    return 0
