"""Refinement: the fitted primitives' parameters optimised directly against the shape.

The network stage of the fit (fit.py) finds the structure: which primitives, roughly
where. Two things limit how closely it follows the shape. Its sweeper is soft (a
boundary band about a voxel wide), so a thin limb comes out fatter than the soft
occupancy suggests once it is swept exactly; and its samples lie near the shape's
surface or uniformly in the cube, so a primitive that bulges far out of the shape is
seen by only a few of them. Refinement takes the kept primitives and optimises their
parameters themselves (through the unconstrained form of ParamLayout, so they stay in
range) with Adam on the binary cross-entropy of the soft union:

- on the points where the result is decided: the cell centres of the fitting grid within
  `band` cells of the shape or of the current abstraction (labelled by the shape's
  inside test at the cell centres), plus the near-surface fitting samples;
- with the analytic sweeper's sharpness annealed geometrically towards the exact test
  (the neural sweeper has no sharpness to anneal, so refinement always uses the
  analytic one);
- the band is recomputed, and the result scored, with the exact inside test every
  `refresh` steps; the best state by that score is what is returned.

Then `prune` drops, one at a time, every primitive whose removal costs at most
`min_gain` of the score: primitives that add next to nothing cost the user attention.

Last, residual rounds look at what the union misses: while the budget of primitives
allows, new primitives are warm-started (as the fit's are, from the medial axis) on the
biggest missed parts; at the budget, the primitive that adds least is swapped for one
on the biggest missed part when that part could add more. Each round is refined and
pruned again and kept only if it raises the score.

The score is the IoU over the labelled points (grid cells and near-surface samples) --
the grid IoU of DESIGN.md section 3, with the thin parts that fall between cell centres
and the surface detail counted too -- plus `surface_weight` times the surface coverage:
the share of the shape's surface samples that have a point of the union within `reach`.
IoU alone is ruled by bulk: a ninth primitive's worth of body volume outweighs a whole
thin limb, yet the missed limb is what the surface metrics (F1, Chamfer) count.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import torch
from scipy import ndimage as ndi
from scipy import sparse
from scipy.spatial import cKDTree

from sweepedit.analysis.metrics import iou
from sweepedit.analysis.skeleton import compute_skeleton
from sweepedit.fitting.losses import boltzmann_union
from sweepedit.fitting.params import ParamLayout
from sweepedit.fitting.sweepers import AnalyticSweeper
from sweepedit.fitting.warmstart import warm_start_primitives
from sweepedit.geometry.inside import grid_points, inside_primitives
from sweepedit.geometry.model import SweepPrimitive

# How near (normalised units) a point of the union must be for a surface sample to count
# as covered: within F1@0.05's threshold, so a limb must be followed, not just neared.
SURFACE_REACH = 0.03


@dataclass(frozen=True)
class RefineSettings:
    """How to refine: steps, Adam's step on the unconstrained parameters, the sharpness
    schedule (from `start_sharpness`, times `sharpness_gain` by the end), points per step
    (`cells` grid cells, `samples` near-surface samples), band width in cells, how
    often (steps) the band and the score are recomputed, and what a primitive must add
    to the score to be kept."""

    iterations: int = 300
    learning_rate: float = 0.02
    start_sharpness: float = 100.0
    sharpness_gain: float = 8.0
    # More near-surface samples than grid cells: the surface's fine detail (F1@0.01)
    # gains more from them than the volume (IoU) loses (measured in BENCHMARKS.md).
    cells: int = 2048
    samples: int = 4096
    band: int = 2
    refresh: int = 25
    # A primitive must add more than this to the score to be kept (see `prune`).
    min_gain: float = 0.001
    # Rounds that add primitives for missed parts (while the budget allows), and the
    # steps of each.
    residual_rounds: int = 2
    residual_iterations: int = 150
    # Missed pieces smaller than this (cells) get no primitive of their own.
    min_missed_cells: int = 12

    @property
    def total_steps(self) -> int:
        """Steps of refinement at most (first pass and every residual round)."""
        return self.iterations + self.residual_rounds * self.residual_iterations


class ScoringPoints:
    """The labelled points that refinement fits and scores: grid cell centres and the
    near-surface samples; and the shape's surface samples that the score's coverage
    term counts.

    grid_target (R, R, R) bool: the shape's inside test at the cell centres.
    samples (S, 3) float and sample_labels (S,) float in {0, 1}: near-surface samples.
    locked: primitives that stay fixed; their exact occupancy is computed once.
    surface (M, 3) float: samples of the shape's surface; a sample counts as covered
    when a labelled point within `reach` is inside the union. None (or surface_weight
    0): the score is the IoU alone.
    """

    def __init__(self, grid_target: np.ndarray, samples: np.ndarray,
                 sample_labels: np.ndarray, locked: Sequence[SweepPrimitive] = (), *,
                 surface: np.ndarray | None = None, reach: float = SURFACE_REACH,
                 surface_weight: float = 0.0) -> None:
        self.resolution = grid_target.shape[0]
        self.grid_target = np.asarray(grid_target, dtype=bool)
        self.cells = grid_points(self.resolution)  # (R^3, 3)
        self.points = np.concatenate([self.cells, np.asarray(samples, dtype=np.float64)])
        self.labels = np.concatenate([self.grid_target.reshape(-1),
                                      np.asarray(sample_labels) > 0.5])
        self.n_cells = self.cells.shape[0]
        self.locked = (inside_primitives(self.points, locked).any(axis=0) if locked
                       else np.zeros(len(self.points), dtype=bool))
        self.surface_weight = surface_weight if surface is not None and len(surface) else 0.0
        self.reach_matrix = (_reach_matrix(np.asarray(surface, dtype=np.float64), self.points,
                                           reach) if self.surface_weight else None)

    def occupancy(self, primitives: Sequence[SweepPrimitive]) -> np.ndarray:
        """Exact occupancy of each primitive at every point: (K, N) bool."""
        return inside_primitives(self.points, primitives)

    def score(self, covered: np.ndarray) -> float:
        """IoU over all the points of a union's occupancy covered (N,) bool (locked
        added), plus surface_weight times its surface coverage."""
        score = self.iou(covered)
        if self.surface_weight:
            score += self.surface_weight * self.surface_coverage(covered)
        return score

    def iou(self, covered: np.ndarray) -> float:
        """IoU over all the points of covered (N,) bool (locked added)."""
        return iou(covered | self.locked, self.labels)

    def surface_coverage(self, covered: np.ndarray) -> float:
        """Share of the surface samples with a point of covered (N,) bool (locked added)
        within reach; 1.0 without surface samples."""
        if self.reach_matrix is None:
            return 1.0
        hits = self.reach_matrix @ (covered | self.locked).astype(np.float32)
        return float(np.count_nonzero(hits) / len(hits))

    def grid_iou(self, covered: np.ndarray) -> float:
        """IoU on the grid cells alone (DESIGN.md section 3) of covered (N,) bool."""
        return iou((covered | self.locked)[: self.n_cells], self.labels[: self.n_cells])

    def band_cells(self, covered: np.ndarray, width: int) -> np.ndarray:
        """Flat indices of the cells within `width` cells of the shape or of the union
        covered (N,) bool: where the result is decided."""
        grid = covered[: self.n_cells].reshape(self.grid_target.shape) | self.grid_target
        return np.flatnonzero(ndi.binary_dilation(grid, iterations=width))


def _reach_matrix(surface: np.ndarray, points: np.ndarray, reach: float) -> sparse.csr_matrix:
    """(M, N) sparse 0/1: which of points (N, 3) lie within reach of each of surface (M, 3)."""
    neighbours = cKDTree(points).query_ball_point(surface, reach)
    lengths = np.fromiter((len(n) for n in neighbours), dtype=np.int64, count=len(neighbours))
    indices = np.fromiter((i for n in neighbours for i in n), dtype=np.int64,
                          count=int(lengths.sum()))
    indptr = np.concatenate([[0], np.cumsum(lengths)])
    return sparse.csr_matrix((np.ones(len(indices), dtype=np.float32), indices, indptr),
                             shape=(len(surface), len(points)))


def prune(occupancy: np.ndarray, points: ScoringPoints, min_gain: float = 0.0) -> list[int]:
    """Indices of the primitives to keep: drop, one at a time, the primitive whose removal
    costs the least score, while that cost is at most min_gain. occupancy (K, N) bool."""
    keep = list(range(occupancy.shape[0]))
    while len(keep) > 1:
        costs = removal_costs(occupancy[keep], points)
        cheapest = int(np.argmin(costs))
        if costs[cheapest] > min_gain:
            break
        del keep[cheapest]
    return keep


def removal_costs(occupancy: np.ndarray, points: ScoringPoints) -> np.ndarray:
    """(K,) how much the score drops without each primitive; occupancy (K, N) bool."""
    full = points.score(occupancy.any(axis=0))
    return np.array([full - points.score(np.delete(occupancy, i, axis=0).any(axis=0))
                     for i in range(occupancy.shape[0])])


def missed_parts(points: ScoringPoints, covered: np.ndarray, min_cells: int) -> np.ndarray:
    """(R, R, R) bool: the cells of the shape that the union covered (N,) bool misses,
    in 26-connected pieces of at least min_cells cells."""
    missed = points.grid_target & ~(covered | points.locked)[: points.n_cells].reshape(
        points.grid_target.shape)
    labels, n = ndi.label(missed, np.ones((3, 3, 3), dtype=bool))
    if n == 0:
        return missed
    sizes = np.bincount(labels.ravel(), minlength=n + 1)
    big = np.flatnonzero(sizes >= min_cells)
    return np.isin(labels, big[big > 0])


def residual_primitives(missed: np.ndarray, budget: int,
                        layout: ParamLayout) -> list[SweepPrimitive]:
    """Up to `budget` new primitives for the missed cells (R, R, R) bool (`missed_parts`),
    warm-started as the fit's warm start is: from their medial axis."""
    if budget <= 0 or not missed.any():
        return []
    skeleton = compute_skeleton(missed)
    return warm_start_primitives(skeleton.branches, budget, layout.n_control_points,
                                 layout.n_scaling)


StepCallback = Callable[[int, dict[str, float], list[SweepPrimitive]], None]


def refine_primitives(primitives: Sequence[SweepPrimitive], layout: ParamLayout,
                      points: ScoringPoints, settings: RefineSettings | None = None, *,
                      budget: int | None = None, seed: int = 0,
                      cancel: threading.Event | None = None,
                      on_step: StepCallback | None = None,
                      report_every: int = 10) -> tuple[list[SweepPrimitive], float]:
    """Refine primitives (all of `layout`) against the scoring points and prune them; then,
    for up to `settings.residual_rounds` rounds, try to cover the missed parts: while
    fewer than `budget` (default: as many as given) are kept, add primitives for the
    biggest missed parts (`residual_primitives`); at the budget, swap the primitive that
    adds least for one on the biggest missed part. Each trial is refined and pruned, and
    kept only if it raises the score.

    on_step(step, losses, current primitives) is called every `report_every` steps and
    at the last step of each pass; steps count on across the passes, up to
    `settings.total_steps`. Returns the best primitives found (never worse by the score
    than the input) and their score.
    """
    settings = settings or RefineSettings()
    cancel = cancel or threading.Event()
    budget = len(primitives) if budget is None else budget
    rng = np.random.default_rng(seed)
    prims, occupancy = _refine_pass(list(primitives), layout, points, settings,
                                    settings.iterations, rng, cancel, on_step, 0, report_every)
    offset = settings.iterations
    for _ in range(settings.residual_rounds):
        if cancel.is_set() or not prims:
            break
        covered = occupancy.any(axis=0)
        missed = missed_parts(points, covered, settings.min_missed_cells)
        free = budget - len(prims)
        if free > 0:
            new = residual_primitives(missed, free, layout)
            trial = prims + new
        else:
            # At the budget: swap the primitive that adds least for one on the biggest
            # missed part, when that part could add more than the primitive does.
            costs = removal_costs(occupancy, points)
            victim = int(np.argmin(costs))
            union = (covered | points.locked | points.labels)[: points.n_cells]
            gain_bound = (np.count_nonzero(missed) / max(np.count_nonzero(union), 1)
                          + points.surface_weight * (1.0 - points.surface_coverage(covered)))
            new = residual_primitives(missed, 1, layout) if gain_bound > costs[victim] else []
            trial = [p for i, p in enumerate(prims) if i != victim] + new
        if not new:
            break  # nothing missed worth a primitive: another pass would refine the same
        trial_prims, trial_occupancy = _refine_pass(trial, layout, points, settings,
                                                    settings.residual_iterations, rng, cancel,
                                                    on_step, offset, report_every)
        offset += settings.residual_iterations
        if points.score(trial_occupancy.any(axis=0)) <= points.score(covered):
            break  # the next round would try much the same again
        prims, occupancy = trial_prims, trial_occupancy
    return prims, points.score(occupancy.any(axis=0))


def _refine_pass(prims: list[SweepPrimitive], layout: ParamLayout, points: ScoringPoints,
                 settings: RefineSettings, iterations: int, rng: np.random.Generator,
                 cancel: threading.Event, on_step: StepCallback | None, offset: int,
                 report_every: int) -> tuple[list[SweepPrimitive], np.ndarray]:
    """One pass of Adam on the primitives' parameters, then `prune`: the kept primitives
    of the best state seen and their exact occupancy (K', N) bool."""
    occupancy = points.occupancy(prims)
    best_score, best_prims, best_occupancy = points.score(occupancy.any(axis=0)), prims, occupancy
    if not prims:
        return prims, occupancy
    logits = layout.to_unconstrained(layout.from_primitives(prims, dtype=torch.float32))
    logits = logits.clone().requires_grad_(True)
    optimizer = torch.optim.Adam([logits], lr=settings.learning_rate)
    sweeper = AnalyticSweeper(sharpness=settings.start_sharpness)
    sweeper.layout = layout
    all_points = torch.as_tensor(points.points, dtype=torch.float32)
    all_labels = torch.as_tensor(points.labels, dtype=torch.float32)
    locked = torch.as_tensor(points.locked, dtype=torch.float32)
    n_samples = len(points.points) - points.n_cells
    band = points.band_cells(occupancy.any(axis=0), settings.band)
    for step in range(iterations):
        if cancel.is_set():
            break
        progress = step / max(iterations - 1, 1)
        sweeper.sharpness = settings.start_sharpness * settings.sharpness_gain ** progress
        index = band[rng.integers(0, len(band), settings.cells)]
        if n_samples:
            index = np.concatenate([index, points.n_cells
                                    + rng.integers(0, n_samples, settings.samples)])
        idx = torch.as_tensor(index)
        loss = _step_loss(sweeper, layout, logits, all_points[idx], all_labels[idx], locked[idx])
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        if torch.isfinite(loss) and bool(torch.isfinite(logits.grad).all()):
            optimizer.step()
        last = step == iterations - 1
        if (step + 1) % settings.refresh == 0 or last:
            current = _valid_primitives(layout, logits.detach(), prims)
            if current is not None:
                occupancy = points.occupancy(current)
                covered = occupancy.any(axis=0)
                score = points.score(covered)
                if score > best_score:
                    best_score, best_prims, best_occupancy = score, current, occupancy
                band = points.band_cells(covered, settings.band)
        if on_step is not None and (step % report_every == 0 or last):
            on_step(offset + step, {"refine": float(loss.detach())},
                    _valid_primitives(layout, logits.detach(), prims) or best_prims)
    keep = prune(best_occupancy, points, settings.min_gain)
    return [best_prims[i] for i in keep], best_occupancy[keep]


def _step_loss(sweeper: AnalyticSweeper, layout: ParamLayout, logits: torch.Tensor,
               queries: torch.Tensor, labels: torch.Tensor, locked: torch.Tensor) -> torch.Tensor:
    """BCE of the soft union (locked primitives as a fixed member) at queries (Q, 3)."""
    params = layout.from_unconstrained(logits)  # (K, P)
    occupancy = sweeper(params[None], queries[None])  # (1, K, Q)
    occupancy = torch.cat([occupancy, locked[None, None]], dim=1)
    union = boltzmann_union(occupancy, torch.ones(1, occupancy.shape[1]))
    eps = 1e-5
    return torch.nn.functional.binary_cross_entropy(union[0].clamp(eps, 1 - eps), labels)


def _valid_primitives(layout: ParamLayout, logits: torch.Tensor,
                      template: Sequence[SweepPrimitive]) -> list[SweepPrimitive] | None:
    """The primitives of logits (K, P), with the template's names, colours and flags; None
    if any value is not finite or any primitive fails validation."""
    if not bool(torch.isfinite(logits).all()):
        return None
    out = []
    for new, old in zip(layout.to_primitives(layout.from_unconstrained(logits).double()),
                        template, strict=True):
        new.name, new.color, new.visible, new.locked = old.name, old.color, old.visible, \
            old.locked
        try:
            new.validate()
        except ValueError:
            return None
        out.append(new)
    return out


