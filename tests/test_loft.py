"""Lofts through rings (geometry/loft.py) against surfaces known in closed form, and
the test that a loft does not cross itself against lofts built to cross, and against
OpenCascade's own check of the solid."""

from __future__ import annotations

import numpy as np
import pytest

from sweepedit.geometry.loft import (
    LoftVerdict,
    loft_samples,
    loft_verdict,
    polygon_crosses_itself,
    ring_loft,
    star_shaped,
)
from sweepedit.geometry.model import SweepPrimitive
from sweepedit.geometry.slices import RAYS, ParallelPlanes

ANGLES = np.linspace(0.0, 2.0 * np.pi, RAYS, endpoint=False)
UP = ParallelPlanes(np.array([0.0, 0.0, 1.0]))


def _rings(heights: np.ndarray, across: np.ndarray) -> np.ndarray:
    """Rings (S, P, 3) at heights (S,) across UP's planes, their points across the
    planes (S, P, 2) in UP's local coordinates."""
    local = np.concatenate([np.broadcast_to(heights[:, None, None], (*across.shape[:2], 1)),
                            across], axis=2)
    return UP.to_world(local)


def _circles(radii: np.ndarray) -> np.ndarray:
    """Circles (S, P, 2) of radii (S,) at ANGLES."""
    return radii[:, None, None] * np.stack([np.cos(ANGLES), np.sin(ANGLES)], axis=-1)


def _cone() -> tuple[np.ndarray, np.ndarray]:
    """A truncated cone: rings at heights 0..1 of radius 0.2 + 0.1 z, and their u."""
    u = np.linspace(0.0, 1.0, 12)
    return _rings(u, _circles(0.2 + 0.1 * u)), u


def test_a_loft_through_circles_of_a_cone_lies_on_the_cone_and_is_vouched_for() -> None:
    rings, u = _cone()
    loft = ring_loft(rings, u, ANGLES)
    assert len(loft.patches) == 4
    points = loft_samples(loft)
    local = UP.to_local(points)
    height, radius = local[..., 0], np.hypot(local[..., 1], local[..., 2])
    # The cone's side is linear in z, so the cubic along it is exact, and only the
    # circle's interpolation by cubics through 48 points errs (about 2e-6 of 0.3).
    assert np.abs(radius - (0.2 + 0.1 * height)).max() < 1e-5
    assert height[0].max() < 1e-12 and height[-1].min() > 1.0 - 1e-12
    assert loft_verdict(loft, UP) is LoftVerdict.EMBEDDED


def test_a_ring_twisted_into_a_figure_of_eight_is_seen_to_cross() -> None:
    rings, u = _cone()
    across = UP.to_local(rings)[..., 1:]
    # The middle rings turn into a figure of eight (Gerono's lemniscate, crossing
    # itself at its centre): the surface crosses itself there.
    eight = 0.25 * np.stack([np.cos(ANGLES), 0.5 * np.sin(2.0 * ANGLES)], axis=-1)
    across[5:7] = eight
    loft = ring_loft(_rings(u, across), u, ANGLES)
    assert loft_verdict(loft, UP) is LoftVerdict.CROSSES
    assert not star_shaped(eight[None])[0]
    assert polygon_crosses_itself(eight)


def _end_looped(start: float) -> tuple[np.ndarray, np.ndarray]:
    """A cone's rings (S, P, 3) and u (S,), dense near u = 0, whose 11th point runs
    `start` of a step past the 12th at u = 0 and back into line within u ~ 0.002: for
    start > 0 the first ring, a cap's outline, makes a small loop there and no ring much
    above it does (as in balloondog.json's 8th primitive, K = 8)."""
    u = np.array([0.0, 2e-4, 5e-4, 1e-3, 2e-3, 5e-3, 0.01, 0.03, 0.1, 0.3, 0.6, 1.0])
    step = ANGLES[1] - ANGLES[0]
    past = start - (1.0 + start) * (1.0 - np.exp(-u / 5e-4))  # -> -1: back in line
    theta = np.broadcast_to(ANGLES, (len(u), len(ANGLES))).copy()
    theta[:, 10] = ANGLES[10] + (1.0 + past) * step
    across = (0.2 + 0.1 * u)[:, None, None] * np.stack([np.cos(theta), np.sin(theta)], -1)
    return _rings(u, across), u


def test_a_loop_in_an_end_ring_alone_is_seen_to_cross() -> None:
    # The level curves lie above the first 0.003 of the height, the loop below it; the
    # end rings are tested on their own, each in its own plane.
    for start, crosses in ((0.3, True), (-0.3, False)):
        rings, u = _end_looped(start)
        assert polygon_crosses_itself(UP.to_local(rings[0])[:, 1:]) is crosses
        assert not polygon_crosses_itself(UP.to_local(rings[4])[:, 1:])
        loft = ring_loft(rings, u, ANGLES)
        assert loft_verdict(loft, UP) is (LoftVerdict.CROSSES if crosses
                                          else LoftVerdict.EMBEDDED)


def test_a_loft_whose_height_turns_back_is_left_to_opencascade() -> None:
    u = np.linspace(0.0, 1.0, 12)
    heights = u.copy()
    heights[6] = heights[4] - 0.02  # the 7th ring below the 5th: the side folds back
    loft = ring_loft(_rings(heights, _circles(0.2 + 0.1 * u)), u, ANGLES)
    assert loft_verdict(loft, UP) is LoftVerdict.UNKNOWN


def test_star_shaped_polygons_and_others() -> None:
    theta = np.linspace(0.0, 2.0 * np.pi, 200, endpoint=False)
    # A superellipse with exponent 0.6 (pinched sides, sharp corners): star-shaped
    # about its centre, in either direction.
    c, s = np.cos(theta), np.sin(theta)
    astroid = np.stack([np.sign(c) * np.abs(c) ** (2 / 0.6),
                        np.sign(s) * np.abs(s) ** (2 / 0.6)], axis=-1) + np.array([3.0, -1.0])
    assert star_shaped(np.stack([astroid, astroid[::-1]])).all()
    # A ring that turns twice round its centre is not simple.
    twice = np.stack([np.cos(2.0 * theta), np.sin(2.0 * theta)], axis=-1)
    assert not star_shaped(twice[None])[0]
    # A thin C, simple but star-shaped about no point tried: not vouched for.
    arc = np.linspace(0.2, 2.0 * np.pi - 0.2, 100)
    c_shape = np.concatenate([np.stack([np.cos(arc), np.sin(arc)], axis=-1),
                              0.9 * np.stack([np.cos(arc[::-1]), np.sin(arc[::-1])], axis=-1)])
    assert not star_shaped(c_shape[None])[0]
    assert not polygon_crosses_itself(c_shape)
    assert not polygon_crosses_itself(astroid)
    # A bow tie crosses itself, and so does the C with two neighbours on its arc
    # swapped (a, c, b, d on a convex arc: the edges a-c and b-d cross); edges that only
    # share a vertex do not cross; the polygon must be rows of two.
    assert polygon_crosses_itself(np.array([[0.0, 0.0], [1.0, 1.0], [1.0, 0.0], [0.0, 1.0]]))
    assert polygon_crosses_itself(c_shape[[*range(50), 51, 50, *range(52, len(c_shape))]])
    assert not polygon_crosses_itself(np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]]))
    with pytest.raises(ValueError, match=r"\(M, 2\)"):
        polygon_crosses_itself(np.zeros((5, 3)))


def test_our_verdict_agrees_with_opencascades_on_lofts_that_do_and_do_not_cross() -> None:
    pytest.importorskip("OCP", reason="the optional 'cad' extra (OpenCascade) is not installed")
    from sweepedit.io.step.checks import crosses_itself
    from sweepedit.io.step.solids import _sewn_solid

    anything = SweepPrimitive([[0.0, 0.0, 0.0], [0.0, 0.0, 0.5], [0.0, 0.0, 1.0]],
                              a=0.3, b=0.3, degree=2.0)
    rings, u = _cone()
    plain = ring_loft(rings, u, ANGLES)
    across = UP.to_local(rings)[..., 1:]
    across[5:7] = 0.25 * np.stack([np.cos(ANGLES), 0.5 * np.sin(2.0 * (ANGLES - 0.3))],
                                  axis=-1)
    twisted = ring_loft(_rings(u, across), u, ANGLES)
    end_looped = ring_loft(*_end_looped(0.3), ANGLES)
    for loft, crosses in ((plain, False), (twisted, True), (end_looped, True)):
        solid = _sewn_solid(anything, loft, None, "a loft")
        assert crosses_itself(solid) == crosses
        assert loft_verdict(loft, UP) is (LoftVerdict.CROSSES if crosses
                                          else LoftVerdict.EMBEDDED)
