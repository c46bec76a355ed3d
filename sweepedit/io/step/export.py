"""export_step: the visible primitives of an abstraction written to a STEP file, one
named, coloured solid each (solids.py, built on two cores by io/step/workers.py) or one
fused solid (union.py), every solid checked before anything is written and the file read
back checked (writer.py)."""

from __future__ import annotations

import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from itertools import islice
from pathlib import Path

from sweepedit.errors import SweepeditError
from sweepedit.geometry.model import Abstraction
from sweepedit.geometry.volumes import UnionVolumes
from sweepedit.io.params import atomic_write_bytes, require_folder
from sweepedit.io.step.occ import ExportCancelledError, is_step_path, load_occ
from sweepedit.io.step.solids import describe_primitive, primitive_solids, sections_cross
from sweepedit.io.step.union import union_bytes
from sweepedit.io.step.workers import build_all
from sweepedit.io.step.writer import step_bytes

Progress = Callable[[float, str], None]
Cancelled = Callable[[], bool]


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
    load_occ()
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
                          lambda k, done: step(done, f"building {describe_primitive(*chosen[k])}"),
                          lambda done: step(done, "building the solids"))
    solids = [solid for solid, _, _ in built]
    seconds = [took for _, took, _ in built]
    builds = [search if here else islice(primitive_solids(p, i, normalization), 1, None)
              for search, (_, _, here), (i, p) in zip(searches, built, chosen, strict=True)]
    if union:
        names = [describe_primitive(i, p) for i, p in chosen]
        data = union_bytes(solids, [p for _, p in chosen], names, builds, seconds, path,
                           normalization, volumes.result(),
                           lambda text: step(len(chosen) + 1, text))
        solids_written = 1
        step(len(chosen) + 2, f"writing {path.name}")
    else:
        parts = [(s, p.name or f"primitive {i}", p.color)
                 for s, (i, p) in zip(solids, chosen, strict=True)]
        step(len(chosen), f"writing {path.name}")
        # Each solid alone is well within the budget. A solid whose sections cross was
        # checked for crossing itself already: by its loft's own test, or as read back
        # from its own STEP text (as_written); the file is read back for its validity.
        data = step_bytes(parts, path, ["validity" if sections_cross(p) else "crossing"
                                         for _, p in chosen])
        solids_written = len(parts)
    atomic_write_bytes(path, data)
    report(1.0, f"wrote {path.name}")
    return StepReport(path, solids_written, time.perf_counter() - started,
                      path.stat().st_size)
