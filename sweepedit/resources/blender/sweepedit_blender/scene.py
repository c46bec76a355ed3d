"""sweepedit primitives as native Blender curve objects, and back.

One primitive becomes one curve object (named as the primitive):

* axis: a NURBS spline of order 3 with endpoint knots and weights 1 through the control
  points. Blender's endpoint knots are clamped with uniform interior knots: exactly
  sweepedit's clamped quadratic B-spline, and Blender evaluates it at evenly spaced
  parameters (resolution_u points per knot span), i.e. at evenly spaced t.
* profile: a bevel object (a closed 2D curve, caps filled): an exact rational NURBS
  ellipse for d = 2, an exact rhombus for d = 1, otherwise a polygon on the superellipse
  whose distance from the true curve is measured and reported.
* scaling: a taper object, a polygon through (t, f(t)) at the axis' evaluated
  parameters. Blender reads the taper at the fraction i / (N - 1) of evaluated point i,
  which is t there, so every ring of the sweep has exactly the size f(t).
* frames: twist_mode 'MINIMUM' (rotation-minimising, as sweepedit) and one tilt on all
  points that turns Blender's start frame onto sweepedit's (measured: Blender's bevel x
  starts along tangent.to_track_quat('-Z', 'Y') @ (1, 0, 0), and a tilt θ turns it to
  cos θ X - sin θ Y of that quaternion).

The exact parameters are kept as custom properties (doubles) on each object, the
normalisation and the rest of the parameter file on the collection, so reading back is
exact wherever the user did not edit (read_objects).
"""

from __future__ import annotations

import json
import math

import bpy
from mathutils import Matrix, Vector

from . import geometry as geo

PREFIX = "sweepedit_"
DOC_KEYS = ("format", "version", "normalization", "source", "primitives", "fit")
JOB_KEY = "sweepedit_blender"
# Points further apart than this (normalised units) count as moved by the user: Blender
# keeps coordinates as 32-bit floats, which round a point of the unit cube by ~3e-8.
EDIT_TOLERANCE = 2e-6


def _flat(rows: list[list[float]]) -> list[float]:
    return [float(v) for row in rows for v in row]


def _rows(flat: list[float], width: int) -> list[list[float]]:
    return [list(flat[i:i + width]) for i in range(0, len(flat), width)]


def _link(ob: bpy.types.Object, collection: bpy.types.Collection) -> bpy.types.Object:
    collection.objects.link(ob)
    return ob


def _material(name: str, color: str) -> bpy.types.Material:
    mat = bpy.data.materials.new(name)
    rgb = geo.hex_to_linear(color)
    mat.diffuse_color = (*rgb, 1.0)
    if not getattr(mat, "node_tree", None) and hasattr(mat, "use_nodes"):
        mat.use_nodes = True
    tree = getattr(mat, "node_tree", None)
    if tree is not None:
        for node in tree.nodes:
            if node.type == "BSDF_PRINCIPLED":
                node.inputs["Base Color"].default_value = (*rgb, 1.0)
    return mat


def _clockwise(points: list) -> list:
    """The profile's points in clockwise order, first point kept: Blender's sweep faces
    outwards with its bevel drawn clockwise (measured), and its caps follow."""
    return points[:1] + points[1:][::-1]


def _bevel_object(name: str, a: float, b: float, d: float, scale: float,
                  collection: bpy.types.Collection) -> tuple[bpy.types.Object, dict]:
    cu = bpy.data.curves.new(name, "CURVE")
    cu.dimensions = "2D"
    cu.fill_mode = "NONE"
    kind = geo.profile_kind(d)
    if kind == "ellipse":
        # Blender's cyclic Bezier-knot NURBS passes through the points at odd indices
        # (measured): start on a corner so that the on-curve points are the axis ends.
        pts = _clockwise(geo.ellipse_nurbs(a, b))
        pts = pts[-1:] + pts[:-1]
        sp = cu.splines.new("NURBS")
        sp.points.add(len(pts) - 1)
        for p, (x, y, w) in zip(sp.points, pts, strict=False):
            p.co = (x, y, 0.0, w)
            p.weight = w
        sp.use_cyclic_u = True
        sp.use_bezier_u = True
        sp.order_u = 3
        sp.resolution_u = max(1, round(geo.ELLIPSE_POINTS * scale / 4))
        info = {"profile": "ellipse", "approximated": False, "profile_error": 0.0,
                "profile_points": 4 * sp.resolution_u}
    else:
        pts, error = geo.profile_polygon(a, b, d, scale)
        pts = _clockwise(pts)
        sp = cu.splines.new("POLY")
        sp.points.add(len(pts) - 1)
        for p, (x, y) in zip(sp.points, pts, strict=False):
            p.co = (x, y, 0.0, 1.0)
        sp.use_cyclic_u = True
        info = {"profile": kind, "approximated": kind != "rhombus", "profile_error": error,
                "profile_points": len(pts)}
    ob = _link(bpy.data.objects.new(name, cu), collection)
    return ob, info


def _taper_object(name: str, scaling: list[float], n_rings: int,
                  collection: bpy.types.Collection) -> bpy.types.Object:
    cu = bpy.data.curves.new(name, "CURVE")
    cu.dimensions = "2D"
    cu.fill_mode = "NONE"
    sp = cu.splines.new("POLY")
    sp.points.add(n_rings - 1)
    for i, p in enumerate(sp.points):
        t = i / (n_rings - 1)
        p.co = (t, geo.scaling_value(scaling, t), 0.0, 1.0)
    return _link(bpy.data.objects.new(name, cu), collection)


def blender_start_axes(T0: list[float]) -> tuple[list[float], list[float]]:
    """Where Blender's bevel x (at tilt 0) and the direction a positive tilt turns it from
    start, for a curve whose first tangent is T0 (measured, see the module docstring)."""
    q = Vector(T0).to_track_quat("-Z", "Y")
    return list(q @ Vector((1.0, 0.0, 0.0))), list(q @ Vector((0.0, 1.0, 0.0)))


def start_tilt(control_points: list[list[float]]) -> float:
    """The tilt that puts the profile's a half-axis on sweepedit's U0."""
    T0 = geo.start_tangent(control_points)
    U0, _ = geo.initial_frame(T0)
    qx, qy = blender_start_axes(T0)
    along_x = sum(u * x for u, x in zip(U0, qx, strict=True))
    along_y = sum(u * y for u, y in zip(U0, qy, strict=True))
    return math.atan2(-along_y, along_x)


def build_primitive(prim: dict, index: int, collection: bpy.types.Collection,
                    helpers: bpy.types.Collection, *, resolution_scale: float = 1.0,
                    folds: bool = False, parent: bpy.types.Object | None = None,
                    ) -> tuple[bpy.types.Object, dict]:
    """One primitive (a parameter file's primitive dict) as a curve object -> (object,
    report entry)."""
    cps = [[float(v) for v in c] for c in prim["control_points"]]
    profile = prim["profile"]
    a, b, d = float(profile["a"]), float(profile["b"]), float(profile["degree"])
    scaling = [float(s) for s in prim.get("scaling", [])]
    name = prim.get("name") or f"primitive {index + 1}"
    color = prim.get("color") or "#e4572e"
    n = len(cps)
    res_u = geo.axis_resolution(n, resolution_scale)
    n_rings = res_u * (n - 2) + 1

    bevel, info = _bevel_object(f"{name} bevel", a, b, d, resolution_scale, helpers)
    taper = _taper_object(f"{name} taper", scaling, n_rings, helpers)
    tilt = start_tilt(cps)

    cu = bpy.data.curves.new(name, "CURVE")
    cu.dimensions = "3D"
    cu.twist_mode = "MINIMUM"
    cu.bevel_mode = "OBJECT"
    cu.bevel_object = bevel
    cu.use_fill_caps = True
    cu.taper_object = taper
    cu.taper_radius_mode = "OVERRIDE"
    cu.use_map_taper = False
    cu.resolution_u = res_u
    sp = cu.splines.new("NURBS")
    sp.points.add(n - 1)
    for p, c in zip(sp.points, cps, strict=False):
        p.co = (c[0], c[1], c[2], 1.0)
        p.weight = 1.0
        p.tilt = tilt
        p.radius = 1.0
    sp.order_u = 3
    sp.use_endpoint_u = True
    sp.use_bezier_u = False
    sp.resolution_u = res_u
    sp.use_smooth = True
    mat = _material(name, color)
    cu.materials.append(mat)

    ob = bpy.data.objects.new(name, cu)
    collection.objects.link(ob)
    if parent is not None:
        ob.parent = parent
        ob.matrix_parent_inverse = Matrix.Identity(4)
    ob.color = (*geo.hex_to_linear(color), 1.0)
    visible = bool(prim.get("visible", True))
    ob.hide_viewport = not visible
    ob.hide_render = not visible

    ob[PREFIX + "primitive"] = index
    ob[PREFIX + "name"] = name
    ob[PREFIX + "object_name"] = ob.name
    ob[PREFIX + "control_points"] = _flat(cps)
    ob[PREFIX + "a"] = a
    ob[PREFIX + "b"] = b
    ob[PREFIX + "degree"] = d
    ob[PREFIX + "scaling"] = json.dumps(scaling)  # an empty list is no ID property array
    ob[PREFIX + "color"] = color
    ob[PREFIX + "visible"] = visible
    ob[PREFIX + "locked"] = bool(prim.get("locked", False))
    ob[PREFIX + "folds"] = bool(folds)
    ob[PREFIX + "bevel_points"] = _flat(_spline_points(bevel))
    ob[PREFIX + "taper_points"] = _flat(_spline_points(taper))
    known = {"control_points", "profile", "scaling", "name", "color", "visible", "locked"}
    extras = {k: v for k, v in prim.items() if k not in known}
    profile_extras = {k: v for k, v in profile.items() if k not in ("a", "b", "degree")}
    if profile_extras:
        extras["profile"] = profile_extras
    if extras:
        ob[PREFIX + "extras"] = json.dumps(extras)
    entry = {"index": index, "name": name, "object": ob.name, "degree": d, **info,
             "folds": bool(folds), "resolution_u": res_u, "rings": n_rings, "tilt": tilt}
    return ob, entry


def _spline_points(ob: bpy.types.Object) -> list[list[float]]:
    sp = ob.data.splines[0]
    pts = sp.points if sp.type != "BEZIER" else sp.bezier_points
    return [[float(p.co[0]), float(p.co[1])] for p in pts]


def _frame_matrix(normalization: dict) -> Matrix:
    s = float(normalization.get("scale", 1.0))
    c = [float(v) for v in normalization.get("center", (0.0, 0.0, 0.0))]
    return Matrix.Translation(Vector(c)) @ Matrix.Diagonal((s, s, s, 1.0))


def build(doc: dict, name: str, *, parent_collection: bpy.types.Collection | None = None,
          original_frame: bool = False, frame_matrix: Matrix | None = None,
          resolution_scale: float = 1.0, folds: list[bool] | None = None,
          target: tuple[list, list] | None = None) -> tuple[bpy.types.Collection, dict]:
    """A parameter file's document as a collection of curve objects -> (collection,
    report). frame_matrix (or original_frame: the file's normalisation) places the
    primitives through a parent empty; their own coordinates stay normalised.
    target: (vertices, faces) of a mesh in the normalised frame, shown beside them."""
    doc = {k: v for k, v in doc.items() if k != JOB_KEY}
    parent_collection = parent_collection or bpy.context.scene.collection
    coll = bpy.data.collections.new(name)
    parent_collection.children.link(coll)
    # The bevel and taper curves: hidden (Blender still evaluates them); show the
    # collection in the outliner to edit them.
    helpers = bpy.data.collections.new(f"{name} profiles")
    coll.children.link(helpers)
    helpers.hide_render = True
    helpers.hide_viewport = True

    normalization = doc.get("normalization") or {"center": [0.0, 0.0, 0.0], "scale": 1.0}
    if frame_matrix is None and original_frame:
        frame_matrix = _frame_matrix(normalization)
    frame = None
    if frame_matrix is not None:
        frame = bpy.data.objects.new(f"{name} frame", None)
        frame.empty_display_type = "ARROWS"
        frame.empty_display_size = 0.1
        coll.objects.link(frame)
        frame.matrix_world = frame_matrix
        frame[PREFIX + "frame"] = True

    coll[PREFIX + "normalization_center"] = [float(v) for v in normalization["center"]]
    coll[PREFIX + "normalization_scale"] = float(normalization["scale"])
    coll[PREFIX + "document"] = json.dumps({k: v for k, v in doc.items() if k != "primitives"})
    coll[PREFIX + "original_frame"] = frame is not None

    entries = []
    prims = doc.get("primitives", [])
    folds = folds or [False] * len(prims)
    for i, prim in enumerate(prims):
        _, entry = build_primitive(prim, i, coll, helpers, resolution_scale=resolution_scale,
                                   folds=bool(folds[i]), parent=frame)
        entries.append(entry)
    for ob in helpers.objects:
        ob.hide_render = True
    if target is not None:
        _target_object(f"{name} target", target, coll, frame)
    return coll, {"collection": coll.name, "primitives": entries}


def _target_object(name: str, target: tuple[list, list], coll: bpy.types.Collection,
                   frame: bpy.types.Object | None) -> bpy.types.Object:
    vertices, faces = target
    me = bpy.data.meshes.new(name)
    me.from_pydata([tuple(map(float, v)) for v in vertices], [], [tuple(map(int, f))
                                                                   for f in faces])
    me.update()
    ob = bpy.data.objects.new(name, me)
    coll.objects.link(ob)
    if frame is not None:
        ob.parent = frame
        ob.matrix_parent_inverse = Matrix.Identity(4)
    ob.display_type = "WIRE"
    ob.hide_render = True
    ob[PREFIX + "target"] = True
    return ob


# --------------------------------------------------------------------------- reading back


def sweep_objects(objects: list[bpy.types.Object] | None = None) -> list[bpy.types.Object]:
    """The sweepedit curve objects among `objects` (all of the file's when None), in the
    order of their primitive index (then name)."""
    objects = list(bpy.data.objects) if objects is None else objects
    found = [ob for ob in objects if ob.type == "CURVE" and PREFIX + "primitive" in ob]
    return sorted(found, key=lambda ob: (int(ob[PREFIX + "primitive"]), ob.name))


def _matrix_rows(m: Matrix) -> list[list[float]]:
    return [[float(m[i][j]) for j in range(4)] for i in range(4)]


def _mat_mul(A: list[list[float]], B: list[list[float]]) -> list[list[float]]:
    return [[sum(A[i][k] * B[k][j] for k in range(4)) for j in range(4)] for i in range(4)]


def _mat_inv(M: list[list[float]]) -> list[list[float]]:
    """Inverse of a 4x4 matrix in double precision (Gauss-Jordan)."""
    n = 4
    A = [row[:] + [1.0 if i == j else 0.0 for j in range(n)] for i, row in enumerate(M)]
    for col in range(n):
        piv = max(range(col, n), key=lambda i: abs(A[i][col]))
        A[col], A[piv] = A[piv], A[col]
        p = A[col][col]
        A[col] = [x / p for x in A[col]]
        for i in range(n):
            if i != col:
                f = A[i][col]
                A[i] = [x - f * y for x, y in zip(A[i], A[col], strict=False)]
    return [row[n:] for row in A]


def _apply(M: list[list[float]], p: list[float]) -> list[float]:
    return [M[i][0] * p[0] + M[i][1] * p[1] + M[i][2] * p[2] + M[i][3] for i in range(3)]


def frame_of(ob: bpy.types.Object) -> bpy.types.Object | None:
    """The parent empty that places `ob`'s collection (the original frame), if any."""
    parent = ob.parent
    while parent is not None:
        if parent.get(PREFIX + "frame"):
            return parent
        parent = parent.parent
    return None


def to_normalized_matrix(ob: bpy.types.Object) -> list[list[float]]:
    """Object coordinates -> the normalised frame: the object's transform and its
    parents', up to its frame (if it has one). Built from each object's own location,
    rotation and scale (matrix_basis) rather than matrix_world, which Blender does not
    update for hidden objects; constraints and drivers are not applied."""
    M = [[1.0 if i == j else 0.0 for j in range(4)] for i in range(4)]
    node = ob
    while node is not None and not node.get(PREFIX + "frame"):
        local = _matrix_rows(node.matrix_basis)
        if node.parent is not None:
            local = _mat_mul(_matrix_rows(node.matrix_parent_inverse), local)
        M = _mat_mul(local, M)
        node = node.parent
    return M


def _close(u: list[float], v: list[float], tol: float) -> bool:
    return len(u) == len(v) and all(abs(x - y) <= tol for x, y in zip(u, v, strict=False))


def read_object(ob: bpy.types.Object) -> tuple[dict, list[str]]:
    """One curve object as a primitive dict -> (primitive, notes on what was edited).

    control points: the spline's points, through the object's world matrix (and back
      through its frame) - the stored doubles when they agree within EDIT_TOLERANCE.
    a, b, d: stored, unless the bevel curve's points changed: then a and b are the
      half-extents of its points (x, y) and d the stored exponent where it still fits the
      points (else a 1-D least-squares fit).
    scaling: stored, unless the taper's points changed: then f is fitted to them by least
      squares with the stored number of terms; a taper that no longer starts at 1 scales
      a and b by its value there.
    name, colour, visibility: the object's name (if renamed), its material's viewport
      colour (if changed), its viewport/render visibility.
    """
    notes = []
    stored = lambda key, default=None: ob.get(PREFIX + key, default)  # noqa: E731
    M = to_normalized_matrix(ob)
    sp = ob.data.splines[0]
    raw = [list(p.co[:3]) for p in (sp.points if sp.type != "BEZIER" else sp.bezier_points)]
    cps = [_apply(M, p) for p in raw]
    stored_cps = stored("control_points")
    if stored_cps is not None:
        stored_rows = _rows(list(stored_cps), 3)
        if len(stored_rows) == len(cps) and all(_close(p, q, EDIT_TOLERANCE)
                                                for p, q in zip(cps, stored_rows, strict=False)):
            cps = stored_rows
        else:
            notes.append("control points moved")
    if sp.type != "NURBS" or sp.order_u != 3 or not sp.use_endpoint_u or sp.use_cyclic_u:
        notes.append("the axis is no longer an endpoint NURBS of order 3; its points are "
                     "read as control points")
    if sp.type == "NURBS" and any(abs(p.co[3] - 1.0) > 1e-6 for p in sp.points):
        notes.append("NURBS weights are ignored (sweepedit's axis is not rational)")

    a, b, d = stored("a"), stored("b"), stored("degree")
    scaling = json.loads(stored("scaling", "[0.0, 0.0]"))
    bevel = ob.data.bevel_object if ob.data.bevel_mode == "OBJECT" else None
    if bevel is not None and bevel.type == "CURVE" and len(bevel.data.splines):
        pts = _spline_points(bevel)
        if a is None or not _close(_flat(pts), list(stored("bevel_points", [])), 1e-6):
            xs, ys = [p[0] for p in pts], [p[1] for p in pts]
            a, b = (max(xs) - min(xs)) / 2.0, (max(ys) - min(ys)) / 2.0
            on_curve = (pts if bevel.data.splines[0].type == "POLY"
                        else [p for p in pts if abs(p[0]) < 1e-9 or abs(p[1]) < 1e-9])
            fits = d is not None and all(abs(abs(x / a) ** d + abs(y / b) ** d - 1.0) < 1e-3
                                         for x, y in on_curve)
            if not fits:
                d = geo.fit_degree(on_curve, a, b)
            notes.append("profile edited")
    taper = ob.data.taper_object
    if taper is not None and taper.type == "CURVE" and len(taper.data.splines):
        pts = _spline_points(taper)
        if not _close(_flat(pts), list(stored("taper_points", [])), 1e-6):
            xs = [p[0] for p in pts]
            lo, hi = min(xs), max(xs)
            ts = [(x - lo) / (hi - lo) if hi > lo else 0.0 for x in xs]
            coeffs = geo.fit_scaling_free(ts, [p[1] for p in pts], max(len(scaling), 1))
            c0 = coeffs[0] if coeffs[0] > 1e-6 else 1.0
            a, b = a * c0, b * c0
            scaling = [c / c0 for c in coeffs[1:]]
            notes.append("taper edited")

    name = stored("name", ob.name)
    if ob.name != stored("object_name", ob.name):
        name = ob.name
    color = stored("color", "#e4572e")
    mat = ob.active_material
    if mat is not None and geo.linear_to_hex(tuple(mat.diffuse_color)) != geo.linear_to_hex(
            geo.hex_to_linear(color)):
        color = geo.linear_to_hex(tuple(mat.diffuse_color))
    prim = {"control_points": cps, "profile": {"a": a, "b": b, "degree": d},
            "scaling": scaling, "name": name, "color": color,
            "visible": not (ob.hide_viewport or ob.hide_render),
            "locked": bool(stored("locked", False))}
    extras = json.loads(stored("extras", "{}"))
    profile_extras = extras.pop("profile", None)
    if profile_extras:
        prim["profile"].update(profile_extras)
    prim.update(extras)
    return prim, notes


def _collection_of(ob: bpy.types.Object) -> bpy.types.Collection | None:
    for coll in ob.users_collection:
        if PREFIX + "document" in coll:
            return coll
    return None


def read_objects(objects: list[bpy.types.Object] | None = None) -> tuple[dict, list[str]]:
    """A parameter-file document of the sweepedit curves among `objects` (all in the file
    when None) -> (document, notes naming each edited primitive). The normalisation and
    the rest of the document come from the first primitive's collection."""
    obs = sweep_objects(objects)
    doc = {"format": "sweepedit.abstraction", "version": 1,
           "normalization": {"center": [0.0, 0.0, 0.0], "scale": 1.0}, "source": None,
           "primitives": [], "fit": None}
    coll = next((c for c in map(_collection_of, obs) if c is not None), None)
    if coll is not None:
        doc.update(json.loads(coll[PREFIX + "document"]))
        norm = dict(doc.get("normalization") or {})
        norm["center"] = [float(v) for v in coll[PREFIX + "normalization_center"]]
        norm["scale"] = float(coll[PREFIX + "normalization_scale"])
        doc["normalization"] = norm
    notes = []
    for ob in obs:
        prim, edits = read_object(ob)
        doc["primitives"].append(prim)
        notes.extend(f"{prim['name']}: {e}" for e in edits)
    ordered = {k: doc[k] for k in DOC_KEYS if k in doc}
    ordered.update({k: v for k, v in doc.items() if k not in ordered})
    return ordered, notes


def evaluated_triangles(ob: bpy.types.Object, depsgraph: bpy.types.Depsgraph | None = None,
                        ) -> tuple[list[list[float]], list[list[int]]]:
    """The curve object's evaluated surface (what Blender renders) as triangles, in the
    normalised frame."""
    depsgraph = depsgraph or bpy.context.evaluated_depsgraph_get()
    ev = ob.evaluated_get(depsgraph)
    me = ev.to_mesh()
    try:
        me.calc_loop_triangles()
        M = to_normalized_matrix(ob)
        verts = [_apply(M, list(v.co)) for v in me.vertices]
        tris = [list(t.vertices) for t in me.loop_triangles]
    finally:
        ev.to_mesh_clear()
    return verts, tris
