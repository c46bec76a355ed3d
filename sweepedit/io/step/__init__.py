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

The modules, each importing only those above it:

- occ.py: OpenCascade's import, the errors, is_step_path, the shared sewing tolerance;
- checks.py: a solid's volume, validity, and whether it crosses itself;
- writer.py: the STEP file with names and colours, read back checked; read_step;
- solids.py: one primitive's B-rep solid, lofted through slices where its sections cross;
- union.py: the fuse of the solids into one, checked and mended;
- workers.py: the solids built on two cores, by a helper process (`python -m
  sweepedit.io.step`, __main__.py) that the app keeps;
- export.py: export_step, which builds, fuses and writes.
"""

from sweepedit.io.step.export import StepReport, export_step
from sweepedit.io.step.occ import (
    CadUnavailableError,
    ExportCancelledError,
    StepExportError,
    is_step_path,
)
from sweepedit.io.step.solids import primitive_solid, primitive_solids
from sweepedit.io.step.writer import StepSolid, read_step

__all__ = [
    "CadUnavailableError",
    "ExportCancelledError",
    "StepExportError",
    "StepReport",
    "StepSolid",
    "export_step",
    "is_step_path",
    "primitive_solid",
    "primitive_solids",
    "read_step",
]
