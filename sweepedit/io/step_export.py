"""STEP export: every primitive as an exact, smooth B-rep solid (OpenCascade, optional).

A primitive's side surface is four B-spline patches, one per quadrant of the profile
(geometry/side_surface.py): the profile's four tips are its corners and cusps when d <= 1,
kept sharp. Each patch becomes one face, the two ends flat caps; the six faces are sewn
into a solid.

Every solid is checked with OpenCascade's analyser and against its volume in closed form
(geometry/volumes.py: the profile's area times the integral of f(t)^2 |s'(t)|, exact when
nothing folds)
before anything is written; a union is checked against a Monte Carlo estimate from the
exact inside test. What is written is read back and checked again: each solid's volume,
and each primitive's solid for crossing itself (OpenCascade's self-interference check),
a union's for validity. A sweep whose sections cross (it folds onto itself: its profile
reaches past the axis' centre of curvature; or its axis comes back onto itself) would
loft into a self-intersecting solid that OpenCascade's checker passes. It is built as a
loft through slices of the true solid by planes that do not cross in it instead
(geometry/slices.py), written only when that is within 1% of a quasi-Monte Carlo
estimate of its true volume and OpenCascade's self-interference check passes it, and
otherwise refused with an error naming it (2 to 5 of the 122 to 127 folding primitives
of the official files and two sets of K = 8 fits of the 30 shapes; BENCHMARKS.md).

OpenCascade (the `cad` extra, package cadquery-ocp-novtk) is imported only when a STEP
file is made, so the rest of sweepedit works without it.
"""

from __future__ import annotations

import math
import tempfile
import time
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from functools import lru_cache
from itertools import islice
from pathlib import Path
from typing import Any, Literal

import numpy as np

from sweepedit.errors import SweepeditError
from sweepedit.geometry.loft import LoftVerdict, SideSurface, loft_verdict, ring_loft
from sweepedit.geometry.model import (
    Abstraction,
    Normalization,
    SweepPrimitive,
    folds_onto_itself,
)
from sweepedit.geometry.side_surface import AXIS_TOLERANCE, side_surface
from sweepedit.geometry.slices import (
    SlicingPlanes,
    end_stubs,
    ring_candidates,
    rings_on_caps,
    slicing_families,
    surface_samples,
)
from sweepedit.geometry.sweep import (
    axis_points,
    scaling_factor,
    superellipse,
)
from sweepedit.geometry.volumes import (
    UnionVolumes,
    closed_form_volume,
    fold_volume,
    union_bounds,
)
from sweepedit.io.params import atomic_write_bytes, require_folder
from sweepedit.io.step_workers import build_all

STEP_FORMATS = (".step", ".stp")
CAD_MISSING = "STEP export needs the optional 'cad' extra: pip install 'sweepedit[cad]'"

# Relative precision asked of OpenCascade's adaptive volume integration. Its results
# come within 1e-4 of a 1e-9 integration on folding solids (2e-6 on the others and on
# a union of 7), far inside every check's tolerance, at a tenth to a half of 1e-6's time
# (a folding primitive's solid: 7-10 ms, against 30-127 ms; femur.json's union 0.39 s
# against 0.91 s; BENCHMARKS.md, STEP export).
VOLUME_PRECISION = 1e-3
# A solid's volume must match the closed form this closely (relative).
VOLUME_TOLERANCE = 1e-3
# The union's volume must match the quasi-Monte Carlo estimate (geometry.volumes.
# union_volume: 8 scrambled Sobol sets of 2^15 points) this closely (relative), besides how
# far its solids' own volumes are from their primitives', or by UNION_SIGMAS standard
# errors of the estimate where that is larger. At 1 %, with plain Monte Carlo's 0.5 % error
# taking it to 2 %, fuzzy fuses that dropped 0.7 % of glyph_8.json's union passed (IoU
# 0.9907, under the 0.995 wanted; BENCHMARKS.md, STEP export).
UNION_TOLERANCE = 0.005
UNION_SIGMAS = 4.0
# Sweeps whose sections cross: how close their solid's volume must be to the estimate
# (geometry.volumes.fold_volume).
FOLD_VOLUME_TOLERANCE = 0.01
# How many families of slicing planes are tried with end stubs before any without.
STUB_FAMILIES = 5
# How many other solids of a primitive whose sections cross (primitive_solids) are tried
# in turn when no fuse of a union passes its check: glyph_8.json's K = 8 fit fuses right
# only with its 5th primitive's second other solid (BENCHMARKS.md, STEP export).
OTHER_SOLIDS = 2
# Fuzzy values tried when a union's fuse fails its check, relative to its size.
FUZZY_FUSE_SHARES = (1e-5, 1e-4)
# The last resort when no fuse passes the check: every solid moved this far (relative to
# the union's size) in its own fixed direction, then fused all at once. OpenCascade's
# fuse fails on some exact configurations (hammer.json's: a valid solid 91 % short,
# however fused) and not on one a hair away; the moved union is checked the same way.
NUDGE_SHARE = 1e-4
# Points per primitive that left_out classifies against a fuse that failed its check.
LEFT_OUT_POINTS = 8
# Largest change of a union's edge curves when they are re-approximated with fewer
# poles (simplify_edge_curves), relative to the union's size.
EDGE_CURVE_TOLERANCE = 1e-6
# A solid read back from the file written must have the volume checked in memory this
# closely (relative): what it catches is gross (a solid inside out, -100 %; a face
# rebuilt wrong, -1.8 %, when the edges' curves on the faces were left out of the file),
# while a union's re-approximated edge curves move the re-read volume by up to ~1e-6,
# and two integrations at VOLUME_PRECISION may differ by up to ~2e-4.
READ_BACK_TOLERANCE = 1e-3
# Decimals of the coordinates, knots and parameters written (|x| in [0.1, 1e7]; smaller
# ones get 9 significant digits): within 5e-9, 20 times under OpenCascade's confusion
# distance (1e-7). OpenCascade's writer prints 13 significant digits; 8 decimals make the
# file 12-16 % smaller. Where a file so written does not read back as checked (knots
# closer than that would merge), it is written again with OpenCascade's 13 digits.
STEP_DECIMALS = 8
STEP_DECIMALS_RANGE = (0.1, 1e7)
# A file larger than this per primitive is written without the edges' curves on their
# faces (pcurves: 2D B-splines that a reader can compute from the 3D curves and the
# faces, 40 % of a large union's poles) where it reads back as checked that way; a
# file within it keeps them. Unions of glyph_8.json, hand.txt, femur.json: 330 -> 193-207
# kB per primitive (BENCHMARKS.md, STEP export).
STEP_BYTES_PER_PRIMITIVE = 250_000
# Sewing tolerance, relative to the solid's size: neighbouring faces share their edge
# curves exactly, so this only absorbs rounding.
SEW_TOLERANCE = 1e-7
# A curve along which a face meets itself is a crossing only where its two points on the
# face lie apart on it: further than this (relative to the face's size) along the
# straight path between them in its parameters, sampled at SAME_POINT_STEPS steps.
# OpenCascade's check also reports "curves" whose two points on the face are one
# (camel.json's 4th: 3e-6 long, its points 1e-9 apart on the face; a real crossing's are
# as far apart as the sheets that meet).
SAME_POINT_SHARE = 1e-6
SAME_POINT_STEPS = 8

Progress = Callable[[float, str], None]
# What a solid read back from its file is checked for besides its volume (_read_back_checked).
ReadBackCheck = Literal["validity", "crossing"]
Cancelled = Callable[[], bool]


class CadUnavailableError(SweepeditError):
    """OpenCascade (the optional `cad` extra) is not installed."""

    def __init__(self) -> None:
        super().__init__(CAD_MISSING)


class StepExportError(SweepeditError):
    """A primitive or union that cannot be written as a correct solid."""


class ExportCancelledError(SweepeditError):
    """The user cancelled a STEP export; nothing was written."""

    def __init__(self) -> None:
        super().__init__("STEP export cancelled; nothing was written")


def is_step_path(path: str | Path) -> bool:
    """True when `path` names a STEP file (.step or .stp, any case)."""
    return Path(path).suffix.lower() in STEP_FORMATS


def _occ() -> Any:
    """The OCP package, or CadUnavailableError with the line that says how to install it."""
    try:
        import OCP
        from OCP.Message import Message, Message_Gravity
    except ImportError:
        raise CadUnavailableError() from None
    # OpenCascade's translators print statistics to stdout; only failures are wanted.
    for printer in Message.DefaultMessenger_s().Printers():
        printer.SetTraceLevel(Message_Gravity.Message_Fail)
    return OCP


# --------------------------------------------------------------------------- B-rep


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


def _transform_poles(poles: np.ndarray, normalization: Normalization | None) -> np.ndarray:
    return poles if normalization is None else normalization.to_original(poles)


def _describe(index: int, primitive: SweepPrimitive) -> str:
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
    _occ()
    what = _describe(index, primitive)
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
            _check_solid(solid, expected, VOLUME_TOLERANCE, what, "its closed-form volume")
        except StepExportError:
            if share != AXIS_TOLERANCE:
                raise
            continue
        yield solid
        return


def _sewn_solid(primitive: SweepPrimitive, surf: SideSurface,
                normalization: Normalization | None, what: str) -> Any:
    """The four side faces and two caps of a primitive sewn into a closed, outward solid."""
    from OCP.BRepBuilderAPI import BRepBuilderAPI_MakeSolid, BRepBuilderAPI_Sewing
    from OCP.ShapeFix import ShapeFix_Solid
    from OCP.TopAbs import TopAbs_SHELL
    from OCP.TopExp import TopExp_Explorer
    from OCP.TopoDS import TopoDS

    faces = [_bspline_face(surf.t_knots, k, _transform_poles(p, normalization))
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
    crosses_itself on the solid as read back from its STEP text, _as_written), best
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
                _check_solid(solid, volume, tolerance, what,
                             "the quasi-Monte Carlo estimate of its sections' union")
                if verdict is LoftVerdict.UNKNOWN:
                    solid = _as_written(solid, what)
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


def _exact_volume(primitive: SweepPrimitive) -> float:
    """A primitive's volume in the normalised frame: in closed form, or for one whose
    sections cross, fold_volume's estimate."""
    if sections_cross(primitive):
        return fold_volume(primitive)[0]
    return closed_form_volume(primitive)


@lru_cache(maxsize=8)
def solid_volume(shape: Any, precision: float = VOLUME_PRECISION) -> float:
    """The volume enclosed by an OpenCascade shape, integrated to the relative
    `precision`. Remembered for the last few shape objects (shapes are not changed in
    place here): a solid's check and the comparison with its re-read copy ask for it
    twice, at 0.02-1 s each."""
    from OCP.BRepGProp import BRepGProp
    from OCP.GProp import GProp_GProps

    props = GProp_GProps()
    # The adaptive integration: the default fixed-order one is off by 0.1% on these faces.
    BRepGProp.VolumeProperties_s(shape, props, precision)
    return float(props.Mass())


def is_valid(shape: Any, parallel: bool = False) -> bool:
    """OpenCascade's checker on `shape`; `parallel` on its thread pool, for a large shape
    (a union of 8: 0.115 -> 0.075 s on two cores)."""
    from OCP.BRepCheck import BRepCheck_Analyzer

    return BRepCheck_Analyzer(shape, True, parallel).IsValid()


def _check_solid(shape: Any, expected: float, tolerance: float, what: str,
                 truth: str, parallel: bool = False) -> None:
    if not is_valid(shape, parallel):
        raise StepExportError(f"{what}: OpenCascade's checker finds the solid invalid")
    volume = solid_volume(shape)
    if not abs(volume / expected - 1.0) <= tolerance:
        raise StepExportError(f"{what}: the solid's volume {volume:.6g} is "
                              f"{100.0 * (volume / expected - 1.0):+.3f}% off {truth} "
                              f"{expected:.6g}; not written")


def _as_written(solid: Any, what: str) -> Any:
    """The solid as read back from the STEP text export_step writes of it (with
    STEP_DECIMALS decimals): a folding solid is checked for crossing itself once, as it
    will be read, where checking it in memory and again read back from the file cost
    0.5 s of the 1.1 s median of a folding primitive (BENCHMARKS.md, STEP export). The
    rounding can tip a contact within OpenCascade's tolerance into a crossing (bone.json's
    6th), and written again the read-back solid has the same surfaces and edges to the
    last digit (only its caps' planes and their edges' curves on them move, by 1e-10).
    Turned right way out where it reads back inside out (see _read_back_checked)."""
    from OCP.TopoDS import TopoDS

    with tempfile.TemporaryDirectory(prefix="sweepedit-step-") as folder:
        tmp = Path(folder) / "solid.step"
        _write_step([(solid, "solid", "#000000")], tmp, tmp, STEP_DECIMALS)
        read = read_step(tmp)
    expected = solid_volume(solid)
    volume = solid_volume(read[0].shape) if len(read) == 1 else 0.0
    if not abs(abs(volume) - expected) <= READ_BACK_TOLERANCE * abs(expected):
        raise StepExportError(f"{what}: its solid reads back from STEP text with another "
                              "volume; not written")
    shape = read[0].shape if volume > 0.0 else read[0].shape.Reversed()
    return TopoDS.Solid(shape)


def crosses_itself(shape: Any) -> bool:
    """Whether OpenCascade's check for boolean operations finds faces of `shape` that
    cross each other or themselves. A loft through slices can cross itself by a sliver
    where its cubics bend sharply (near a fold's crease or an end), which the volume
    check passes, BRepCheck_Analyzer does not look for, and a CAD tool's booleans trip
    on: 10 of 125 folding solids did (BENCHMARKS.md, STEP export). 0.3-1 s for a
    folding solid, on both cores. A face that the check finds meeting itself crosses
    itself only where the two points of a meeting lie apart on it (_face_meets_itself):
    at a loft's short end edge the check also finds "curves" whose two points on the face
    are one (camel.json's 4th, glyph_G.json's 6th)."""
    return any(is_crossing(result) for result in self_interference(shape))


def self_interference(shape: Any) -> list[Any]:
    """What OpenCascade's check for boolean operations finds where the shape meets
    itself: its BRepAlgoAPI_Check results, none when it finds nothing. These are raw
    alarms; is_crossing judges each (crosses_itself, both)."""
    from OCP.BRepAlgoAPI import BRepAlgoAPI_Check

    check = BRepAlgoAPI_Check()
    check.SetData(shape, False, True)  # self-interference only, not the small-edge test
    check.SetRunParallel(True)
    check.Perform()
    return [] if check.IsValid() else list(check.Result())


def is_crossing(result: Any) -> bool:
    """Whether a result of self_interference is a crossing: anything but one face
    meeting itself only at points that are one point of it (_face_meets_itself)."""
    face = _face_alone(result)
    return face is None or _face_meets_itself(face)


def _face_alone(result: Any) -> Any | None:
    """The face of a BRepAlgoAPI_Check result that reports one face meeting itself (its
    check intersects each B-spline face with itself), else None: a crossing of two
    sub-shapes, or anything else the check found."""
    from OCP.BOPAlgo import BOPAlgo_CheckStatus
    from OCP.TopAbs import TopAbs_FACE
    from OCP.TopoDS import TopoDS

    faulty = [*result.GetFaultyShapes1(), *result.GetFaultyShapes2()]
    if (result.GetCheckStatus() != BOPAlgo_CheckStatus.BOPAlgo_SelfIntersect or not faulty
            or faulty[0].ShapeType() != TopAbs_FACE
            or not all(s.IsSame(faulty[0]) for s in faulty)):
        return None
    return TopoDS.Face(faulty[0])


def _face_meets_itself(face: Any, samples: int = 9) -> bool:
    """Whether a face meets itself at two points that lie apart on it (SAME_POINT_SHARE):
    OpenCascade's intersection of the face with itself (as its check runs it), each
    curve found followed at `samples` points and each point found, with their parameters
    on both copies of the face. Where the intersection fails, True (cannot vouch)."""
    from OCP.Bnd import Bnd_Box
    from OCP.BRep import BRep_Tool
    from OCP.BRepBndLib import BRepBndLib
    from OCP.IntTools import IntTools_FaceFace

    meet = IntTools_FaceFace()
    meet.SetParameters(True, True, True, SEW_TOLERANCE)  # with its curves on both copies
    meet.Perform(face, face, False)
    if not meet.IsDone():
        return True
    surface = BRep_Tool.Surface_s(face)
    box = Bnd_Box()
    BRepBndLib.Add_s(face, box)
    apart = SAME_POINT_SHARE * math.sqrt(box.SquareExtent())

    def path(uv1: tuple[float, float], uv2: tuple[float, float]) -> float:
        steps = np.linspace(0.0, 1.0, SAME_POINT_STEPS + 1)[:, None]
        uv = (1.0 - steps) * np.asarray(uv1) + steps * np.asarray(uv2)
        points = np.array([surface.Value(u, v).Coord() for u, v in uv])
        return float(np.linalg.norm(np.diff(points, axis=0), axis=1).sum())

    pairs: list[tuple[tuple[float, float], tuple[float, float]]] = []
    for curve in meet.Lines():
        on1, on2 = curve.FirstCurve2d(), curve.SecondCurve2d()
        if on1 is None or on2 is None:
            return True
        first, last = curve.Curve().FirstParameter(), curve.Curve().LastParameter()
        if not (math.isfinite(first) and math.isfinite(last)):
            return True
        for t in np.linspace(first, last, samples):
            pairs.append((on1.Value(t).Coord(), on2.Value(t).Coord()))
    for point in meet.Points():
        pairs.append((point.P1().Parameters(), point.P2().Parameters()))
    return any(path(uv1, uv2) > apart for uv1, uv2 in pairs)


# --------------------------------------------------------------------------- union


def fuse_solids(solids: Sequence[Any], fuzzy: float = 0.0) -> Any:
    """The boolean union of OpenCascade solids (one solid, or a compound of disjoint ones);
    with `fuzzy` > 0, faces within that distance are taken as touching."""
    from OCP.BRepAlgoAPI import BRepAlgoAPI_Fuse
    from OCP.collections import List_TopoDS_Shape

    if len(solids) == 1:
        return solids[0]
    args, tools = List_TopoDS_Shape(), List_TopoDS_Shape()
    args.Append(solids[0])
    for s in solids[1:]:
        tools.Append(s)
    fuse = BRepAlgoAPI_Fuse()
    fuse.SetArguments(args)
    fuse.SetTools(tools)
    # Oriented boxes prune the pairs of faces to intersect; threads share the rest.
    fuse.SetUseOBB(True)
    fuse.SetRunParallel(True)
    if fuzzy > 0.0:
        fuse.SetFuzzyValue(fuzzy)
    fuse.Build()
    if not fuse.IsDone():
        raise StepExportError("OpenCascade could not fuse the primitives into one solid")
    fuse.SimplifyResult()
    return fuse.Shape()


def simplify_edge_curves(shape: Any) -> Any:
    """`shape` with its B-spline edge curves re-approximated with fewer poles (degree
    <= 5, <= 32 spans) to EDGE_CURVE_TOLERANCE of its size, and the curves on the faces of
    the edges changed projected anew from them; its surfaces untouched. Not checked: the
    caller checks the result and keeps `shape` where it is not valid. The fuse
    approximates its intersection curves to 1e-7 with hundreds of poles each, and their
    curves on the faces as many: most of a union's STEP file (BENCHMARKS.md, STEP
    export). Projecting the curves on the faces anew, rather than re-approximating them
    too, keeps more unions valid and makes them 10-35 % smaller."""
    from OCP.Bnd import Bnd_Box
    from OCP.BRepBndLib import BRepBndLib
    from OCP.BRepLib import BRepLib
    from OCP.BRepTools import BRepTools_Modifier
    from OCP.collections import DataMap_TopoDS_Shape_TopoDS_Shape_TopTools_ShapeMapHasher
    from OCP.GeomAbs import GeomAbs_C1
    from OCP.ShapeAnalysis import ShapeAnalysis_Edge
    from OCP.ShapeCustom import ShapeCustom, ShapeCustom_BSplineRestriction
    from OCP.ShapeFix import ShapeFix_Edge
    from OCP.TopAbs import TopAbs_EDGE, TopAbs_FACE
    from OCP.TopExp import TopExp_Explorer
    from OCP.TopoDS import TopoDS

    box = Bnd_Box()
    BRepBndLib.Add_s(shape, box)
    tolerance = EDGE_CURVE_TOLERANCE * math.sqrt(box.SquareExtent())
    # Surfaces no, 3D curves yes, their curves on the faces no (they are dropped where the
    # 3D curve changed); segments before degree; polynomial.
    restriction = ShapeCustom_BSplineRestriction(
        False, True, False, tolerance, tolerance, GeomAbs_C1, GeomAbs_C1, 5, 32, False, True)
    simplified = ShapeCustom.ApplyModifier_s(
        shape, restriction, DataMap_TopoDS_Shape_TopoDS_Shape_TopTools_ShapeMapHasher(),
        BRepTools_Modifier())
    has_curve, add_curve = ShapeAnalysis_Edge(), ShapeFix_Edge()
    faces = TopExp_Explorer(simplified, TopAbs_FACE)
    while faces.More():
        face = TopoDS.Face(faces.Current())
        edges, explorer = [], TopExp_Explorer(face, TopAbs_EDGE)
        while explorer.More():
            edges.append(TopoDS.Edge(explorer.Current()))
            explorer.Next()
        for edge in edges:
            if not has_curve.HasPCurve(edge, face):
                # A seam (a closed face's edge, in its wire twice) gets both its curves.
                seam = sum(edge.IsSame(other) for other in edges) > 1
                add_curve.FixAddPCurve(edge, face, seam, tolerance)
        faces.Next()
    # The curves' parameters and the edges' tolerances follow the new curves.
    BRepLib.SameParameter_s(simplified, 10.0 * tolerance, True)
    BRepLib.UpdateTolerances_s(simplified, False)
    return simplified


def nudged(solids: Sequence[Any], distance: float, seed: int = 0) -> list[Any]:
    """Copies of OpenCascade solids, each moved by `distance` in its own direction
    (pseudo-random, the same for the same seed)."""
    from OCP.BRepBuilderAPI import BRepBuilderAPI_Transform
    from OCP.gp import gp_Trsf, gp_Vec

    rng = np.random.default_rng(seed)
    moved = []
    for solid in solids:
        direction = rng.normal(size=3)
        move = gp_Trsf()
        move.SetTranslation(gp_Vec(*(distance * direction / np.linalg.norm(direction))))
        moved.append(BRepBuilderAPI_Transform(solid, move, True).Shape())
    return moved


def left_out(fused: Any, volumes: UnionVolumes, normalization: Normalization | None,
             size: float) -> list[int]:
    """The primitives (indices) that a fuse `fused` of all of `volumes`' primitives left
    out: most of up to LEFT_OUT_POINTS points inside one primitive and no other are
    outside `fused` by OpenCascade's classifier (~10 ms a point on these faces; a
    primitive is decided as soon as a majority of its points is). `size` is the union's
    (its box's diagonal), for the classifier's tolerance."""
    from OCP.BRepClass3d import BRepClass3d_SolidClassifier
    from OCP.gp import gp_Pnt
    from OCP.TopAbs import TopAbs_OUT

    classifier = BRepClass3d_SolidClassifier(fused)
    dropped = []
    for k in range(volumes.count):
        points = _transform_poles(volumes.only_inside(k, LEFT_OUT_POINTS), normalization)
        outside = 0
        for n, point in enumerate(points):
            classifier.Perform(gp_Pnt(*(float(x) for x in point)), 1e-7 * size)
            outside += classifier.State() == TopAbs_OUT
            if 2 * outside > len(points) or 2 * (n + 1 - outside) >= len(points):
                break
        if 2 * outside > len(points):
            dropped.append(k)
    return dropped


def fuse_one_at_a_time(solids: Sequence[Any]) -> Any:
    """The boolean union of OpenCascade solids, fused one at a time, the largest first."""
    order = _largest_first(solids)
    fused = solids[order[0]]
    for k in order[1:]:
        fused = fuse_solids([fused, solids[k]])
    return fused



def _union_tolerance(solids: Sequence[Any], primitives: Sequence[SweepPrimitive],
                     estimate: float, error: float, scale3: float) -> float:
    """How far a fuse of `solids` may be off the estimate (-> share) of its primitives'
    union (estimate ± error, normalised frame): it can differ from the exact union by as
    much as its solids differ from their primitives (a folding one's loft by up to 1 %),
    no more, and the estimate is not closer than UNION_SIGMAS of its standard errors."""
    off = sum(abs(solid_volume(s) / scale3 - _exact_volume(p))
              for s, p in zip(solids, primitives, strict=True))
    return max(UNION_TOLERANCE + off / estimate, UNION_SIGMAS * error / estimate)


class _OtherSolids:
    """The other solids of each primitive (primitive_solids' after the first), found
    only when asked for and kept, so that a second search goes on from the first."""

    def __init__(self, builds: Sequence[Iterator[Any]]) -> None:
        self._builds = builds
        self._found: list[list[Any]] = [[] for _ in builds]

    def get(self, k: int, n: int) -> Any | None:
        """The n-th (from 0) other solid of the k-th primitive, or None."""
        while len(self._found[k]) <= n:
            other = next(self._builds[k], None)
            if other is None:
                return None
            self._found[k].append(other)
        return self._found[k][n]


def _union_bytes(solids: list[Any], primitives: list[SweepPrimitive], names: list[str],
                 builds: Sequence[Iterator[Any]], seconds: Sequence[float], path: Path,
                 normalization: Normalization | None, volumes: UnionVolumes,
                 say: Callable[[str], None]) -> bytes:
    """The STEP bytes of one solid fusing `solids` (of `primitives`, named `names` in
    messages, in the frame of `normalization`), checked against the exact inside test's
    estimate of the union (`volumes`, of `primitives`) and read back. say(text) names
    each attempt (and raises to cancel); `builds` give the other solids of primitives
    whose sections cross (primitive_solids), `seconds` how long each took to build. The
    first failure's StepExportError where no attempt passes.

    OpenCascade's fuse of all at once (largest first, _largest_first) sometimes drops
    material or comes out invalid (2 of the benchmark's 51 unions on 12-06: hand2.txt,
    glyph_8.json; up to 7 with earlier solids). Then the solids are fused one at a time,
    the largest first, each partial union checked against its own estimate, so that a step
    that goes wrong is known and retried alone: fuzzy (faces that close taken as
    touching: hand.json), nudged (moved a hair apart: bone, fertility, hammer), or with
    the new primitive sliced another way (glyph_8.json's 5th). Where that fails too, the
    earlier whole-union attempts follow (BENCHMARKS.md, STEP export)."""
    scale3 = (normalization.scale if normalization else 1.0) ** 3
    lo, hi = union_bounds(primitives)
    size = float(np.linalg.norm(hi - lo)) * (normalization.scale if normalization else 1.0)
    others = _OtherSolids(builds)
    estimate, error = volumes.volume(range(len(primitives)))
    tolerance = _union_tolerance(solids, primitives, estimate, error, scale3)

    def written(union: Any, volume: float) -> bytes:
        # A union read back is checked by OpenCascade's checker too: one fused with
        # its solids nudged came back invalid from a file once (bone.json).
        return _step_bytes([(union, path.stem, primitives[0].color)], path,
                           checks=["validity"],
                           budget=STEP_BYTES_PER_PRIMITIVE * len(primitives),
                           volumes=[volume])

    def checked(fused: Any) -> bytes:
        # The fuse's volume is checked, and the same with edge curves of fewer poles
        # only as read back against it: with those curves the volume takes twice as
        # long to integrate (glyph_8.json: 0.47 s against 0.22 s), and a fuse that
        # went wrong is known before they are made (BENCHMARKS.md, STEP export).
        _check_solid(fused, estimate * scale3, tolerance, "the union",
                     "the exact inside test's quasi-Monte Carlo estimate", parallel=True)
        volume = solid_volume(fused)
        simplified = simplify_edge_curves(fused)
        if is_valid(simplified, parallel=True):
            try:
                return written(simplified, volume)
            except StepExportError:
                pass
        return written(fused, volume)  # the fewer poles rebuilt a face wrong

    def first_passing(tried: list[tuple[str, Callable[[], Any]]]) -> bytes:
        for k, (text, attempt) in enumerate(tried):
            say(text)
            try:
                return checked(attempt())
            except StepExportError:
                if k == len(tried) - 1:
                    raise
        raise AssertionError("unreachable")

    order = _largest_first(solids)
    say("fusing the solids")
    fused = None
    try:
        fused = fuse_solids([solids[k] for k in order])
        return checked(fused)
    except StepExportError as failure:
        first_failure = failure
    # A fuse of all at once may leave a whole solid out (hand2.txt's 1st, 9.1 % short,
    # in any order): fusing it back costs one fuse, where one at a time costs one a
    # solid, each checked (hand2.txt: 0.6 s against 3.2 s; BENCHMARKS.md, STEP export).
    dropped = [] if fused is None else left_out(fused, volumes, normalization, size)
    if dropped:
        say("fusing back the solids left out: " + ", ".join(names[k] for k in dropped))
        try:
            return checked(fuse_solids([fused, *(solids[k] for k in dropped)]))
        except StepExportError:
            pass
    try:
        return checked(_fused_stepwise(solids, order, primitives, names, others, volumes,
                                       scale3, size, say))
    except StepExportError:
        pass
    # Where no step passes, one sliced solid may meet an earlier one in a way the fuse
    # gets wrong however the solids lie (hand.txt: its 1st and 7th, 37 % short as a
    # pair): the whole union fuzzy and nudged, then with each such primitive sliced
    # another way, the slowest to build first (its first slicings failed: a hard fold,
    # whose loft is the likeliest to trip the fuse).
    tried = [(f"fusing the solids, faces within {share:g} of their size touching",
              lambda share=share: fuse_solids(solids, share * size))
             for share in FUZZY_FUSE_SHARES]
    tried.append((f"fusing the solids, each moved by {NUDGE_SHARE:g} of their size",
                  lambda: fuse_solids(nudged(solids, NUDGE_SHARE * size))))
    for k in np.argsort(seconds)[::-1]:
        if not sections_cross(primitives[k]):
            continue
        for n in range(OTHER_SOLIDS):
            def replaced(k: int = k, n: int = n) -> list[Any]:
                other = others.get(k, n)
                if other is None:
                    raise StepExportError(f"{names[k]}: no other solid")
                return [*solids[:k], other, *solids[k + 1:]]

            tried += [(f"fusing the solids, {names[k]} sliced another way",
                       lambda replaced=replaced: fuse_solids(replaced())),
                      (f"fusing the solids one at a time, {names[k]} sliced another way",
                       lambda replaced=replaced: fuse_one_at_a_time(replaced()))]
    try:
        return first_passing(tried)
    except StepExportError:
        raise first_failure from None


def _largest_first(solids: Sequence[Any]) -> list[int]:
    """The indices of `solids` by volume, the largest first: the order both fuses take
    them in. OpenCascade's fuse of all at once depends on it: octopus.json's K = 8 fit
    came out 59 % short in the primitives' order and right (+0.27 %) largest first,
    where the 50 other unions of the benchmark came out the same either way
    (BENCHMARKS.md, STEP export)."""
    return sorted(range(len(solids)), key=lambda k: solid_volume(solids[k]), reverse=True)


def _fused_stepwise(solids: list[Any], order: list[int], primitives: list[SweepPrimitive],
                    names: list[str], others: _OtherSolids, volumes: UnionVolumes,
                    scale3: float, size: float, say: Callable[[str], None]) -> Any:
    """The solids fused one at a time in `order` (_largest_first), each partial union checked
    (valid, its volume within _union_tolerance of the estimate of its primitives'
    union) before the next is added. A step that fails is tried again fuzzy, nudged
    and with the new primitive's other solids; StepExportError names the primitive
    where none passes. Costs a check a step (0.1-0.7 s) over fuse_one_at_a_time."""
    fused, used = solids[order[0]], {order[0]: solids[order[0]]}
    for k in order[1:]:
        what = names[k]
        members = [*used, k]
        estimate, error = volumes.volume(members)

        def tries(fused: Any = fused, k: int = k) -> Iterator[tuple[str, Any, Any]]:
            yield "", solids[k], lambda: fuse_solids([fused, solids[k]])
            # The coarser share first: where two solids' fuse fails, it is the one that
            # passes (glyph_8.json: 15.8 -> 13.3 s, the same solid).
            for share in sorted(FUZZY_FUSE_SHARES, reverse=True):
                yield (f", faces within {share:g} of their size touching", solids[k],
                       lambda share=share: fuse_solids([fused, solids[k]], share * size))
            yield (f", moved by {NUDGE_SHARE:g} of their size", solids[k],
                   lambda: fuse_solids(nudged([fused, solids[k]], NUDGE_SHARE * size)))
            if sections_cross(primitives[k]):
                for n in range(OTHER_SOLIDS):
                    other = others.get(k, n)
                    if other is None:
                        break
                    yield ", sliced another way", other, lambda other=other: fuse_solids(
                        [fused, other])

        for how, solid, fuse in tries():
            say(f"fusing the solids one at a time: {what}{how}")
            tolerance = _union_tolerance([*(used[j] for j in members[:-1]), solid],
                                         [primitives[j] for j in members],
                                         estimate, error, scale3)
            try:
                candidate = fuse()
                _check_solid(candidate, estimate * scale3, tolerance, "the union",
                             f"the exact inside test's estimate with {what} added")
            except StepExportError:
                continue
            fused, used[k] = candidate, solid
            break
        else:
            raise StepExportError(f"the union: no fuse of {what} with the larger ones "
                                  "passes its check")
    return fused

# --------------------------------------------------------------------------- writing


def _color(hex_color: str) -> Any:
    from OCP.Quantity import Quantity_Color, Quantity_TOC_sRGB

    rgb = [int(hex_color[i:i + 2], 16) / 255.0 for i in (1, 3, 5)]
    return Quantity_Color(*rgb, Quantity_TOC_sRGB)


def _step_bytes(parts: Sequence[tuple[Any, str, str]], path: Path,
                checks: Sequence[ReadBackCheck], budget: int | None = None,
                volumes: Sequence[float] | None = None) -> bytes:
    """Shapes with names and colours [(shape, name, '#rrggbb')] as the bytes of an AP214
    STEP file that reads back as checked (_read_back_checked), with STEP_DECIMALS
    decimals, or with OpenCascade's own 13 digits where that file reads back with other
    solids or volumes, or solids that cross themselves (the rounding could be why; an
    invalid solid of the right volume reads back invalid at 13 digits too, and is not
    written again). A file over `budget`
    bytes is written without the edges' curves on their faces where it reads back as
    checked that way (_checked_bytes). `checks`: what each part is checked for on reading
    back; `volumes`: the volume each must read back with, by default its own. `path` is
    the file meant, for messages."""
    parts = list(parts)
    checks = list(checks)
    expected = [solid_volume(shape) for shape, _, _ in parts] if volumes is None \
        else list(volumes)
    if not len(checks) == len(expected) == len(parts):
        raise ValueError(f"{len(checks)} read-back checks and {len(expected)} volumes "
                         f"for {len(parts)} solids")
    with tempfile.TemporaryDirectory(prefix="sweepedit-step-") as folder:
        tmp = Path(folder) / "export.step"
        if budget is not None:
            # Writing is cheap (0.2 s for a union of 8), reading back and checking is not:
            # the size is looked at first, and only one file is read back where it can.
            _write_step(parts, tmp, path, STEP_DECIMALS)
            if tmp.stat().st_size <= budget:  # read that file back, not another copy
                return _checked_bytes(parts, tmp, path, checks, expected,
                                      face_curves=True, written=True)
            try:
                return _checked_bytes(parts, tmp, path, checks, expected,
                                      face_curves=False)
            except StepExportError:
                pass  # read back otherwise than checked: the file with the curves
        return _checked_bytes(parts, tmp, path, checks, expected, face_curves=True)


def _checked_bytes(parts: list[tuple[Any, str, str]], tmp: Path, path: Path,
                   checks: list[ReadBackCheck], expected: list[float], face_curves: bool,
                   written: bool = False) -> bytes:
    """_read_back_checked with STEP_DECIMALS decimals, else with all digits (see
    _step_bytes). `written`: tmp already holds `parts` written with STEP_DECIMALS
    decimals and these face_curves."""
    try:
        return _read_back_checked(parts, tmp, path, STEP_DECIMALS, checks, expected,
                                  face_curves, written)
    except _InvalidOnReadingError:
        raise  # not the rounding: the same at 13 digits (bone.json's unions)
    except StepExportError:
        return _read_back_checked(parts, tmp, path, None, checks, expected, face_curves)


class _InvalidOnReadingError(StepExportError):
    """A solid read back from its file with the volume checked, but invalid."""


def _read_back_checked(parts: list[tuple[Any, str, str]], tmp: Path, path: Path,
                       decimals: int | None, checks: list[ReadBackCheck],
                       expected: list[float], face_curves: bool = True,
                       written: bool = False) -> bytes:
    """The bytes of `parts` written as STEP (at tmp, by _write_step, unless `written`
    says tmp holds them so already), read back and each solid's volume compared with
    `expected` (the one checked in memory), and each solid whose entry of `checks` says "validity"
    checked by OpenCascade's checker, "crossing" by its self-interference check
    (crosses_itself: a solid that passes it in memory can cross itself within
    OpenCascade's tolerance once its numbers are rounded; 2 of 327 did at 8 decimals,
    BENCHMARKS.md, STEP export). OpenCascade's writer turns a few sewn solids inside out (the
    same volume, negated, on reading; seen on 1 of 378 primitives): such a solid is
    written reversed instead (in `parts`); anything else that differs is an error, not a
    file."""
    from OCP.TopoDS import TopoDS

    for attempt in range(2):
        if attempt or not written:
            _write_step(parts, tmp, path, decimals, face_curves)
        read = read_step(tmp)
        if len(read) != len(parts):
            raise StepExportError(f"{path}: {len(read)} solids read back from the "
                                  f"STEP file written, not {len(parts)}; not written")
        volumes = [solid_volume(r.shape) for r in read]
        flipped = [i for i, (v, e) in enumerate(zip(volumes, expected, strict=True))
                   if abs(v + e) <= READ_BACK_TOLERANCE * abs(e)]
        wrong = [parts[i][1] for i, (v, e) in enumerate(zip(volumes, expected, strict=True))
                 if i not in flipped and not abs(v - e) <= READ_BACK_TOLERANCE * abs(e)]
        if wrong:
            raise StepExportError(f"{path}: {', '.join(wrong)} read back from the STEP "
                                  "file with another volume than was checked; not written")
        invalid = [parts[i][1] for i, (r, check) in enumerate(zip(read, checks, strict=True))
                   if check == "validity" and not is_valid(r.shape, parallel=True)]
        if invalid:
            raise _InvalidOnReadingError(f"{path}: {', '.join(invalid)} read back from "
                                         "the STEP file as an invalid solid; not written")
        crossing = [parts[i][1] for i, (r, check) in enumerate(zip(read, checks, strict=True))
                    if check == "crossing" and crosses_itself(r.shape)]
        if crossing:
            raise StepExportError(f"{path}: {', '.join(crossing)} read back from the STEP "
                                  "file as a solid that crosses itself; not written. "
                                  "Export it as a mesh, or hide it and export the others")
        if not flipped:
            return tmp.read_bytes()
        for i in flipped:
            shape, name, color = parts[i]
            parts[i] = (TopoDS.Solid(shape.Reversed()), name, color)
    raise StepExportError(f"{path}: a solid reads back inside out from the STEP file "
                          "however it is written; not written")


def _write_step(parts: Sequence[tuple[Any, str, str]], tmp: Path, path: Path,
                decimals: int | None = None, face_curves: bool = True) -> None:
    """Write [(shape, name, '#rrggbb')] as an AP214 STEP file at tmp (not atomic), its
    real numbers with `decimals` decimals (STEP_DECIMALS_RANGE), or as OpenCascade writes
    them (None); without `face_curves`, the edges' curves on their faces (pcurves) are
    left out, and a reader computes them from the edges' 3D curves and the faces."""
    from OCP.IFSelect import IFSelect_RetDone
    from OCP.Interface import Interface_Static
    from OCP.StepAP214 import StepAP214_Protocol
    from OCP.STEPCAFControl import STEPCAFControl_Writer
    from OCP.STEPControl import STEPControl_AsIs
    from OCP.StepData import StepData_StepWriter
    from OCP.TCollection import TCollection_ExtendedString
    from OCP.TDataStd import TDataStd_Name
    from OCP.TDocStd import TDocStd_Document
    from OCP.XCAFDoc import XCAFDoc_ColorSurf, XCAFDoc_DocumentTool

    doc = TDocStd_Document(TCollection_ExtendedString("XmlXCAF"))
    shapes = XCAFDoc_DocumentTool.ShapeTool_s(doc.Main())
    colors = XCAFDoc_DocumentTool.ColorTool_s(doc.Main())
    for shape, name, color in parts:
        label = shapes.AddShape(shape, False)
        TDataStd_Name.Set_s(label, TCollection_ExtendedString(name))
        colors.SetColor(label, _color(color), XCAFDoc_ColorSurf)
    writer = STEPCAFControl_Writer()
    writer.SetNameMode(True)
    writer.SetColorMode(True)
    # A process-wide setting that the translation reads: set for this file, then reset.
    Interface_Static.SetIVal_s("write.surfacecurve.mode", int(face_curves))
    try:
        translated = writer.Transfer(doc, STEPControl_AsIs)
    finally:
        Interface_Static.SetIVal_s("write.surfacecurve.mode", 1)
    if not translated:
        raise StepExportError(f"{path}: OpenCascade could not translate the solids to STEP")
    if decimals is None:
        if writer.Write(str(tmp)) != IFSelect_RetDone or not tmp.is_file():
            raise StepExportError(f"{path}: OpenCascade could not write the STEP file")
        return
    # What STEPControl_Writer.Write does (StepSelect_WorkLibrary), with another format
    # for the reals, which that writer fixes at 12 digits after the point.
    lines = StepData_StepWriter(writer.ChangeWriter().Model())
    lines.FloatWriter().SetDefaults(decimals)
    lines.FloatWriter().SetFormatForRange(f"%.{decimals}f", *STEP_DECIMALS_RANGE)
    lines.SendModel(StepAP214_Protocol())
    text = "\n".join(lines.Line(i).ToCString() for i in range(1, lines.NbLines() + 1))
    tmp.write_text(text + "\n", encoding="utf-8")


@dataclass
class StepReport:
    """What an export did: the file, solids written, seconds, bytes."""

    path: Path
    solids: int
    seconds: float
    size: int


def export_step(abstraction: Abstraction, path: str | Path, *, union: bool = False,
                original_frame: bool = False, progress: Progress | None = None,
                cancelled: Cancelled | None = None) -> StepReport:
    """Write the visible primitives to a STEP file: one named, coloured solid each, or
    with `union` one fused solid named after the file. Every solid is checked first; a
    primitive that cannot be built correctly is an error naming it, and then nothing is
    written. progress(fraction, text) is called as the work goes; cancelled() is polled
    between steps and ExportCancelledError raised when it says so."""
    started = time.perf_counter()
    path = Path(path)
    if not is_step_path(path):
        raise SweepeditError(f"{path}: a STEP file must end in .step or .stp")
    require_folder(path)  # before the work, not after it
    chosen = [(i, p) for i, p in enumerate(abstraction.primitives) if p.visible]
    if not chosen:
        raise SweepeditError(f"{path}: the abstraction has no visible primitives to export")
    _occ()
    normalization = abstraction.normalization if original_frame else None
    report = progress or (lambda fraction, text: None)

    def step(done: int, text: str) -> None:
        if cancelled is not None and cancelled():
            raise ExportCancelledError()
        report(done / (len(chosen) + (2 if union else 0) + 1), text)

    for i, prim in chosen:
        prim.validate(i)  # every bad parameter before any work
    # A union may want other solids of a primitive whose sections cross (_OtherSolids):
    # the search goes on from the first where that was built here, and starts again,
    # skipping the first, where the helper built it.
    searches = [primitive_solids(p, i, normalization) for i, p in chosen]
    with ThreadPoolExecutor(max_workers=1) as pool:
        # A union's estimate (0.1-0.3 s) is made meanwhile, on a core the building
        # leaves idle (the inside test lets go of the interpreter).
        volumes = pool.submit(UnionVolumes, [p for _, p in chosen]) if union else None
        built = build_all(chosen, normalization, lambda k: next(searches[k]),
                          [sections_cross(p) for _, p in chosen],
                          lambda k, done: step(done, f"building {_describe(*chosen[k])}"),
                          lambda done: step(done, "building the solids"))
    solids = [solid for solid, _, _ in built]
    seconds = [took for _, took, _ in built]
    builds = [search if here else islice(primitive_solids(p, i, normalization), 1, None)
              for search, (_, _, here), (i, p) in zip(searches, built, chosen, strict=True)]
    if union:
        data = _union_bytes(solids, [p for _, p in chosen], [_describe(i, p) for i, p in chosen],
                            builds, seconds, path, normalization, volumes.result(),
                            lambda text: step(len(chosen) + 1, text))
        solids_written = 1
        step(len(chosen) + 2, f"writing {path.name}")
    else:
        parts = [(s, p.name or f"primitive {i}", p.color)
                 for s, (i, p) in zip(solids, chosen, strict=True)]
        step(len(chosen), f"writing {path.name}")
        # Each solid alone is well within the budget. A solid whose sections cross was
        # checked for crossing itself already: by its loft's own test, or as read back
        # from its own STEP text (_as_written); the file is read back for its validity.
        data = _step_bytes(parts, path, ["validity" if sections_cross(p) else "crossing"
                                         for _, p in chosen])
        solids_written = len(parts)
    atomic_write_bytes(path, data)
    report(1.0, f"wrote {path.name}")
    return StepReport(path, solids_written, time.perf_counter() - started,
                      path.stat().st_size)


# --------------------------------------------------------------------------- reading


@dataclass
class StepSolid:
    """A solid read back from a STEP file: its OpenCascade shape, name and colour."""

    shape: Any
    name: str
    color: str | None


def read_step(path: str | Path) -> list[StepSolid]:
    """The top-level shapes of a STEP file with their names and colours (OpenCascade's
    XCAF reader); used to check what export_step wrote."""
    _occ()
    from OCP.collections import Sequence_TDF_Label
    from OCP.IFSelect import IFSelect_RetDone
    from OCP.Quantity import Quantity_Color, Quantity_TOC_sRGB
    from OCP.STEPCAFControl import STEPCAFControl_Reader
    from OCP.TCollection import TCollection_ExtendedString
    from OCP.TDataStd import TDataStd_Name
    from OCP.TDocStd import TDocStd_Document
    from OCP.XCAFDoc import XCAFDoc_ColorSurf, XCAFDoc_DocumentTool

    reader = STEPCAFControl_Reader()
    reader.SetNameMode(True)
    reader.SetColorMode(True)
    if reader.ReadFile(str(path)) != IFSelect_RetDone:
        raise SweepeditError(f"{path}: OpenCascade cannot read this STEP file")
    doc = TDocStd_Document(TCollection_ExtendedString("XmlXCAF"))
    reader.Transfer(doc)
    shapes = XCAFDoc_DocumentTool.ShapeTool_s(doc.Main())
    colors = XCAFDoc_DocumentTool.ColorTool_s(doc.Main())
    labels = Sequence_TDF_Label()
    shapes.GetFreeShapes(labels)
    out = []
    for i in range(1, labels.Length() + 1):
        label = labels.Value(i)
        name_attr = TDataStd_Name()
        name = (name_attr.Get().ToExtString()
                if label.FindAttribute(TDataStd_Name.GetID_s(), name_attr) else "")
        color = Quantity_Color()
        hex_color = None
        if colors.GetColor(shapes.GetShape_s(label), XCAFDoc_ColorSurf, color):
            r, g, b = color.Values(Quantity_TOC_sRGB)
            hex_color = "#" + "".join(f"{round(v * 255):02x}" for v in (r, g, b))
        out.append(StepSolid(shapes.GetShape_s(label), name, hex_color))
    return out
