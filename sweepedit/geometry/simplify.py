"""A primitive's layout -- how many axis control points, how many scaling terms -- changed
while its solid stays where it is.

The fit optimises every primitive in one generous layout (long curved parts need more
than the three control points of a quadratic Bezier, a limb that tapers to a tip more
than a quadratic scaling), then gives each primitive back the simplest layout that
keeps its surface within a tolerance (`simplify_primitive`): a straight leg ends with
three control points and two scaling terms, a curled tail keeps eight. `relayout`
writes a primitive in another layout by least squares in the sweep parameter t, so
the axis point, and with it the scaling f(t), keeps its place along the sweep. Towards
more control points this is exact where the finer axis's knots include the coarser
one's (a quadratic Bezier into any layout, 4 control points into 6 or 8, 5 into 8: the
finer spline space holds the coarser curve), towards more scaling terms always.

Shapes: n control points, k scaling terms, M parameter samples.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from sweepedit.geometry.axis_edit import fit_control_points, fit_scaling
from sweepedit.geometry.model import MIN_SCALE, SweepPrimitive
from sweepedit.geometry.sweep import axis_points, scaling_factor, sweep_surface

# Samples of the sweep parameter and of the profile angle on which two primitives'
# surfaces are compared point by point.
COMPARE_STATIONS = 65
COMPARE_ANGLES = 32
# Control points and scaling terms a simplified primitive may get, simplest first
# (layouts beyond the primitive's own are never offered).
CONTROL_POINT_CHOICES = (3, 4, 5, 6, 8, 10, 14)
SCALING_CHOICES = (2, 3, 4, 5, 6)


def relayout(primitive: SweepPrimitive, n_control_points: int, n_scaling: int,
             samples: int = 129) -> SweepPrimitive:
    """The primitive with n_control_points control points and n_scaling scaling terms:
    its axis and f(t) fitted by least squares at `samples` values of t, ends pinned;
    the profile, name, colour and flags are kept."""
    t = np.linspace(0.0, 1.0, samples)
    cps, _, scaling = primitive.batch_arrays()
    points = axis_points(cps, t)[0]
    f = scaling_factor(scaling, t)[0]
    out = primitive.copy()
    out.control_points = fit_control_points(points, t, n_control_points)
    out.scaling = fit_scaling(f, t, n_scaling)
    return out


def surface_deviation(first: SweepPrimitive, second: SweepPrimitive) -> float:
    """The largest distance between the two primitives' side surfaces at the same sweep
    parameter and profile angle (COMPARE_STATIONS x COMPARE_ANGLES points): an upper
    bound on how far one surface lies from the other, the end rings (and so the caps'
    rims) included."""
    t = np.linspace(0.0, 1.0, COMPARE_STATIONS)
    theta = np.linspace(0.0, 2.0 * np.pi, COMPARE_ANGLES, endpoint=False)
    surfaces = [sweep_surface(*p.batch_arrays(), t, theta)[0] for p in (first, second)]
    return float(np.max(np.linalg.norm(surfaces[0] - surfaces[1], axis=-1)))


def layout_choices(primitive: SweepPrimitive) -> list[tuple[int, int]]:
    """The (control points, scaling terms) layouts simpler than the primitive's own,
    fewest parameters first, then its own. Only axes whose segments nest in the
    primitive's are offered (its segment count a multiple of theirs), so that the
    simplified primitive goes back into the fit's layout exactly (relayout) when a later
    refinement, such as refitting a selection with others of the first layout, needs
    it there."""
    n, k = primitive.n_control_points, len(primitive.scaling)
    simpler = {(m, j) for m in (*CONTROL_POINT_CHOICES, n) for j in (*SCALING_CHOICES, k)
               if m <= n and (n - 2) % (m - 2) == 0 and j <= k and (m, j) != (n, k)}
    return [*sorted(simpler, key=lambda mj: (3 * mj[0] + mj[1], mj[0])), (n, k)]


def simplify_primitive(primitive: SweepPrimitive, tolerance: float) -> SweepPrimitive:
    """The primitive in the simplest layout (layout_choices) whose surface stays within
    `tolerance` (normalised units) of the primitive's own (surface_deviation), valid and
    with its control points in [-0.5, 0.5]^3; the primitive itself when none does."""
    for n, k in layout_choices(primitive)[:-1]:
        candidate = relayout(primitive, n, k)
        if not _acceptable(candidate):
            continue
        if surface_deviation(primitive, candidate) <= tolerance:
            return candidate
    return primitive


def simplify_primitives(primitives: Sequence[SweepPrimitive],
                        tolerance: float) -> list[SweepPrimitive]:
    """simplify_primitive of each."""
    return [simplify_primitive(p, tolerance) for p in primitives]


def _acceptable(primitive: SweepPrimitive) -> bool:
    if np.any(np.abs(primitive.control_points) > 0.5):
        return False
    try:
        primitive.validate()
    except ValueError:
        return False
    f = scaling_factor(primitive.scaling_array, np.linspace(0.0, 1.0, 257))
    return bool(np.min(f) > MIN_SCALE)
