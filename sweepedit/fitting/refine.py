"""Refinement: the fitted primitives' parameters optimised directly against the shape.

The network stage of the fit (fit.py) finds the structure: which primitives, roughly
where. Two things limit how closely it follows the shape. Its sweeper is soft (a
boundary band about a voxel wide), so a thin limb comes out fatter than the soft
occupancy suggests once it is swept exactly; and its samples lie near the shape's
surface or uniformly in the cube, so a primitive that bulges far out of the shape is
seen by only a few of them. Refinement takes the kept primitives and optimises their
parameters themselves (through the unconstrained form of ParamLayout, so they stay in
range) with Adam on the binary cross-entropy of the soft union:

- on the points where the gradient is: the cell centres of the fitting grid within
  `band` cells of the shape's or the current union's boundary, or where the two
  disagree (labelled by the shape's inside test at the cell centres), plus the
  near-surface fitting samples. Cells deep inside both are left out: the soft
  occupancy is saturated there (sampling the whole interior, as before, spent most
  steps on them: on 8 benchmark shapes the shell raised mean IoU 0.810 -> 0.823);
- with the analytic sweeper's sharpness annealed geometrically towards the exact test
  (the neural sweeper has no sharpness to anneal, so refinement always uses the
  analytic one);
- the band is recomputed, and the result scored, with the exact inside test every
  `refresh` steps (on the shell where the union can have moved); the best state by
  that score is what is returned, and a pass ends once `patience` refreshes in a row
  have not raised it.

Then `prune` drops, one at a time, every primitive whose removal costs at most
`min_gain` of the score: primitives that add next to nothing cost the user attention.

Last, residual rounds look at what the union misses: while the budget of primitives
allows, new primitives are warm-started (as the fit's are, from the medial axis) on the
biggest missed parts; at the budget, the primitive that adds least is swapped for one
on the biggest missed part when that part could add more. Each round is refined and
pruned again and kept only if it raises the score.

The score is the IoU over the labelled points (grid cells and near-surface samples) --
the grid IoU of docs/quality.md, with the thin parts that fall between cell centres
and the surface detail counted too -- plus `surface_weight` times the surface coverage:
the share of the shape's surface samples that have a point of the union within `reach`.
IoU alone is ruled by bulk: a ninth primitive's worth of body volume outweighs a whole
thin limb, yet the missed limb is what the surface metrics (F1, Chamfer) count.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field

import numpy as np
import torch
from scipy import ndimage as ndi
from scipy import sparse
from scipy.spatial import cKDTree
from threadpoolctl import threadpool_limits

from sweepedit.analysis.metrics import iou
from sweepedit.analysis.skeleton import compute_skeleton
from sweepedit.fitting.losses import boltzmann_union, fold_loss, outside_axis_loss
from sweepedit.fitting.params import ParamLayout
from sweepedit.fitting.sweepers import AnalyticSweeper
from sweepedit.fitting.warmstart import warm_start_primitives
from sweepedit.geometry.inside import T_SAMPLES, grid_points, inside_primitives, inside_union
from sweepedit.geometry.model import SweepPrimitive
from sweepedit.geometry.sweep import axis_points, scaling_factor

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
    # Adam's step: 0.02 -> 0.04 raised the 30 benchmark shapes at K = 8 from IoU 0.839 to
    # 0.847 and F1@0.01 0.802 -> 0.822 in the same steps (0.03, 0.05 on 8 shapes: below,
    # level); fewer steps at 0.04 lost more than that.
    learning_rate: float = 0.04
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
    # A pass ends early once this many exact refreshes in a row have not raised the
    # score: later steps only polish what the next refresh would reject anyway.
    patience: int = 3
    # Axis stations of the analytic sweeper while refining (its bracket search, a dense
    # primitives x points x stations pass, is ~40 % of a step; 32 stations were 15 %
    # faster but lost a little IoU and F1@0.01 on 8 benchmark shapes).
    stations: int = 48
    # Exact-test samples along the axis while scoring refreshes (the metric's test uses
    # 256; scoring only ranks states of one fit, and its cost is linear in this).
    scoring_t_samples: int = 128
    # Where the steps run: "cpu" or a torch device such as "cuda" (the exact scoring
    # stays on the CPU).
    device: str = "cpu"
    # Weight of losses.fold_loss against the cross-entropy: keeps the axes from bending
    # tighter than the profile's reach, where a sweep folds onto itself.
    fold_weight: float = 0.0
    # Weight of losses.outside_axis_loss against the cross-entropy: keeps each axis
    # within the shape, where the grid cannot see a thin tail.
    axis_weight: float = 0.0
    # Points per axis that outside_axis_loss measures.
    axis_samples: int = 32

    # Steps of each pass for 8 primitives, and more for more (pass_steps); else as set.
    steps_per_8: bool = False

    def total_steps(self, n_primitives: int = 8) -> int:
        """Steps of refinement at most (first pass and every residual round) for
        about n_primitives."""
        return (pass_steps(self, n_primitives, first=True)
                + self.residual_rounds * pass_steps(self, n_primitives, first=False))


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
    shell (2L, 3) float and shell_labels (2L,) bool: pairs of points a little inside and
    outside the shape's surface (Shape.shell_samples), tested with the rest; the share
    on their right side, weighted by shell_weight, joins the score: a sub-voxel measure
    of where the union's boundary lies (the grid's cells are 0.016 wide, F1@0.01 asks
    for 0.01).
    """

    def __init__(self, grid_target: np.ndarray, samples: np.ndarray,
                 sample_labels: np.ndarray, locked: Sequence[SweepPrimitive] = (), *,
                 surface: np.ndarray | None = None, reach: float = SURFACE_REACH,
                 surface_weight: float = 0.0, shell: np.ndarray | None = None,
                 shell_labels: np.ndarray | None = None, shell_weight: float = 0.0) -> None:
        self.resolution = grid_target.shape[0]
        self.grid_target = np.asarray(grid_target, dtype=bool)
        self.cells = grid_points(self.resolution)  # (R^3, 3)
        if shell is None or shell_labels is None or not shell_weight:
            shell, shell_labels, shell_weight = np.zeros((0, 3)), np.zeros(0, dtype=bool), 0.0
        self.points = np.concatenate([self.cells, np.asarray(samples, dtype=np.float64),
                                      np.asarray(shell, dtype=np.float64)])
        self.labels = np.concatenate([self.grid_target.reshape(-1),
                                      np.asarray(sample_labels) > 0.5,
                                      np.asarray(shell_labels, dtype=bool)])
        self.n_cells = self.cells.shape[0]
        # Cells and samples come first; the IoU and the steps' points are theirs.
        self.n_labelled = len(self.points) - len(shell)
        self.shell_weight = float(shell_weight)
        self.locked = (inside_primitives(self.points, locked).any(axis=0) if locked
                       else np.zeros(len(self.points), dtype=bool))
        self.surface_weight = surface_weight if surface is not None and len(surface) else 0.0
        self._target_bands: dict[int, np.ndarray] = {}
        self._outside: np.ndarray | None = None
        self.reach_matrix = (_reach_matrix(np.asarray(surface, dtype=np.float64),
                                           self.points[: self.n_labelled], reach)
                             if self.surface_weight else None)

    def occupancy(self, primitives: Sequence[SweepPrimitive],
                  t_samples: int = T_SAMPLES) -> np.ndarray:
        """Exact occupancy of each primitive at every point: (K, N) bool."""
        return inside_primitives(self.points, primitives, t_samples)

    def union_near(self, primitives: Sequence[SweepPrimitive], previous: np.ndarray,
                   width: int, t_samples: int = T_SAMPLES) -> np.ndarray:
        """The union's occupancy (N,) bool, tested exactly only where it can have changed
        since `previous` (N,) bool, the union of a state a few steps back: the cells
        within `width` cells of the shape's or that union's boundary (or labelled
        otherwise than it), and the near-surface samples. Elsewhere -- deep inside or
        far outside both -- the previous value stands: a primitive moves well under
        `width` cells between refreshes, and the shell is 3-5 times fewer points."""
        where = np.concatenate([self.boundary_cells(previous, width),
                                np.arange(self.n_cells, len(self.points))])
        covered = previous.copy()
        covered[where] = inside_union(self.points[where], primitives, t_samples)
        return covered

    def score(self, covered: np.ndarray) -> float:
        """IoU over the cells and samples of a union's occupancy covered (N,) bool
        (locked added), plus surface_weight times its surface coverage, plus
        shell_weight times its shell accuracy."""
        score = self.iou(covered)
        if self.surface_weight:
            score += self.surface_weight * self.surface_coverage(covered)
        if self.shell_weight:
            score += self.shell_weight * self.shell_accuracy(covered)
        return score

    def iou(self, covered: np.ndarray) -> float:
        """IoU over the cells and samples of covered (N,) bool (locked added)."""
        n = self.n_labelled
        return iou((covered | self.locked)[:n], self.labels[:n])

    def surface_coverage(self, covered: np.ndarray) -> float:
        """Share of the surface samples with a point of covered (N,) bool (locked added)
        within reach; 1.0 without surface samples."""
        if self.reach_matrix is None:
            return 1.0
        inside = (covered | self.locked)[: self.n_labelled]
        hits = self.reach_matrix @ inside.astype(np.float32)
        return float(np.count_nonzero(hits) / len(hits))

    def shell_accuracy(self, covered: np.ndarray) -> float:
        """Share of the shell points on their right side of covered (N,) bool's boundary
        (locked added); 1.0 without shell points."""
        if self.n_labelled == len(self.points):
            return 1.0
        n = self.n_labelled
        return float(np.mean((covered | self.locked)[n:] == self.labels[n:]))

    def outside_distance(self) -> np.ndarray:
        """(R, R, R) float: each cell centre's distance to the nearest cell of the shape,
        in normalised units (0 inside). The shape's cells are those inside it and those
        holding a sample labelled inside: a limb thinner than a cell covers no cell
        centre, and its axis must not count as outside."""
        if self._outside is None:
            shape = self.grid_target.copy()
            inside = self.points[self.n_cells:][self.labels[self.n_cells:]]
            index = np.clip(np.floor((inside + 0.5) * self.resolution).astype(np.int64), 0,
                            self.resolution - 1)
            shape[index[:, 0], index[:, 1], index[:, 2]] = True
            self._outside = ndi.distance_transform_edt(~shape) / self.resolution
        return self._outside

    def grid_iou(self, covered: np.ndarray) -> float:
        """IoU on the grid cells alone (docs/quality.md) of covered (N,) bool."""
        return iou((covered | self.locked)[: self.n_cells], self.labels[: self.n_cells])

    def boundary_cells(self, covered: np.ndarray, width: int) -> np.ndarray:
        """Flat indices of the cells where a step's gradient comes from: within `width`
        cells of the shape's or the union's boundary, or labelled otherwise than the
        union covered (N,) bool says. Cells deep inside (or outside) both are left out:
        the soft occupancy is saturated there, so they would cost a step without
        moving it."""
        union = covered[: self.n_cells].reshape(self.grid_target.shape) | self.locked[
            : self.n_cells].reshape(self.grid_target.shape)
        if width not in self._target_bands:  # the shape's band never changes
            self._target_bands[width] = _band(self.grid_target, width)
        near = self._target_bands[width] | _band(union, width)
        return np.flatnonzero(near | (union != self.grid_target))


def _band(grid: np.ndarray, width: int) -> np.ndarray:
    """(R, R, R) bool: the cells within `width` cells of the boundary of grid (R, R, R) bool."""
    return ndi.binary_dilation(grid, iterations=width) & ~ndi.binary_erosion(grid,
                                                                              iterations=width)


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


@dataclass
class RefineStep:
    """What refinement reports: `step` counts on across passes (up to the settings'
    total_steps); `stage` names the pass ("refinement", "residual round k of n") and
    `fraction` (0..1, monotone, 1 at the pass's end) how far it is; `primitives` are the
    current valid primitives."""

    step: int
    stage: str
    fraction: float
    losses: dict[str, float]
    primitives: list[SweepPrimitive]


StepCallback = Callable[[RefineStep], None]


@dataclass
class StageTimings:
    """Seconds spent per stage of a fit, summed over its passes and restarts (for the fit
    record and the bench's stage table)."""

    seconds: dict[str, float] = field(default_factory=dict)

    @contextmanager
    def measure(self, name: str) -> Iterator[None]:
        """Add the time the block takes to stage `name`."""
        started = time.perf_counter()
        try:
            yield
        finally:
            self.seconds[name] = self.seconds.get(name, 0.0) + time.perf_counter() - started


def _never() -> bool:
    return False


# Why refinement stopped adding primitives (RefineResult.stopped), in a user's words.
STOP_REASONS = {
    "accurate": "the surfaces agree within the tolerance",
    "nothing missed": "no part of the shape is left out that a primitive could cover",
    "no gain": "another primitive made the fit no better",
    "rounds": "the residual rounds were all used",
    "stopped": "cancelled or out of time",
}


@dataclass
class RefineResult:
    """What refine_primitives found: the primitives, their score and exact occupancy
    (K, N) bool at the scoring points, and why it stopped adding primitives (a key of
    STOP_REASONS)."""

    primitives: list[SweepPrimitive]
    score: float
    occupancy: np.ndarray
    stopped: str


def pass_steps(settings: RefineSettings, n_primitives: int, first: bool) -> int:
    """Steps of a pass over n_primitives: settings.iterations (the first pass) or
    settings.residual_iterations, each for 8 primitives when settings.steps_per_8 (a
    step's points are shared by all primitives, so more need more steps to move as
    far), else as they are."""
    steps = settings.iterations if first else settings.residual_iterations
    if settings.steps_per_8:
        steps = round(steps * max(1.0, n_primitives / 8.0))
    return steps


def refine_primitives(primitives: Sequence[SweepPrimitive], layout: ParamLayout,
                      points: ScoringPoints, settings: RefineSettings | None = None, *,
                      budget: int | None = None, seed: int = 0,
                      stop: Callable[[], bool] = _never,
                      on_step: StepCallback | None = None,
                      report_every: int = 10,
                      timings: StageTimings | None = None,
                      accurate: Callable[[list[SweepPrimitive]], bool] | None = None,
                      ) -> RefineResult:
    """Refine primitives (all of `layout`) against the scoring points and prune them; then,
    for up to `settings.residual_rounds` rounds, try to cover the missed parts: while
    fewer than `budget` (default: as many as given) are kept, add primitives for the
    biggest missed parts (`residual_primitives`); at the budget, swap the primitive that
    adds least for one on the biggest missed part. Each trial is refined and pruned, and
    kept only if it raises the score. With `accurate`, no round starts once it holds
    for the primitives (the automatic count: add primitives until the fit is accurate).

    stop() is polled every step (cancel, time limit): a pass that is stopped keeps its
    best state so far, and no further round starts. on_step gets a RefineStep every
    `report_every` steps and at the end of each pass. The primitives are the best found
    (never worse by the score than the input).
    """
    settings = settings or RefineSettings()
    timings = timings or StageTimings()
    budget = len(primitives) if budget is None else budget
    rng = np.random.default_rng(seed)
    rounds = settings.residual_rounds
    steps = pass_steps(settings, len(primitives), first=True)
    prims, occupancy = _refine_pass(list(primitives), layout, points, settings, steps, rng,
                                    stop, on_step, 0, report_every, "refinement", timings)
    offset = steps
    stopped = "rounds"
    for k in range(rounds):
        if stop() or not prims:
            stopped = "stopped"
            break
        if accurate is not None:
            with timings.measure("residual rounds"):
                if accurate(prims):
                    stopped = "accurate"
                    break
        with timings.measure("residual rounds"):
            covered = occupancy.any(axis=0)
            missed = missed_parts(points, covered, settings.min_missed_cells)
            free = budget - len(prims)
            if free > 0:
                new = residual_primitives(missed, free, layout)
                kept, kept_rows = prims, occupancy
            else:
                # At the budget: swap the primitive that adds least for one on the
                # biggest missed part, when that part could add more than it does.
                costs = removal_costs(occupancy, points)
                victim = int(np.argmin(costs))
                union = (covered | points.locked | points.labels)[: points.n_cells]
                gain_bound = (np.count_nonzero(missed) / max(np.count_nonzero(union), 1)
                              + points.surface_weight
                              * (1.0 - points.surface_coverage(covered))
                              + points.shell_weight * (1.0 - points.shell_accuracy(covered)))
                new = (residual_primitives(missed, 1, layout) if gain_bound > costs[victim]
                       else [])
                kept = [p for i, p in enumerate(prims) if i != victim]
                kept_rows = np.delete(occupancy, victim, axis=0)
            if new:  # the kept primitives' exact rows are known: only the new are tested
                trial_start = np.concatenate([kept_rows, points.occupancy(
                    new, settings.scoring_t_samples)])
        if not new:
            # Nothing missed worth a primitive: another pass would refine the same.
            stopped = "nothing missed"
            break
        trial = kept + new
        # All primitives move in the round: with the old ones frozen (5x cheaper) the
        # many-limbed shapes lost F1@0.05, the body making no room for a new limb.
        steps = pass_steps(settings, len(trial), first=False)
        trial_prims, trial_occupancy = _refine_pass(
            trial, layout, points, settings, steps, rng, stop, on_step,
            offset, report_every, f"residual round {k + 1} of {rounds}", timings,
            timing_name="residual rounds", start_occupancy=trial_start)
        offset += steps
        if points.score(trial_occupancy.any(axis=0)) <= points.score(covered):
            stopped = "stopped" if stop() else "no gain"
            break  # the next round would try much the same again
        prims, occupancy = trial_prims, trial_occupancy
    return RefineResult(prims, points.score(occupancy.any(axis=0)), occupancy, stopped)


def _refine_pass(prims: list[SweepPrimitive], layout: ParamLayout, points: ScoringPoints,
                 settings: RefineSettings, iterations: int, rng: np.random.Generator,
                 stop: Callable[[], bool], on_step: StepCallback | None, offset: int,
                 report_every: int, stage: str, timings: StageTimings,
                 timing_name: str = "refinement", start_occupancy: np.ndarray | None = None,
                 ) -> tuple[list[SweepPrimitive], np.ndarray]:
    """One pass of Adam on the primitives' parameters, then `prune`: the kept primitives
    of the best state seen and their exact occupancy (K', N) bool. Ends early when
    `settings.patience` exact refreshes in a row do not raise the score, or on stop().
    start_occupancy (K, N) bool: prims' exact occupancy, when known."""
    with timings.measure(timing_name):
        best_prims, best_occupancy = _optimise(prims, layout, points, settings, iterations, rng,
                                               stop, on_step, offset, report_every, stage,
                                               start_occupancy)
    with timings.measure("pruning"):
        keep = prune(best_occupancy, points, settings.min_gain)
    return [best_prims[i] for i in keep], best_occupancy[keep]


def optimise_primitives(primitives: Sequence[SweepPrimitive], layout: ParamLayout,
                        points: ScoringPoints, settings: RefineSettings, iterations: int,
                        rng: np.random.Generator, stop: Callable[[], bool] = _never,
                        on_step: StepCallback | None = None, *, report_every: int = 10,
                        stage: str = "refinement", offset: int = 0,
                        ) -> tuple[list[SweepPrimitive], np.ndarray]:
    """Adam on the given primitives' parameters alone: no pruning, no residual rounds,
    the points' locked primitives a fixed member of the union (refit of a selection).
    Returns the best state by the exact score (the input's at worst) and its exact
    occupancy (K, N) bool."""
    return _optimise(list(primitives), layout, points, settings, iterations, rng, stop,
                     on_step, offset, report_every, stage)


# numpy's BLAS on one thread while a pass runs: the exact test's matmuls between the
# steps are small, and a second OpenBLAS thread fought torch's OpenMP threads for the two
# cores (glyph_8: whole fit 15.6 -> 14.2 s, the same result). Here, the fit and the refit
# of a selection both get it.
@threadpool_limits.wrap(limits=1, user_api="blas")
def _optimise(prims: list[SweepPrimitive], layout: ParamLayout, points: ScoringPoints,
              settings: RefineSettings, iterations: int, rng: np.random.Generator,
              stop: Callable[[], bool], on_step: StepCallback | None, offset: int,
              report_every: int, stage: str, occupancy: np.ndarray | None = None,
              ) -> tuple[list[SweepPrimitive], np.ndarray]:
    """The Adam steps of a pass: the best state by the exact score (the input's at worst)
    and its exact occupancy (K, N) bool. occupancy (K, N) bool: prims' own, when known."""
    if occupancy is None:
        occupancy = points.occupancy(prims, settings.scoring_t_samples)
    best_score = points.score(occupancy.any(axis=0))
    best_prims: list[SweepPrimitive] = prims
    best_occupancy: np.ndarray | None = occupancy
    if not prims:
        return prims, occupancy
    device = torch.device(settings.device)
    logits = layout.to_unconstrained(layout.from_primitives(prims, dtype=torch.float32,
                                                            device=device))
    logits = logits.clone().requires_grad_(True)
    optimizer = Adam(logits, lr=settings.learning_rate)
    sweeper = AnalyticSweeper(sharpness=settings.start_sharpness, stations=settings.stations)
    sweeper.layout = layout
    all_points = torch.as_tensor(points.points, dtype=torch.float32, device=device)
    all_labels = torch.as_tensor(points.labels, dtype=torch.float32, device=device)
    locked = torch.as_tensor(points.locked, dtype=torch.float32, device=device)
    n_samples = points.n_labelled - points.n_cells
    covered = occupancy.any(axis=0)
    band = points.boundary_cells(covered, settings.band)
    stale = 0
    loss = torch.zeros(())
    outside = axis_t = None
    if settings.axis_weight:
        outside = torch.as_tensor(points.outside_distance(), dtype=torch.float32,
                                  device=device)
        axis_t = torch.linspace(0.0, 1.0, settings.axis_samples, device=device)
    for step in range(iterations):
        if stop():
            break
        progress = step / max(iterations - 1, 1)
        sweeper.sharpness = settings.start_sharpness * settings.sharpness_gain ** progress
        index = band[rng.integers(0, len(band), settings.cells)]
        if n_samples:
            index = np.concatenate([index, points.n_cells
                                    + rng.integers(0, n_samples, settings.samples)])
        idx = torch.as_tensor(index, device=device)
        loss = _step_loss(sweeper, layout, logits, all_points[idx], all_labels[idx], locked[idx],
                          settings.fold_weight, settings.axis_weight, outside, axis_t)
        logits.grad = None
        loss.backward()
        if bool(torch.isfinite(loss) & torch.isfinite(logits.grad).all()):
            optimizer.step()
        last = step == iterations - 1
        if (step + 1) % settings.refresh == 0 or last:
            current = _valid_primitives(layout, logits.detach(), prims)
            if current is not None:
                # Refreshes test the shell where the union can have moved; the best
                # state is tested everywhere once, at the end of the pass.
                covered = points.union_near(current, covered, settings.band + 2,
                                            settings.scoring_t_samples)
                score = points.score(covered)
                if score > best_score:
                    best_score, best_prims, best_occupancy = score, current, None
                    stale = 0
                else:
                    stale += 1
                band = points.boundary_cells(covered, settings.band)
            if stale >= settings.patience:
                last = True
        if on_step is not None and (step % report_every == 0 or last):
            on_step(RefineStep(offset + step, stage, 1.0 if last else progress,
                               {"refine": float(loss.detach())},
                               _valid_primitives(layout, logits.detach(), prims)
                               or best_prims))
        if last:
            break
    if best_occupancy is None:
        best_occupancy = points.occupancy(best_prims, settings.scoring_t_samples)
    return best_prims, best_occupancy


class Adam:
    """Adam on one tensor, the same update as torch.optim.Adam's defaults (betas 0.9,
    0.999, eps 1e-8). Its own few lines because torch.optim's first optimizer imports
    torch._dynamo (1.5 s idle, 4 s on a busy machine): a tenth of a whole `sweepedit fit`
    and of the app's first abstraction, for an update that refinement needs no more of."""

    def __init__(self, param: torch.Tensor, lr: float, betas: tuple[float, float] = (0.9, 0.999),
                 eps: float = 1e-8) -> None:
        self.param, self.lr, self.betas, self.eps = param, lr, betas, eps
        self.exp_avg = torch.zeros_like(param)
        self.exp_avg_sq = torch.zeros_like(param)
        self.steps = 0

    @torch.no_grad()
    def step(self) -> None:
        """One update of param from its .grad."""
        grad = self.param.grad
        beta1, beta2 = self.betas
        self.steps += 1
        self.exp_avg.lerp_(grad, 1.0 - beta1)
        self.exp_avg_sq.mul_(beta2).addcmul_(grad, grad, value=1.0 - beta2)
        step_size = self.lr / (1.0 - beta1 ** self.steps)
        denom = (self.exp_avg_sq.sqrt() / math.sqrt(1.0 - beta2 ** self.steps)).add_(self.eps)
        self.param.addcdiv_(self.exp_avg, denom, value=-step_size)


def _step_loss(sweeper: AnalyticSweeper, layout: ParamLayout, logits: torch.Tensor,
               queries: torch.Tensor, labels: torch.Tensor, locked: torch.Tensor,
               fold_weight: float = 0.0, axis_weight: float = 0.0,
               outside: torch.Tensor | None = None,
               axis_t: torch.Tensor | None = None) -> torch.Tensor:
    """BCE of the soft union (locked primitives as a fixed member) at queries (Q, 3),
    plus fold_weight times the primitives' fold_loss, plus axis_weight times their
    outside_axis_loss at axis_t (S,) against the shape's outside (R, R, R) distance."""
    params = layout.from_unconstrained(logits)  # (K, P)
    occupancy, bend = sweeper.occupancy_and_bend(params[None], queries[None])  # (1, K, Q)
    occupancy = torch.cat([occupancy, locked[None, None]], dim=1)
    union = boltzmann_union(occupancy, torch.ones(1, occupancy.shape[1]))
    eps = 1e-5
    loss = torch.nn.functional.binary_cross_entropy(union[0].clamp(eps, 1 - eps), labels)
    control_points, profile, scaling = layout.split(params)
    if fold_weight:
        stations = torch.linspace(0.0, 1.0, bend.shape[2], dtype=params.dtype,
                                  device=params.device)
        loss = loss + fold_weight * fold_loss(bend[0], scaling_factor(scaling, stations),
                                              profile)
    if axis_weight and outside is not None and axis_t is not None:
        loss = loss + axis_weight * outside_axis_loss(axis_points(control_points, axis_t),
                                                      outside)
    return loss


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


