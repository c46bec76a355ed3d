"""SweepNet's losses (docs/fitting.md), each a small function over tensors.

Shapes: B shapes, K primitives, Q query points, M skeleton points, S axis samples.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

BOLTZMANN_ALPHA = 40.0
# How far a profile point may reach towards the centre of the axis's bend, as a share of
# the bend's radius, before fold_loss counts it. A sweep folds onto itself at 1; up to
# about 1.5 the fold stays inside the solid, beyond it grows fins. On the 30 benchmark
# shapes at K = 8 (8 control points): no penalty, a median primitive reached 11.8 and
# F1@0.01 was 0.908; limit 0.9, 1.3 and 0.890; limit 1.5, 1.9 and 0.898.
FOLD_LIMIT = 1.5
# How far an axis may stray outside the shape before outside_axis_loss counts it: one
# cell of the 64^3 grid, the resolution of the distance it is measured by.
AXIS_MARGIN = 1.0 / 64


@dataclass(frozen=True)
class LossWeights:
    """The paper's weights: reconstruction 12, overlap 6, parsimony 0.3*K/8, axis 5."""

    reconstruction: float = 12.0
    overlap: float = 6.0
    parsimony: float | None = None  # None: 0.3 * K / 8
    axis: float = 5.0
    # The axis prior guides the start of the fit and then fades out: weight * decay^progress.
    axis_decay: float = 0.01
    # Coverage above this many primitives is penalised (the official code uses 1).
    overlap_threshold: float = 1.0

    def parsimony_weight(self, n_primitives: int) -> float:
        return 0.3 * n_primitives / 8.0 if self.parsimony is None else self.parsimony

    def axis_weight(self, progress: float) -> float:
        """Axis weight at progress in [0, 1] through the fit (exponential decay)."""
        return self.axis * self.axis_decay ** min(max(progress, 0.0), 1.0)


def boltzmann_union(occupancy: torch.Tensor, selection: torch.Tensor,
                    alpha: float = BOLTZMANN_ALPHA) -> torch.Tensor:
    """Soft union of selected primitives: occupancy (B, K, Q), selection (B, K) -> (B, Q).

    sum_i o_i e^(a o_i) / sum_i e^(a o_i) with o_i = selection_i * occupancy_i, a smooth
    maximum that passes gradients to every primitive near the top.
    """
    o = occupancy * selection[:, :, None]
    weights = torch.softmax(alpha * o, dim=1)
    return (weights * o).sum(dim=1)


def reconstruction_loss(union: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Mean squared error between the union (B, Q) and the target occupancy (B, Q)."""
    return torch.mean((union - target) ** 2)


def overlap_loss(occupancy: torch.Tensor, selection: torch.Tensor,
                 threshold: float = 1.0) -> torch.Tensor:
    """Mean coverage beyond `threshold` primitives: occupancy (B, K, Q), selection (B, K)."""
    coverage = (occupancy * selection[:, :, None]).sum(dim=1)
    return torch.mean(torch.relu(coverage - threshold))


def parsimony_loss(selection: torch.Tensor) -> torch.Tensor:
    """sqrt of the (soft) number of selected primitives, averaged over the batch: (B, K)."""
    return torch.mean(torch.sqrt(selection.sum(dim=1) + 1e-6))


def axis_chamfer_loss(skeleton: torch.Tensor, axes: torch.Tensor,
                      selection: torch.Tensor) -> torch.Tensor:
    """Chamfer distance between skeleton points and the selected primitives' axes.

    skeleton (M, 3); axes (K, S, 3) points sampled along each axis; selection (K,).
    Skeleton -> axes asks every part of the medial axis to be covered by some selected
    axis; axes -> skeleton keeps each selected axis on the medial axis (weighted by
    its selection so that dropped primitives are free).
    """
    K, S, _ = axes.shape
    d2 = torch.cdist(skeleton, axes.reshape(K * S, 3)) ** 2  # (M, K*S)
    # A dropped primitive should not cover the skeleton: push its points away.
    penalty = (1.0 - selection).repeat_interleave(S)[None, :]
    to_axes = torch.min(d2 + penalty, dim=1).values.mean()
    per_axis = torch.min(d2, dim=0).values.reshape(K, S).mean(dim=1)  # (K,)
    to_skeleton = (per_axis * selection).sum() / (selection.sum() + 1e-6)
    return to_axes + to_skeleton


def fold_loss(bend: torch.Tensor, scale: torch.Tensor, profile: torch.Tensor,
              limit: float = FOLD_LIMIT) -> torch.Tensor:
    """Mean squared excess of the sweeps' fold measure over `limit`.

    bend (K, S, 2): the axes' curvature vector along U and V at S stations
    (AnalyticSweeper.occupancy_and_bend); scale (K, S): f(t) there; profile (K, 3): a, b,
    d. A profile point o moves along the axis at the rate 1 - f o.kN, so the sweep folds
    onto itself where the profile's support in the direction of f kN -- (|a q_u|^p +
    |b q_v|^p)^(1/p) for the superellipse of exponent d, p = d / (d - 1) -- passes 1
    (docs/primitive.md, folding). Where it folds, the tube's surface turns inside out
    and the solid grows fins, which no abstraction of a shape needs.
    """
    q = bend * scale[..., None]
    a, b, d = (profile[:, i : i + 1] for i in range(3))
    d = torch.clamp(d, min=1.1)
    p = d / (d - 1.0)
    reach = ((a * q[..., 0]).abs() + 1e-12) ** p + ((b * q[..., 1]).abs() + 1e-12) ** p
    return torch.mean(torch.relu(reach ** (1.0 / p) - limit) ** 2)


def outside_axis_loss(axes: torch.Tensor, outside: torch.Tensor,
                      margin: float = AXIS_MARGIN) -> torch.Tensor:
    """Mean excess over `margin` of the distance from the shape to the axes' points.

    axes (K, S, 3): points along each axis, in the normalised frame; outside (R, R, R):
    each cell centre's distance to the shape in normalised units (0 inside), indexed
    [ix, iy, iz] over [-0.5, 0.5]^3, read between centres trilinearly. Where a sweep's
    tail leaves the shape thinner than a cell, no cell centre and hardly a sample lies
    inside it, so the cross-entropy has nothing to pull it back with; its axis does.
    """
    K, S, _ = axes.shape
    # grid_sample reads (x, y, z) as (W, H, D): the last index first.
    where = (2.0 * axes).flip(-1).reshape(1, 1, 1, K * S, 3)
    grid = outside.to(axes.dtype)[None, None]
    distance = torch.nn.functional.grid_sample(grid, where, mode="bilinear",
                                               padding_mode="border", align_corners=False)
    return torch.mean(torch.relu(distance.reshape(K, S) - margin))
