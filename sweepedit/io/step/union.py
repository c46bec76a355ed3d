"""The union of primitives' solids as one checked solid: OpenCascade's fuse, checked
against the exact inside test's estimate of the union, and mended where it fails (fusing
back what it left out, one solid at a time, fuzzy, nudged, a folding primitive sliced
another way); its edge curves re-approximated with fewer poles; written as STEP bytes."""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from sweepedit.geometry.model import Normalization, SweepPrimitive
from sweepedit.geometry.volumes import (
    UnionVolumes,
    closed_form_volume,
    fold_volume,
    union_bounds,
)
from sweepedit.io.step.checks import check_solid, is_valid, solid_volume
from sweepedit.io.step.occ import StepExportError
from sweepedit.io.step.solids import sections_cross, transform_poles
from sweepedit.io.step.writer import step_bytes

# The union's volume must match the quasi-Monte Carlo estimate (geometry.volumes.
# union_volume: 8 scrambled Sobol sets of 2^15 points) this closely (relative), besides how
# far its solids' own volumes are from their primitives', or by UNION_SIGMAS standard
# errors of the estimate where that is larger. At 1 %, with plain Monte Carlo's 0.5 % error
# taking it to 2 %, fuzzy fuses that dropped 0.7 % of glyph_8.json's union passed (IoU
# 0.9907, under the 0.995 wanted; BENCHMARKS.md, STEP export).
UNION_TOLERANCE = 0.005
UNION_SIGMAS = 4.0
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
# A file larger than this per primitive is written without the edges' curves on their
# faces (pcurves: 2D B-splines that a reader can compute from the 3D curves and the
# faces, 40 % of a large union's poles) where it reads back as checked that way; a
# file within it keeps them. Unions of glyph_8.json, hand.txt, femur.json: 330 -> 193-207
# kB per primitive (BENCHMARKS.md, STEP export).
STEP_BYTES_PER_PRIMITIVE = 250_000


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
        points = transform_poles(volumes.only_inside(k, LEFT_OUT_POINTS), normalization)
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


def _exact_volume(primitive: SweepPrimitive) -> float:
    """A primitive's volume in the normalised frame: in closed form, or for one whose
    sections cross, fold_volume's estimate."""
    if sections_cross(primitive):
        return fold_volume(primitive)[0]
    return closed_form_volume(primitive)


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


def union_bytes(solids: list[Any], primitives: list[SweepPrimitive], names: list[str],
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
        return step_bytes([(union, path.stem, primitives[0].color)], path,
                           checks=["validity"],
                           budget=STEP_BYTES_PER_PRIMITIVE * len(primitives),
                           volumes=[volume])

    def checked(fused: Any) -> bytes:
        # The fuse's volume is checked, and the same with edge curves of fewer poles
        # only as read back against it: with those curves the volume takes twice as
        # long to integrate (glyph_8.json: 0.47 s against 0.22 s), and a fuse that
        # went wrong is known before they are made (BENCHMARKS.md, STEP export).
        check_solid(fused, estimate * scale3, tolerance, "the union",
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
                check_solid(candidate, estimate * scale3, tolerance, "the union",
                             f"the exact inside test's estimate with {what} added")
            except StepExportError:
                continue
            fused, used[k] = candidate, solid
            break
        else:
            raise StepExportError(f"the union: no fuse of {what} with the larger ones "
                                  "passes its check")
    return fused
