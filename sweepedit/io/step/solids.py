"""One primitive as a checked OpenCascade solid (B-rep).

A primitive's side surface is four B-spline patches, one per quadrant of the profile
(geometry/side_surface.py): the profile's four tips are its corners and cusps when d <= 1,
kept sharp. Each patch becomes one face, the two ends flat caps; the six faces are sewn
into a solid, checked with OpenCascade's analyser and against its volume in closed form
(geometry/volumes.py).

A sweep whose sections cross (it folds onto itself, or its axis comes back onto itself)
is lofted through slices of its true solid by planes that do not cross in it
(geometry/slices.py) instead, checked against a quasi-Monte Carlo estimate of its volume
and for crossing itself, and otherwise refused by name.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ThreadPoolExecutor
from itertools import islice
from typing import Any

import numpy as np

from sweepedit.geometry.loft import LoftVerdict, SideSurface, loft_verdict, ring_loft
from sweepedit.geometry.model import Normalization, SweepPrimitive, folds_onto_itself
from sweepedit.geometry.side_surface import AXIS_TOLERANCE, side_surface
from sweepedit.geometry.slices import (
    SlicingPlanes,
    end_stubs,
    ring_candidates,
    rings_on_caps,
    slicing_families,
    surface_samples,
)
from sweepedit.geometry.sweep import axis_points, scaling_factor, superellipse
from sweepedit.geometry.volumes import closed_form_volume, fold_volume
from sweepedit.io.step.checks import check_solid, crosses_itself
from sweepedit.io.step.occ import SEW_TOLERANCE, StepExportError, load_occ
from sweepedit.io.step.writer import as_written

# A solid's volume must match the closed form this closely (relative).
VOLUME_TOLERANCE = 1e-3
# Sweeps whose sections cross: how close their solid's volume must be to the estimate
# (geometry.volumes.fold_volume).
FOLD_VOLUME_TOLERANCE = 0.01
# How many families of slicing planes are tried with end stubs before any without.
STUB_FAMILIES = 5


def _knots_and_mults(knots: np.ndarray) -> tuple[list[float], list[int]]:
    """A flat knot vector -> distinct knots and their multiplicities."""
    values, mults = [float(knots[0])], [1]
    for k in knots[1:]:
        if abs(float(k) - values[-1]) <= 1e-12:
            mults[-1] += 1
        else:
            values.append(float(k))
            mults.append(1)
    return values, mults


def _bspline_face(t_knots: np.ndarray, v_knots: np.ndarray, poles: np.ndarray) -> Any:
    """A face on the cubic x cubic B-spline surface with poles (Nt, Nv, 3), whole."""
    from OCP.BRepBuilderAPI import BRepBuilderAPI_MakeFace
    from OCP.collections import Array1_double, Array1_int, Array2_gp_Pnt
    from OCP.Geom import Geom_BSplineSurface
    from OCP.gp import gp_Pnt

    def reals(values: list[float]) -> Any:
        arr = Array1_double(1, len(values))
        for i, v in enumerate(values, 1):
            arr.SetValue(i, v)
        return arr

    def ints(values: list[int]) -> Any:
        arr = Array1_int(1, len(values))
        for i, v in enumerate(values, 1):
            arr.SetValue(i, v)
        return arr

    nt, nv = poles.shape[:2]
    grid = Array2_gp_Pnt(1, nt, 1, nv)
    for i in range(nt):
        for j in range(nv):
            x, y, z = poles[i, j]
            grid.SetValue(i + 1, j + 1, gp_Pnt(float(x), float(y), float(z)))
    tk, tm = _knots_and_mults(t_knots)
    vk, vm = _knots_and_mults(v_knots)
    surface = Geom_BSplineSurface(grid, reals(tk), reals(vk), ints(tm), ints(vm), 3, 3)
    return BRepBuilderAPI_MakeFace(surface, 1e-9).Face()


def _cap_face(faces: Sequence[Any], first: bool) -> Any:
    """The flat cap bounded by the side faces' iso-curves at t = 0 (first) or t = 1."""
    from OCP.BRep import BRep_Tool
    from OCP.BRepBuilderAPI import (
        BRepBuilderAPI_MakeEdge,
        BRepBuilderAPI_MakeFace,
        BRepBuilderAPI_MakeWire,
    )

    wire = BRepBuilderAPI_MakeWire()
    for face in faces:
        surface = BRep_Tool.Surface_s(face)
        u0, u1, _, _ = surface.Bounds()
        wire.Add(BRepBuilderAPI_MakeEdge(surface.UIso(u0 if first else u1)).Edge())
    if not wire.IsDone():
        raise StepExportError("the cap's outline is not a closed wire")
    maker = BRepBuilderAPI_MakeFace(wire.Wire(), True)
    if not maker.IsDone():
        raise StepExportError("the cap's outline is not planar")
    return maker.Face()


def transform_poles(poles: np.ndarray, normalization: Normalization | None) -> np.ndarray:
    return poles if normalization is None else normalization.to_original(poles)


def describe_primitive(index: int, primitive: SweepPrimitive) -> str:
    """How errors name a primitive: by its name, else by its 0-based index."""
    return f"primitive '{primitive.name}'" if primitive.name else f"primitive {index}"


def sections_cross(primitive: SweepPrimitive) -> bool:
    """Whether the primitive's sections cross (it folds onto itself, or its axis comes
    back onto itself): its solid is then lofted through slices (_sections_union_solids)."""
    return folds_onto_itself(primitive) or _sections_meet(primitive)


def primitive_solid(primitive: SweepPrimitive, index: int = 0,
                    normalization: Normalization | None = None) -> Any:
    """One primitive as a checked OpenCascade TopoDS_Solid (in the original frame when a
    normalization is given). StepExportError names the primitive if it folds onto itself
    or the solid fails a check; CadUnavailableError without OpenCascade."""
    return next(primitive_solids(primitive, index, normalization))


def primitive_solids(primitive: SweepPrimitive, index: int = 0,
                     normalization: Normalization | None = None) -> Iterator[Any]:
    """primitive_solid's solid first (its errors raised on the first next()), then, for a
    primitive whose sections cross, each other solid of it that passes the same checks
    (sliced another way), as a union's fuse may want one (export_step). Lazy: the others
    are searched for only when asked, continuing where the first stopped."""
    load_occ()
    what = describe_primitive(index, primitive)
    primitive.validate(index)
    # Where the axis comes back, the sweep overlaps itself: the closed form counts that
    # twice, and a loft through its sections would intersect itself.
    if sections_cross(primitive):
        yield from _sections_union_solids(primitive, normalization, what)
        return
    scale = 1.0 if normalization is None else normalization.scale
    expected = closed_form_volume(primitive) * scale**3
    # The volume is almost always far inside the tolerance; should the interpolation
    # along t ever miss it, a finer one is tried before giving up.
    for share in (AXIS_TOLERANCE, AXIS_TOLERANCE / 16.0):
        solid = _sewn_solid(primitive, side_surface(primitive, share), normalization, what)
        try:
            check_solid(solid, expected, VOLUME_TOLERANCE, what, "its closed-form volume")
        except StepExportError as exc:
            failure = exc
            continue
        yield solid
        return
    # One smooth side that OpenCascade's checker still rejects (a squarish profile whose
    # scaling swells fast: its four patches sew with a fold at a corner): the solid is
    # lofted through slices instead, as for a sweep whose sections cross, each piece
    # checked the same way.
    try:
        yield from _sections_union_solids(primitive, normalization, what)
    except StepExportError:
        raise failure from None


def _sewn_solid(primitive: SweepPrimitive, surf: SideSurface,
                normalization: Normalization | None, what: str) -> Any:
    """The four side faces and two caps of a primitive sewn into a closed, outward solid."""
    from OCP.BRepBuilderAPI import BRepBuilderAPI_MakeSolid, BRepBuilderAPI_Sewing
    from OCP.ShapeFix import ShapeFix_Solid
    from OCP.TopAbs import TopAbs_SHELL
    from OCP.TopExp import TopExp_Explorer
    from OCP.TopoDS import TopoDS

    faces = [_bspline_face(surf.t_knots, k, transform_poles(p, normalization))
             for k, p in surf.patches]
    faces += [_cap_face(faces[:4], True), _cap_face(faces[:4], False)]
    scale = 1.0 if normalization is None else normalization.scale
    size = scale * float(np.ptp(primitive.control_points, axis=0).max()
                         + 2.0 * max(primitive.a, primitive.b))
    sewing = BRepBuilderAPI_Sewing(SEW_TOLERANCE * size)
    for face in faces:
        sewing.Add(face)
    sewing.Perform()
    explorer = TopExp_Explorer(sewing.SewedShape(), TopAbs_SHELL)
    if not explorer.More():
        raise StepExportError(f"{what}: its faces do not sew into a closed shell")
    fix = ShapeFix_Solid(BRepBuilderAPI_MakeSolid(TopoDS.Shell(explorer.Current())).Solid())
    fix.Perform()
    return fix.Solid()


# --------------------------------------------------------------------------- folding


def _sections_meet(primitive: SweepPrimitive, samples: int = 512) -> bool:
    """Whether the sweep may overlap itself where its axis comes back: two axis points
    further apart along the axis than π times the largest profile radius (closer ones
    cannot meet without a fold) lie closer than the sum of their radii (plus the gap
    between samples). Conservative: a sweep it passes does not overlap itself."""
    t = np.linspace(0.0, 1.0, samples)
    x, y = superellipse(np.linspace(0.0, 2.0 * np.pi, 256, endpoint=False),
                        primitive.profile[None])
    radius = scaling_factor(primitive.scaling_array, t)[0] * float(np.hypot(x, y).max())
    points = axis_points(primitive.control_points[None], t)[0]
    step = np.linalg.norm(np.diff(points, axis=0), axis=1)
    along = np.concatenate([[0.0], np.cumsum(step)])
    gap = float(step.max())
    i, j = np.triu_indices(samples, 1)
    far = along[j] - along[i] > np.pi * radius.max() + gap
    i, j = i[far], j[far]
    near = np.linalg.norm(points[i] - points[j], axis=1) < radius[i] + radius[j] + gap
    return bool(near.any())


def _sections_union_solids(primitive: SweepPrimitive, normalization: Normalization | None,
                           what: str) -> Iterator[Any]:
    """A primitive whose sections cross (it folds onto itself, or its axis comes back onto
    itself): its solid is the union of its sections, whose volume the closed form does not
    give, and a loft through the sections would overlap itself. It is lofted through
    slices of the true solid instead (_sliced_solids), and written only when that
    is within FOLD_VOLUME_TOLERANCE of a quasi-Monte Carlo estimate from the exact inside
    test (fold_volume) with two standard errors to spare: a tolerance widened by the
    estimate's own error let solids 1.1-1.6 % short through (BENCHMARKS.md, STEP export).
    Otherwise the primitive is refused by name. After the first, the other solids that
    pass (primitive_solids).

    Lofts through forward sections (the profile clamped short of the fold, as the solid
    mesher's forward tubes) kept the sweep's own faces, but OpenCascade's self-interference
    check (BRepAlgoAPI_Check) failed 19 of the 48 written, which broke unions; slices by
    parallel planes cannot cross, and build as many (BENCHMARKS.md, STEP export)."""
    scale3 = (1.0 if normalization is None else normalization.scale) ** 3
    # The estimate is needed only once the first rings are found: made meanwhile on the
    # other core (numpy lets go of the interpreter in the inside test's array work).
    with ThreadPoolExecutor(max_workers=1) as pool:
        estimated = pool.submit(fold_volume, primitive)

        def expected() -> tuple[float, float]:
            estimate, error = estimated.result()
            tolerance = FOLD_VOLUME_TOLERANCE - 2.0 * error / estimate
            if tolerance <= 0.0:
                raise StepExportError(
                    f"{what}: its sections cross, and its volume cannot be estimated "
                    "precisely enough to check a solid of it; export a mesh")
            return estimate * scale3, tolerance

        found = False
        for solid in _sliced_solids(primitive, normalization, what, expected):
            found = True
            yield solid
        if found:
            return
        expected()  # its error first, where no slicing gave rings
    how, advice = (("folds onto itself", "make it thinner or its bend wider")
                   if folds_onto_itself(primitive)
                   else ("comes back onto itself",
                         "move its control points apart where its axis comes back"))
    raise StepExportError(f"{what} {how} in a way STEP export cannot build as a correct "
                          "solid (no loft through slices of it is within 1% of "
                          f"its volume without crossing itself); export a mesh, or {advice}")


def _sliced_solids(primitive: SweepPrimitive, normalization: Normalization | None,
                   what: str, expected: Callable[[], tuple[float, float]]) -> Iterator[Any]:
    """The lofts through slices of the exact solid (geometry/slices.py) by families of
    planes that cut every slice in one star-shaped region, whose solids are valid, within
    the tolerance of the volume that expected() gives (-> volume, tolerance; asked for
    only once there are rings to loft) and do not cross themselves (geometry/loft.py's
    loft_verdict on the loft's samples, or where that cannot tell, OpenCascade's
    crosses_itself on the solid as read back from its STEP text, as_written), best
    first. Those that OpenCascade checked are yielded as read back, so a file need not
    check them for crossing again; those that loft_verdict vouches for as built (a write
    and read back less: 0.06 s of the 0.5 s of a folding primitive, BENCHMARKS.md, STEP
    export). Their surfaces interpolate the true boundary, so the fold's creases come out
    rounded by about a slice's spacing.

    The solid is sliced with its end stubs first (slices.end_stubs: straight
    continuations past the caps), and the loft's rings moved onto the caps' planes
    (slices.rings_on_caps), so that its caps are flat and their rims sharp: a loft that
    ends at the solid's extreme rounds the rims off, which put about half of the 64^3
    cells that sliced solids got wrong at their ends. Without stubs where that fails
    (in the order of _slicing_attempts)."""
    surface = surface_samples(primitive)
    stubs = end_stubs(primitive, surface)
    extended = np.concatenate([surface, *(stub.surface() for stub in stubs)])
    for planes, with_stubs in _slicing_attempts(slicing_families(primitive, surface),
                                                bool(stubs)):
        ends, samples = (stubs, extended) if with_stubs else ([], surface)
        for sliced in ring_candidates(primitive, planes, samples, ends):
            if ends:
                sliced = rings_on_caps(sliced, ends)
                if sliced is None:
                    break
            loft = ring_loft(sliced.rings, sliced.u, sliced.angles)
            # Whether it crosses itself, on its samples first; OpenCascade's check of the
            # solid (0.1-2.5 s) only where that cannot tell.
            verdict = loft_verdict(loft, planes)
            if verdict is LoftVerdict.CROSSES:
                continue
            volume, tolerance = expected()  # its error is the primitive's, not the loft's
            try:
                solid = _sewn_solid(primitive, loft, normalization, what)
                check_solid(solid, volume, tolerance, what,
                             "the quasi-Monte Carlo estimate of its sections' union")
                if verdict is LoftVerdict.UNKNOWN:
                    solid = as_written(solid, what)
                    if crosses_itself(solid):
                        continue
            except StepExportError:
                continue  # other centres, no stubs or another family may do
            yield solid


def _slicing_attempts(families: Iterator[SlicingPlanes], stubs: bool
                      ) -> Iterator[tuple[SlicingPlanes, bool]]:
    """The order in which _sliced_solids tries the families of planes, each with the end
    stubs (True) and without: with stubs over the first STUB_FAMILIES families before
    any without, then family by family. A loft without stubs rounds the rims of its
    caps off: taken as soon as the first family's stubs failed, it put camel.json's 1st
    primitive 101 of 4705 64^3 cells wrong, where the fifth family's with stubs put 16.
    Of the benchmark's 120 folding primitives, 3 move to stubs and 11 others take
    0.4-0.8 s longer to end with the same loft (BENCHMARKS.md, STEP export). Lazy: the
    later families (and the caps' pencil) are made only if they are reached."""
    if not stubs:
        for planes in families:
            yield planes, False
        return
    first = list(islice(families, STUB_FAMILIES))
    yield from ((planes, True) for planes in first)
    yield from ((planes, False) for planes in first)
    for planes in families:
        yield planes, True
        yield planes, False
