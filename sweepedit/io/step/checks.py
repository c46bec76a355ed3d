"""Checks of OpenCascade solids: their volume, OpenCascade's validity checker, and
whether a shape crosses itself (OpenCascade's self-interference check, with the alarms
of a face meeting itself at one point of it dismissed)."""

from __future__ import annotations

import math
from functools import lru_cache
from typing import Any

import numpy as np

from sweepedit.io.step.occ import SEW_TOLERANCE, StepExportError

# Relative precision asked of OpenCascade's adaptive volume integration. Its results
# come within 1e-4 of a 1e-9 integration on folding solids (2e-6 on the others and on
# a union of 7), far inside every check's tolerance, at a tenth to a half of 1e-6's time
# (a folding primitive's solid: 7-10 ms, against 30-127 ms; femur.json's union 0.39 s
# against 0.91 s; BENCHMARKS.md, STEP export).
VOLUME_PRECISION = 1e-3
# A curve along which a face meets itself is a crossing only where its two points on the
# face lie apart on it: further than this (relative to the face's size) along the
# straight path between them in its parameters, sampled at SAME_POINT_STEPS steps.
# OpenCascade's check also reports "curves" whose two points on the face are one
# (camel.json's 4th: 3e-6 long, its points 1e-9 apart on the face; a real crossing's are
# as far apart as the sheets that meet).
SAME_POINT_SHARE = 1e-6
SAME_POINT_STEPS = 8


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


def check_solid(shape: Any, expected: float, tolerance: float, what: str,
                 truth: str, parallel: bool = False) -> None:
    if not is_valid(shape, parallel):
        raise StepExportError(f"{what}: OpenCascade's checker finds the solid invalid")
    volume = solid_volume(shape)
    if not abs(volume / expected - 1.0) <= tolerance:
        raise StepExportError(f"{what}: the solid's volume {volume:.6g} is "
                              f"{100.0 * (volume / expected - 1.0):+.3f}% off {truth} "
                              f"{expected:.6g}; not written")


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
