"""Building a STEP export's solids on two cores (io/step/workers.py): what the helper
process sends back is the solid this process would build, to the last bit; its errors
are raised here as they were; its death, a stall or a cancel never lose an export."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest
from crossing import CROSSING

from sweepedit.errors import SweepeditError
from sweepedit.geometry.model import Abstraction, SweepPrimitive
from sweepedit.io.step import (
    ExportCancelledError,
    export_step,
    primitive_solid,
    primitive_solids,
    read_step,
)
from sweepedit.io.step import workers as step_workers
from sweepedit.io.step.checks import solid_volume
from sweepedit.io.step.solids import sections_cross
from sweepedit.io.step.workers import build_all, solid_bytes, solid_from_bytes

needs_occ = pytest.mark.skipif(importlib.util.find_spec("OCP") is None,
                               reason="the cad extra (cadquery-ocp-novtk) is not installed")
needs_two_cores = pytest.mark.skipif(not step_workers.two_cores_available(),
                                     reason="one core: everything is built here")



def _geometry(solid) -> list:
    """Each face's surface as numbers: its kind, and a B-spline's poles and knots."""
    from OCP.BRep import BRep_Tool
    from OCP.TopAbs import TopAbs_FACE
    from OCP.TopExp import TopExp_Explorer
    from OCP.TopoDS import TopoDS

    faces, explorer = [], TopExp_Explorer(solid, TopAbs_FACE)
    while explorer.More():
        surface = BRep_Tool.Surface_s(TopoDS.Face(explorer.Current()))
        numbers = [type(surface).__name__]
        if hasattr(surface, "NbUPoles"):
            numbers += [surface.Pole(i, j).Coord()
                        for i in range(1, surface.NbUPoles() + 1)
                        for j in range(1, surface.NbVPoles() + 1)]
            numbers += [surface.UKnot(i) for i in range(1, surface.NbUKnots() + 1)]
            numbers += [surface.VKnot(i) for i in range(1, surface.NbVKnots() + 1)]
        faces.append(numbers)
        explorer.Next()
    return faces


def _ready_helper():
    step_workers.start_helper()
    helper = step_workers._Helper.current()
    assert helper is not None and helper.ready.wait(120), "the helper did not start"
    return helper


def _no_helper() -> None:
    helper = step_workers._Helper.current()
    if helper is not None:
        helper.stop()


def _here(chosen):
    return lambda k: next(primitive_solids(chosen[k][1], chosen[k][0]))


@needs_occ
def test_binary_round_trip_keeps_a_solid_exactly() -> None:
    prim = SweepPrimitive([[-0.3, 0, 0], [0, 0.2, 0.1], [0.3, 0, 0]], a=0.06, b=0.03,
                          degree=0.7, scaling=(0.1, -0.2))
    solid = primitive_solid(prim)
    back = solid_from_bytes(solid_bytes(solid))
    assert solid_volume(back) == solid_volume(solid)
    assert _geometry(back) == _geometry(solid)
    assert any(len(face) > 1 for face in _geometry(solid))  # B-spline faces compared


@needs_occ
def test_with_fewer_than_two_slow_primitives_all_are_built_here_in_order() -> None:
    rod = SweepPrimitive([[0, 0, 0], [0.1, 0, 0], [0.2, 0, 0]], a=0.02, b=0.02, degree=2.0)
    chosen = list(enumerate([CROSSING[0], rod]))
    starts: list[tuple[int, int]] = []
    built = build_all(chosen, None, _here(chosen), [True, False],
                      lambda k, done: starts.append((k, done)), lambda done: None)
    assert starts == [(0, 0), (1, 1)]
    assert all(here for _, _, here in built)
    with pytest.raises(ValueError, match="1 slowness flags for 2"):
        build_all(chosen, None, _here(chosen), [True], lambda k, d: None, lambda d: None)


@needs_occ
@needs_two_cores
def test_the_helper_builds_the_same_solids_and_they_come_back_in_order() -> None:
    _ready_helper()
    chosen = list(enumerate(CROSSING))
    assert all(sections_cross(p) for _, p in chosen)
    starts: list[int] = []
    built = build_all(chosen, None, _here(chosen), [True] * 4,
                      lambda k, done: starts.append(k), lambda done: None)
    there = [k for k, (_, _, here) in enumerate(built) if not here]
    assert there and there[0] == 0  # the helper takes the front of the list
    assert sorted(starts) == [k for k, (_, _, here) in enumerate(built) if here]
    for k in there:  # the very solid this process builds
        assert _geometry(built[k][0]) == _geometry(primitive_solid(CROSSING[k], k))


@needs_occ
@needs_two_cores
def test_an_export_shared_with_the_helper_writes_every_solid(tmp_path: Path) -> None:
    _ready_helper()
    rod = SweepPrimitive([[0.3, 0, 0], [0.4, 0.05, 0], [0.5, 0, 0]], a=0.03, b=0.03,
                         degree=2.0, name="rod")
    prims = [CROSSING[0], rod, CROSSING[1], CROSSING[3]]
    out = tmp_path / "shared.step"
    export_step(Abstraction(prims), out)
    solids = read_step(out)
    assert [s.name for s in solids] == ["elbow", "rod", "hairpin", "eight6"]
    for read, (k, prim) in zip(solids, enumerate(prims), strict=True):
        assert solid_volume(read.shape) == pytest.approx(solid_volume(primitive_solid(prim, k)),
                                                         rel=1e-6)  # 8 decimals written


@needs_occ
@needs_two_cores
def test_the_helpers_error_is_raised_here_as_it_was() -> None:
    _ready_helper()
    broken = SweepPrimitive([[0, 0, 0], [0.1, 0.1, 0], [0.2, 0, 0]], a=0.05, b=0.05,
                            degree=2.0, name="broken")
    broken.control_points[1, 1] = np.nan
    chosen = [(0, broken), (1, CROSSING[0])]
    with pytest.raises(SweepeditError) as here:
        primitive_solid(broken, 0)
    with pytest.raises(type(here.value), match=str(here.value).replace("(", r"\(")
                       .replace(")", r"\)")):
        # both slow, so that the helper, not this process, gets the broken one first
        build_all(chosen, None, _here(chosen), [True, True], lambda k, d: None,
                  lambda d: None)


@needs_occ
@needs_two_cores
def test_a_helper_that_dies_loses_nothing() -> None:
    helper = _ready_helper()
    chosen = list(enumerate(CROSSING[:3]))

    def started(k: int, done: int) -> None:
        helper._process.kill()  # as a crash in OpenCascade would end it, mid-solid

    built = build_all(chosen, None, _here(chosen), [True] * 3, started, lambda d: None)
    assert all(here for _, _, here in built)
    for (solid, _, _), (k, prim) in zip(built, chosen, strict=True):
        assert _geometry(solid) == _geometry(primitive_solid(prim, k))
    assert step_workers._Helper._current is not helper  # the next export starts another


@needs_occ
@needs_two_cores
def test_a_cancel_stops_the_helper() -> None:
    helper = _ready_helper()
    chosen = list(enumerate(CROSSING[:3]))

    def started(k: int, done: int) -> None:
        raise ExportCancelledError()

    with pytest.raises(ExportCancelledError):
        build_all(chosen, None, _here(chosen), [True] * 3, started, lambda d: None)
    assert not helper.alive()


@needs_occ
@needs_two_cores
def test_a_one_off_export_starts_a_helper_only_for_many_slow_primitives(monkeypatch) -> None:
    _no_helper()
    chosen = list(enumerate(CROSSING[:2]))
    built = build_all(chosen, None, _here(chosen), [True, True], lambda k, d: None,
                      lambda d: None)
    assert all(here for _, _, here in built)
    assert step_workers._Helper.current() is None  # not worth its 5 s start
    # With as many as MIN_SLOW_TO_START it is started, and takes work once ready (here
    # it is not yet: the solids are all built in this process, none lost waiting).
    monkeypatch.setattr(step_workers, "MIN_SLOW_TO_START", 2)
    built = build_all(chosen, None, _here(chosen), [True, True], lambda k, d: None,
                      lambda d: None)
    for (solid, _, _), (k, prim) in zip(built, chosen, strict=True):
        assert _geometry(solid) == _geometry(primitive_solid(prim, k))
    assert step_workers._Helper.current() is not None
