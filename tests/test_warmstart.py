"""The warm start's share-out of primitives over skeleton branches."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from sweepedit.fitting.warmstart import warm_start_primitives
from sweepedit.geometry.sweep import axis_points


def _loop(sign: float, n: int = 64) -> SimpleNamespace:
    """A figure eight's loop as the skeleton gives it: from the crossing at the origin
    round a circle of radius 0.2 (centre z = +-0.2) back to the crossing."""
    angle = np.linspace(0.05, 2 * np.pi - 0.05, n)
    points = np.stack([0.2 * np.sin(angle), np.zeros(n), sign * 0.2 * (1 - np.cos(angle))], 1)
    return SimpleNamespace(points=points, radii=np.full(n, 0.06), start_kind="junction",
                           end_kind="junction")


def test_a_nub_at_a_junction_gives_its_primitive_to_a_loop() -> None:
    """Eight at K = 4: two loops and the short branch between the crossing's two skeleton
    nodes. Each loop needs two quadratic axes (one cannot go round), so the nub, a tenth of
    a loop's volume, gets none; before, it kept one and the second loop got a single
    hairpin (fitted IoU 0.76 against 0.89)."""
    nub = SimpleNamespace(points=np.array([[-0.02, 0.0, 0.0], [0.0, 0.0, 0.0], [0.02, 0.0, 0.0]]),
                          radii=np.full(3, 0.1), start_kind="junction", end_kind="junction")
    prims = warm_start_primitives([_loop(1.0), _loop(-1.0), nub], 4)
    assert len(prims) == 4
    halves = []
    for p in prims:
        axis = axis_points(p.control_points[None], np.linspace(0, 1, 50))[0]
        halves.append(np.sign(np.mean(axis[:, 2])))
        # On its loop: every axis point about 0.2 from that loop's centre.
        centre = np.array([0.0, 0.0, 0.2 * halves[-1]])
        radius = np.linalg.norm(axis - centre, axis=1)
        assert np.all(np.abs(radius - 0.2) < 0.05), radius
    assert sorted(halves) == [-1.0, -1.0, 1.0, 1.0]


def test_a_branch_worth_keeping_is_not_dropped_for_a_split() -> None:
    """The same loops with a straight limb half a loop's volume: at K = 3 the limb keeps
    its primitive and one loop stays whole, rather than losing the limb."""
    n = 32
    limb = SimpleNamespace(points=np.stack([np.linspace(0.0, 0.3, n), np.zeros(n),
                                            np.zeros(n)], 1),
                           radii=np.full(n, 0.06 * np.sqrt(1.3 / 0.3 / 2)),
                           start_kind="junction", end_kind="tip")
    prims = warm_start_primitives([_loop(1.0), _loop(-1.0), limb], 3)
    straight = [p for p in prims if np.ptp(p.control_points[:, 2]) < 0.02]
    assert len(prims) == 3 and len(straight) == 1
