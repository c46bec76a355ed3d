# ruff: noqa: N801, RUF012  (Blender names classes AREA_OT_name and keeps bl_options sets)
"""The add-on's operators, preferences and menu entries.

* File > Import > sweepedit parameters (.json): a parameter file as curve objects.
* File > Export > sweepedit parameters (.json): the selected sweep curves as a file.
* Object > Abstract selected mesh (sweepedit): runs ``sweepedit fit MESH -o OUT.json
  --progress-json`` on the selected mesh in a subprocess (progress in the status bar,
  Esc cancels) and imports the result as curves placed on the mesh.
"""

from __future__ import annotations

import json
import os
import queue
import shutil
import struct
import subprocess
import tempfile
import threading
import time

import bpy
from bpy.props import BoolProperty, FloatProperty, StringProperty
from bpy_extras.io_utils import ExportHelper, ImportHelper
from mathutils import Matrix, Vector

from . import scene

ADDON = __package__


def _prefs() -> bpy.types.AddonPreferences | None:
    addon = bpy.context.preferences.addons.get(ADDON)
    return addon.preferences if addon else None


class SWEEPEDIT_AP_preferences(bpy.types.AddonPreferences):
    bl_idname = ADDON
    executable: StringProperty(
        name="sweepedit executable", subtype="FILE_PATH", default="",
        description="Path of the `sweepedit` command (empty: the one on PATH)")

    def draw(self, context: bpy.types.Context) -> None:
        self.layout.prop(self, "executable")


def _print_report(op: bpy.types.Operator, report: dict) -> None:
    for e in report["primitives"]:
        if e["approximated"]:
            op.report({"INFO"}, f"{e['name']}: the superellipse (d = {e['degree']:.3g}) "
                      f"is drawn as a polygon of {e['profile_points']} points, within "
                      f"{e['profile_error']:.2g} of the profile's size")
        if e["folds"]:
            op.report({"WARNING"}, f"{e['name']} folds: Blender's curve turns inside-out "
                      "there, the solid is not exact")


def import_document(doc: dict, name: str, *, original_frame: bool = True,
                    frame_matrix: Matrix | None = None, resolution_scale: float = 1.0,
                    ) -> tuple[bpy.types.Collection, dict]:
    job = doc.get(scene.JOB_KEY) or {}
    coll, report = scene.build(doc, name, original_frame=original_frame,
                               frame_matrix=frame_matrix, resolution_scale=resolution_scale,
                               folds=job.get("folds"))
    return coll, report


class SWEEPEDIT_OT_import_json(bpy.types.Operator, ImportHelper):
    """Import a sweepedit parameter file as editable curve objects"""
    bl_idname = "import_scene.sweepedit_json"
    bl_label = "Import sweepedit parameters"
    bl_options = {"REGISTER", "UNDO"}
    filename_ext = ".json"
    filter_glob: StringProperty(default="*.json", options={"HIDDEN"})
    original_frame: BoolProperty(
        name="Original frame", default=True,
        description="Place the primitives where the shape was (normalised frame otherwise)")
    resolution_scale: FloatProperty(name="Resolution scale", default=1.0, min=0.25, max=16.0)

    def execute(self, context: bpy.types.Context) -> set[str]:
        try:
            with open(self.filepath, encoding="utf-8") as f:
                doc = json.load(f)
        except (OSError, ValueError) as exc:
            self.report({"ERROR"}, f"{self.filepath}: {exc}")
            return {"CANCELLED"}
        name = os.path.splitext(os.path.basename(self.filepath))[0]
        _, report = import_document(doc, name, original_frame=self.original_frame,
                                    resolution_scale=self.resolution_scale)
        _print_report(self, report)
        self.report({"INFO"}, f"imported {len(report['primitives'])} primitives")
        return {"FINISHED"}


class SWEEPEDIT_OT_export_json(bpy.types.Operator, ExportHelper):
    """Write the selected sweep curves as a sweepedit parameter file"""
    bl_idname = "export_scene.sweepedit_json"
    bl_label = "Export sweepedit parameters"
    filename_ext = ".json"
    filter_glob: StringProperty(default="*.json", options={"HIDDEN"})
    selected_only: BoolProperty(name="Selected only", default=True)

    def execute(self, context: bpy.types.Context) -> set[str]:
        objects = list(context.selected_objects) if self.selected_only else None
        if not scene.sweep_objects(objects):
            self.report({"ERROR"}, "no sweepedit curves selected")
            return {"CANCELLED"}
        doc, notes = scene.read_objects(objects)
        tmp = f"{self.filepath}.{os.getpid()}.tmp"
        with open(tmp, "w", encoding="utf-8") as f:
            json.dump(doc, f, indent=1)
        os.replace(tmp, self.filepath)
        for note in notes:
            self.report({"INFO"}, note)
        self.report({"INFO"}, f"wrote {len(doc['primitives'])} primitives")
        return {"FINISHED"}


def write_ply(ob: bpy.types.Object, path: str, depsgraph: bpy.types.Depsgraph) -> None:
    """The object's evaluated mesh (modifiers applied), in its own coordinates, as a
    binary PLY of triangles."""
    ev = ob.evaluated_get(depsgraph)
    me = ev.to_mesh()
    try:
        me.calc_loop_triangles()
        with open(path, "wb") as f:
            f.write(("ply\nformat binary_little_endian 1.0\n"
                     f"element vertex {len(me.vertices)}\n"
                     "property float x\nproperty float y\nproperty float z\n"
                     f"element face {len(me.loop_triangles)}\n"
                     "property list uchar int vertex_indices\nend_header\n").encode())
            f.write(b"".join(struct.pack("<3f", *v.co) for v in me.vertices))
            f.write(b"".join(struct.pack("<B3i", 3, *t.vertices) for t in me.loop_triangles))
    finally:
        ev.to_mesh_clear()


class FitJob:
    """``sweepedit fit`` in a subprocess; its --progress-json lines read by a thread."""

    def __init__(self, executable: str, mesh: str, output: str) -> None:
        self.output = output
        self.proc = subprocess.Popen([executable, "fit", mesh, "-o", output, "--progress-json"],
                                     stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        self.events: queue.Queue = queue.Queue()
        self.stderr: list[str] = []
        threading.Thread(target=self._read, args=(self.proc.stdout, True), daemon=True).start()
        threading.Thread(target=self._read, args=(self.proc.stderr, False), daemon=True).start()
        self.fraction = 0.0
        self.text = "sweepedit: starting"
        self.done: dict | None = None

    def _read(self, stream: object, is_stdout: bool) -> None:
        for line in stream:
            if not is_stdout:
                self.stderr.append(line.strip())
                continue
            try:
                self.events.put(json.loads(line))
            except ValueError:
                continue

    def poll(self) -> bool:
        """Take in the events so far; True once the process has ended."""
        while True:
            try:
                ev = self.events.get_nowait()
            except queue.Empty:
                break
            if ev.get("event") == "progress":
                self.fraction = float(ev.get("fraction") or 0.0)
                left = ev.get("seconds_left")
                self.text = (f"sweepedit: {ev.get('stage', 'fit')} {self.fraction:.0%}, "
                             f"{ev.get('primitives', '?')} primitives"
                             + (f", about {left:.0f} s left" if left is not None else ""))
            elif ev.get("event") == "done":
                self.done = ev
        return self.proc.poll() is not None

    def error(self) -> str | None:
        if self.proc.returncode == 0 and os.path.isfile(self.output):
            return None
        return (self.stderr[-1] if self.stderr else f"sweepedit exited with status "
                f"{self.proc.returncode}")

    def cancel(self) -> None:
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(timeout=5)
            except subprocess.TimeoutExpired:
                self.proc.kill()


class SWEEPEDIT_OT_abstract(bpy.types.Operator):
    """Fit sweep primitives to the selected mesh with sweepedit and import them as curves"""
    bl_idname = "object.sweepedit_abstract"
    bl_label = "Abstract selected mesh (sweepedit)"
    bl_options = {"REGISTER", "UNDO"}
    executable: StringProperty(name="sweepedit executable", default="",
                               options={"SKIP_SAVE"})

    _timer = None
    _job: FitJob | None = None

    @classmethod
    def poll(cls, context: bpy.types.Context) -> bool:
        ob = context.active_object
        return ob is not None and ob.type == "MESH"

    def _start(self, context: bpy.types.Context) -> bool:
        exe = self.executable or (_prefs().executable if _prefs() else "") or shutil.which(
            "sweepedit")
        if not exe:
            self.report({"ERROR"}, "sweepedit not found: set its path in the add-on's "
                        "preferences or put `sweepedit` on PATH")
            return False
        self._mesh = context.active_object
        self._dir = tempfile.mkdtemp(prefix="sweepedit-")
        ply = os.path.join(self._dir, "mesh.ply")
        write_ply(self._mesh, ply, context.evaluated_depsgraph_get())
        try:
            self._job = FitJob(exe, ply, os.path.join(self._dir, "params.json"))
        except OSError as exc:
            self.report({"ERROR"}, f"cannot run {exe}: {exc}")
            return False
        return True

    def _finish(self, context: bpy.types.Context) -> set[str]:
        job = self._job
        err = job.error()
        shutil_dir = self._dir
        if err:
            self.report({"ERROR"}, err)
            shutil.rmtree(shutil_dir, ignore_errors=True)
            return {"CANCELLED"}
        with open(job.output, encoding="utf-8") as f:
            doc = json.load(f)
        shutil.rmtree(shutil_dir, ignore_errors=True)
        norm = doc.get("normalization") or {"center": [0, 0, 0], "scale": 1.0}
        s = float(norm["scale"])
        frame = (self._mesh.matrix_world @ Matrix.Translation(Vector(norm["center"]))
                 @ Matrix.Diagonal((s, s, s, 1.0)))
        _, report = import_document(doc, f"{self._mesh.name} sweeps", frame_matrix=frame)
        _print_report(self, report)
        self.report({"INFO"}, f"sweepedit: {len(report['primitives'])} primitives")
        return {"FINISHED"}

    def execute(self, context: bpy.types.Context) -> set[str]:
        """Without a window (scripts, background): run the fit to the end, blocking."""
        if not self._start(context):
            return {"CANCELLED"}
        while not self._job.poll():
            time.sleep(0.05)
        self._job.poll()
        return self._finish(context)

    def invoke(self, context: bpy.types.Context, event: bpy.types.Event) -> set[str]:
        if not self._start(context):
            return {"CANCELLED"}
        wm = context.window_manager
        self._timer = wm.event_timer_add(0.2, window=context.window)
        wm.progress_begin(0.0, 1.0)
        wm.modal_handler_add(self)
        return {"RUNNING_MODAL"}

    def _end_modal(self, context: bpy.types.Context) -> None:
        wm = context.window_manager
        wm.event_timer_remove(self._timer)
        wm.progress_end()
        context.workspace.status_text_set(None)

    def modal(self, context: bpy.types.Context, event: bpy.types.Event) -> set[str]:
        if event.type == "ESC":
            self._job.cancel()
            self._end_modal(context)
            shutil.rmtree(self._dir, ignore_errors=True)
            self.report({"INFO"}, "sweepedit: cancelled")
            return {"CANCELLED"}
        if event.type != "TIMER":
            return {"PASS_THROUGH"}
        finished = self._job.poll()
        context.window_manager.progress_update(self._job.fraction)
        context.workspace.status_text_set(self._job.text + " (Esc cancels)")
        if not finished:
            return {"RUNNING_MODAL"}
        self._end_modal(context)
        return self._finish(context)


def _menu_import(self: bpy.types.Menu, context: bpy.types.Context) -> None:
    self.layout.operator(SWEEPEDIT_OT_import_json.bl_idname, text="sweepedit parameters (.json)")


def _menu_export(self: bpy.types.Menu, context: bpy.types.Context) -> None:
    self.layout.operator(SWEEPEDIT_OT_export_json.bl_idname, text="sweepedit parameters (.json)")


def _menu_object(self: bpy.types.Menu, context: bpy.types.Context) -> None:
    self.layout.operator(SWEEPEDIT_OT_abstract.bl_idname)


CLASSES = (SWEEPEDIT_AP_preferences, SWEEPEDIT_OT_import_json, SWEEPEDIT_OT_export_json,
           SWEEPEDIT_OT_abstract)
MENUS = (("TOPBAR_MT_file_import", _menu_import), ("TOPBAR_MT_file_export", _menu_export),
         ("VIEW3D_MT_object", _menu_object))


def register() -> None:
    for cls in CLASSES:
        bpy.utils.register_class(cls)
    for menu, fn in MENUS:
        getattr(bpy.types, menu).append(fn)


def unregister() -> None:
    for menu, fn in MENUS:
        getattr(bpy.types, menu).remove(fn)
    for cls in reversed(CLASSES):
        bpy.utils.unregister_class(cls)
