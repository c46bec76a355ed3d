"""Per-shape fitting: warm start, optionally SweepNet's network stage, then refinement.

`fit_abstraction` is what the CLI and the app call. Two methods:

- "direct" (the default): the warm-start primitives (fitted to the skeleton's branches,
  radius and scaling included) go straight into refinement (sweepedit.fitting.refine),
  whose residual rounds add primitives where the shape is missed. On the benchmark
  shapes this matches the network path's quality in a fraction of the time
  (docs/benchmark-log.md, "Quality and speed of the default fit").
- "network": the paper's method: the voxel encoder and two heads trained per shape
  (with the analytic or the neural sweeper, reconstruction, overlap, parsimony and axis
  losses), then the same refinement.

It reports progress through a callback: the stage ("warm start", "network",
"refinement", "residual round k of n"), its own fraction, an estimate of the seconds
left, and the current primitives as a valid Abstraction -- the first report is the
complete warm start. It stops within a step when `cancel` is set or the time limit is
reached, and always returns a valid, non-empty abstraction: parameters pass through the
range mapping, and a step that produces a non-finite value is never taken as a result.
"""

from __future__ import annotations

import math
import os
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
import torch

from sweepedit.analysis.metrics import SurfaceAgreement
from sweepedit.errors import SweepeditError, primitive_label
from sweepedit.fitting.losses import (
    LossWeights,
    axis_chamfer_loss,
    boltzmann_union,
    overlap_loss,
    parsimony_loss,
    reconstruction_loss,
)
from sweepedit.fitting.network import SweepNet
from sweepedit.fitting.params import ParamLayout
from sweepedit.fitting.refine import (
    STOP_REASONS,
    RefineSettings,
    RefineStep,
    ScoringPoints,
    StageTimings,
    refine_primitives,
)
from sweepedit.fitting.sweepers import load_sweeper
from sweepedit.fitting.warmstart import warm_start_primitives
from sweepedit.geometry.inside import inside_union
from sweepedit.geometry.model import Abstraction, SweepPrimitive, palette_color
from sweepedit.geometry.simplify import simplify_primitives
from sweepedit.geometry.sweep import axis_points

if TYPE_CHECKING:
    from sweepedit.io.shapes import Shape

# Axis samples per primitive for the axis (Chamfer) loss.
_AXIS_SAMPLES = 16
# Selection logit of warm-started primitives (sigmoid ~ 0.88: on, but free to drop), and
# of the spare ones beyond the skeleton's pieces (sigmoid 0.5: undecided, so the
# reconstruction loss can claim them for what the skeleton missed and parsimony can drop
# them; at -2 they stayed off and many-limb shapes lost coverage).
_WARM_SELECTION_LOGIT = 2.0
_SPARE_SELECTION_LOGIT = 0.0
# Default refinement steps per 8 primitives (FitSettings.refine_steps).
REFINE_STEPS_PER_8 = 300
# The automatic count (FitSettings.auto): at most this many primitives unless asked
# otherwise, residual rounds up to AUTO_ROUNDS, and the surface agreement it stops at:
# AUTO_AGREEMENT of each surface's samples within `tolerance` of the other's.
AUTO_MAX_PRIMITIVES = 32
AUTO_ROUNDS = 6
AUTO_AGREEMENT = 0.95
DEFAULT_TOLERANCE = 0.008
# Samples of each surface the agreement is estimated on (analysis.metrics.SurfaceAgreement).
AGREEMENT_SAMPLES = 8000
# A fitted primitive gets the simplest layout (fewest control points and scaling terms)
# that keeps its surface within this of the fitted one (geometry.simplify): a fifth of
# F1@0.01's threshold.
SIMPLIFY_TOLERANCE = 0.002
# Surface samples for the refinement score's coverage term.
SURFACE_SAMPLES = 2048
# Surface samples whose pairs of points SHELL_OFFSET inside and outside the surface give
# the refinement score's shell term (ScoringPoints): half F1@0.01's threshold.
SHELL_SAMPLES = 2048
SHELL_OFFSET = 0.005


@dataclass
class FitSettings:
    """How to fit. `primitives` is K, the number of new primitives (locked ones come on top)."""

    primitives: int = 8
    # Decide the count from the shape: add primitives where it is missed until the
    # surfaces agree within `tolerance` (AUTO_AGREEMENT of each within it of the other),
    # drop those that add nothing; `primitives` is then the most it may use.
    auto: bool = False
    tolerance: float = DEFAULT_TOLERANCE
    # "direct": warm start, then refinement; "network": the paper's network stage
    # (`iterations` steps) between them.
    method: str = "direct"
    iterations: int = 300
    sweeper: str = "analytic"
    seed: int = 0
    restarts: int = 1
    # The layout every primitive is fitted in: axes of up to `control_points` control
    # points (long curved parts need more than a quadratic Bezier's three) and scaling
    # of up to `scaling_degree` terms; each result then gets the simplest layout within
    # SIMPLIFY_TOLERANCE of its surface (3 and 2 where that is enough).
    control_points: int = 8
    scaling_degree: int = 3
    batch_points: int = 4096
    learning_rate: float = 3e-4
    # The analytic sweeper's sharpness while fitting (1/length): softer than its default
    # so that primitives feel the shape from a few voxels away.
    sharpness: float = 100.0
    # Training the voxel encoder too costs ~3x per iteration on a CPU and buys little for
    # one fixed input; its code is computed once unless this is set.
    train_encoder: bool = False
    encoder: str = "auto"  # "voxel", "points" or "auto" (by the input's kind)
    weights: LossWeights = field(default_factory=LossWeights)
    progress_every: int = 10
    # Steps of direct refinement after the network stage (sweepedit.fitting.refine); 0
    # skips it and the network's primitives are the result. None: REFINE_STEPS_PER_8
    # per 8 primitives, at least that many (`refine_steps`).
    refine_iterations: int | None = None
    # Rounds of refinement that add primitives where the shape is missed (each half as
    # long as the first pass), while fewer than `primitives` are kept. None: 2, or
    # AUTO_ROUNDS with `auto`.
    residual_rounds: int | None = None
    # What a primitive must add to the refinement score (IoU plus weighted surface
    # coverage) to be kept, up to 8 primitives (beyond, `keep_gain`): higher keeps fewer.
    min_gain: float = 0.001
    # Weight of surface coverage against IoU in the refinement score
    # (sweepedit.fitting.refine): higher spends primitives on thin parts that IoU
    # alone would leave out.
    surface_weight: float = 1.0
    # Weight of the shell accuracy (where the union's boundary lies, to SHELL_OFFSET)
    # against IoU in the refinement score.
    shell_weight: float = 1.0
    # Weight of the fold penalty (losses.fold_loss) against refinement's cross-entropy:
    # keeps the axes from bending far tighter than the profile's reach, where a sweep
    # folds onto itself and grows fins.
    fold_weight: float = 1.0
    # Weight of the outside-axis penalty (losses.outside_axis_loss) against refinement's
    # cross-entropy: keeps thin tails, which the grid cannot see, within the shape. On
    # the 30 shapes at K = 8: weight 0, 5, 20 gave CD-L1 0.0065, 0.0054, 0.0053 and
    # F1@0.05 0.988, 0.995, 0.996.
    axis_weight: float = 20.0
    # Seconds for the whole fit (None: no limit): the best abstraction found by then is
    # returned, never an empty one.
    time_limit: float | None = None
    # "auto" (CUDA when present, else the CPU), "cpu" or "cuda".
    device: str = "auto"

    @property
    def rounds(self) -> int:
        """Residual rounds: as set, else 2, or AUTO_ROUNDS with `auto`."""
        if self.residual_rounds is not None:
            return self.residual_rounds
        return AUTO_ROUNDS if self.auto else 2

    @property
    def keep_gain(self) -> float:
        """What a primitive must add to be kept: min_gain up to 8 primitives, then shrinking
        as 8 / K, since each of K primitives' natural share of the shape does (with
        `auto`, K = 16)."""
        k = 16 if self.auto else self.primitives
        return self.min_gain * min(1.0, 8.0 / max(k, 1))

    @property
    def refine_steps(self) -> int:
        """Refinement steps of the first pass: as set, or by default REFINE_STEPS_PER_8
        per 8 primitives (at least that many). Each step's points are shared by all the
        primitives, so more primitives need more steps to move as far (dino at K = 16:
        300 steps F1@0.01 0.797, 600 steps 0.868; BENCHMARKS.md)."""
        if self.refine_iterations is not None:
            return self.refine_iterations
        return round(REFINE_STEPS_PER_8 * max(1.0, self.primitives / 8))

    def validate(self) -> None:
        checks = [
            (self.primitives >= 1, "primitives must be at least 1"),
            (self.method in ("direct", "network"), "method must be 'direct' or 'network'"),
            (self.time_limit is None or self.time_limit > 0, "time limit must be positive"),
            (self.device in ("auto", "cpu", "cuda"), "device must be auto, cpu or cuda"),
            (self.iterations >= 1, "iterations must be at least 1"),
            (self.refine_iterations is None or self.refine_iterations >= 0,
             "refine iterations must be >= 0"),
            (self.residual_rounds is None or self.residual_rounds >= 0,
             "residual rounds must be >= 0"),
            (self.tolerance > 0.0, "tolerance must be positive"),
            (0.0 <= self.min_gain < 1.0, "min gain must be in [0, 1)"),
            (self.surface_weight >= 0.0, "surface weight must be >= 0"),
            (self.shell_weight >= 0.0, "shell weight must be >= 0"),
            (self.fold_weight >= 0.0, "fold weight must be >= 0"),
            (self.axis_weight >= 0.0, "axis weight must be >= 0"),
            (self.restarts >= 1, "restarts must be at least 1"),
            (self.control_points >= 3, "control points must be at least 3"),
            (self.scaling_degree >= 0, "scaling degree must be >= 0"),
            (self.sweeper in ("analytic", "neural"), "sweeper must be 'analytic' or 'neural'"),
            (self.encoder in ("auto", "voxel", "points"), "encoder must be auto, voxel or points"),
        ]
        for ok, message in checks:
            if not ok:
                raise SweepeditError(f"fit settings: {message}")


# The stages of one restart, in the order they run ("residual round k of n" stands for
# each round). The fit's seconds per stage (FitResult.stage_seconds) add "voxelise",
# "skeleton", "pruning" and "scoring", and count all residual rounds as one.
STAGES = ("warm start", "network", "refinement", "residual round")


@dataclass
class FitProgress:
    """A snapshot for progress bars and live previews: `iteration` of `total` steps over
    the whole fit; `stage` (see STAGES) with its own `stage_fraction` (0..1, monotone
    within the stage, 1 at its end); `seconds_left` an estimate (None before one can be
    made); `abstraction` the current primitives, complete and valid."""

    iteration: int
    total: int
    restart: int
    losses: dict[str, float]
    abstraction: Abstraction
    stage: str = "network"
    stage_fraction: float = 0.0
    seconds_left: float | None = None


@dataclass
class FitResult:
    """The fitted abstraction; iou is its IoU over the grid cells and near-surface
    samples (sweepedit.fitting.refine.ScoringPoints), NaN for a cancelled single run."""

    abstraction: Abstraction
    seconds: float
    losses: dict[str, float]
    iou: float
    cancelled: bool
    # Seconds per stage, summed over restarts.
    stage_seconds: dict[str, float] = field(default_factory=dict)
    # The time limit ended the fit before it was done.
    timed_out: bool = False
    # Why refinement stopped adding primitives (refine.STOP_REASONS), None when it did
    # not run.
    stopped: str | None = None


def resolve_device(name: str) -> str:
    """The torch device for a FitSettings.device: "auto" is CUDA when present, else the
    CPU; "cuda" without CUDA is an error that says so."""
    if name == "cpu":
        return "cpu"
    available = torch.cuda.is_available()
    if name == "cuda" and not available:
        raise SweepeditError("fit settings: device 'cuda' asked for, but torch sees no CUDA "
                             "device here (use --device cpu or auto)")
    return "cuda" if available else "cpu"


def configure_threads() -> None:
    """Torch's and the compiled loops' (numba's) CPU threads: one per core this process
    may use (a worker pinned to some cores, as a batch scheduler does, gets that many
    rather than the machine's count, so that two fits never fight over one core).
    Honours OMP_NUM_THREADS when set."""
    import numba

    if "OMP_NUM_THREADS" in os.environ:
        numba.set_num_threads(max(1, min(torch.get_num_threads(),
                                         numba.config.NUMBA_NUM_THREADS)))
        return
    try:
        cores = len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        cores = os.cpu_count() or 1
    if torch.get_num_threads() != cores:
        torch.set_num_threads(cores)
    numba.set_num_threads(max(1, min(cores, numba.config.NUMBA_NUM_THREADS)))


class _Clock:
    """The fit's time: elapsed seconds, the time limit, cancel, and a time-left estimate
    from the pace of the steps since the first report of a step (the time before it --
    preparing the shape, a first step that loads or compiles code -- says nothing of
    the pace: a fresh install's first step once read "~1620 s left" for a 9 s fit)."""

    def __init__(self, limit: float | None, cancel: threading.Event, total_steps: int) -> None:
        self.start = time.perf_counter()
        self.limit = limit
        self.cancel = cancel
        self.total_steps = max(total_steps, 1)
        self.timed_out = False
        self._since: tuple[float, int] | None = None  # (time, steps) of the first report

    def elapsed(self) -> float:
        return time.perf_counter() - self.start

    def stop(self) -> bool:
        """True once cancelled or past the time limit (remembered as timed_out)."""
        if self.cancel.is_set():
            return True
        if self.limit is not None and self.elapsed() >= self.limit:
            self.timed_out = True
            return True
        return False

    def seconds_left(self, steps_done: int) -> float | None:
        """Seconds left at steps_done steps; None while the pace is not known."""
        elapsed = self.elapsed()
        estimate = None
        if steps_done > 0 and self._since is None:
            self._since = (elapsed, steps_done)
        elif self._since is not None and steps_done > self._since[1]:
            pace = (elapsed - self._since[0]) / (steps_done - self._since[1])
            estimate = pace * max(self.total_steps - steps_done, 0)
        if self.limit is not None:
            remaining = max(self.limit - elapsed, 0.0)
            estimate = remaining if estimate is None else min(estimate, remaining)
        return estimate


class _Run:
    """The network stage of one fit from one seed: the network, the sweeper and the data
    as tensors, started from the given primitives (padded to K with spares)."""

    def __init__(self, shape: Shape, settings: FitSettings, seed: int,
                 locked: Sequence[SweepPrimitive], skeleton_points: np.ndarray,
                 init: list[SweepPrimitive], device: str) -> None:
        self.settings = settings
        self.device = torch.device(device)
        self.layout = ParamLayout(settings.control_points, settings.scaling_degree)
        torch.manual_seed(seed)
        self.rng = np.random.default_rng(seed)
        K = settings.primitives
        n_warm = len(init)
        init = _pad_primitives(init, K, self.rng, settings, shape.occupancy)
        init_params = self.layout.from_primitives(init, dtype=torch.float32)
        point_input = settings.encoder == "points" or (
            settings.encoder == "auto" and shape.kind == "points")
        self.net = SweepNet(K, self.layout.size, point_input=point_input)
        self.net.warm_start(self.layout.to_unconstrained(init_params),
                            torch.tensor([_WARM_SELECTION_LOGIT] * n_warm
                                         + [_SPARE_SELECTION_LOGIT] * (K - n_warm)))
        self.net.to(self.device)
        self.encoder_input = self._encoder_input(shape, point_input).to(self.device)
        if not settings.train_encoder:
            with torch.no_grad():
                self.code = self.net.encoder(self.encoder_input)
        params = list(self.net.parameters()) if settings.train_encoder else (
            list(self.net.mlp.parameters()) + list(self.net.primitive_head.parameters())
            + list(self.net.selection_head.parameters()))
        self.optimizer = torch.optim.Adam(params, lr=settings.learning_rate)
        self.sweeper = (load_sweeper("analytic", sharpness=settings.sharpness)
                        if settings.sweeper == "analytic" else load_sweeper(settings.sweeper))
        # Both sweepers read the primitive through its key points or frames, so any
        # number of control points and scaling terms works once they know the layout.
        self.sweeper.layout = self.layout
        self.sweeper.requires_grad_(False)
        self.sweeper.to(self.device)

        samples = shape.samples
        self.points = torch.as_tensor(samples.points, dtype=torch.float32, device=self.device)
        self.labels = torch.as_tensor(samples.labels, dtype=torch.float32, device=self.device)
        # Locked primitives do not move: their exact occupancy at the samples is fixed.
        self.locked = list(locked)
        self.locked_occupancy = torch.as_tensor(
            inside_union(samples.points, self.locked), dtype=torch.float32,
            device=self.device) if locked else None
        self.skeleton = torch.as_tensor(skeleton_points, dtype=torch.float32,
                                        device=self.device)
        self.t_axis = torch.linspace(0.0, 1.0, _AXIS_SAMPLES, device=self.device)

    def _encoder_input(self, shape: Shape, point_input: bool) -> torch.Tensor:
        if point_input:
            pts = np.asarray(shape.surface_samples(1024, seed=0), dtype=np.float32)
            return torch.as_tensor(pts)[None]
        occ = np.asarray(shape.occupancy, dtype=np.float32)
        return torch.as_tensor(occ)[None, None]

    def outputs(self) -> tuple[torch.Tensor, torch.Tensor]:
        """Current params (K, P) in range and selection logits (K,)."""
        code = self.net.encoder(self.encoder_input) if self.settings.train_encoder else self.code
        unit, logits = self.net.heads(code)
        return self.layout.from_unit(unit[0]), logits[0]

    def step(self, progress: float) -> dict[str, float]:
        s, w = self.settings, self.settings.weights
        idx = torch.as_tensor(self.rng.integers(0, len(self.points), s.batch_points),
                              device=self.device)
        queries, target = self.points[idx], self.labels[idx]
        params, logits = self.outputs()
        selection = torch.sigmoid(logits)
        occupancy = self.sweeper(params[None], queries[None])  # (1, K, Q)
        if self.locked_occupancy is not None:
            occupancy = torch.cat([occupancy, self.locked_occupancy[idx][None, None]], dim=1)
            selection_all = torch.cat([selection, torch.ones(1, device=self.device)])
        else:
            selection_all = selection
        union = boltzmann_union(occupancy, selection_all[None])
        cps = self.layout.split(params)[0]
        axes = axis_points(cps, self.t_axis)
        terms = {
            "reconstruction": reconstruction_loss(union, target[None]),
            "overlap": overlap_loss(occupancy, selection_all[None], w.overlap_threshold),
            "parsimony": parsimony_loss(selection[None]),
            "axis": axis_chamfer_loss(self.skeleton, axes, selection),
        }
        total = (w.reconstruction * terms["reconstruction"] + w.overlap * terms["overlap"]
                 + w.parsimony_weight(s.primitives) * terms["parsimony"]
                 + w.axis_weight(progress) * terms["axis"])
        self.optimizer.zero_grad(set_to_none=True)
        total.backward()
        grads_ok = all(p.grad is None or bool(torch.isfinite(p.grad).all())
                       for group in self.optimizer.param_groups for p in group["params"])
        if grads_ok and torch.isfinite(total):
            self.optimizer.step()
        losses = {k: float(v.detach()) for k, v in terms.items()}
        losses["total"] = float(total.detach())
        return losses

    def snapshot(self) -> tuple[torch.Tensor, torch.Tensor] | None:
        """Detached (params, logits), or None if anything is not finite."""
        with torch.no_grad():
            params, logits = self.outputs()
        if not (torch.isfinite(params).all() and torch.isfinite(logits).all()):
            return None
        return params.clone(), logits.clone()

    def primitives(self, params: torch.Tensor, logits: torch.Tensor,
                   final: bool) -> list[SweepPrimitive]:
        """Selected primitives (logit > 0 at the end; > 0 or the best one while running)."""
        keep = (logits > 0).nonzero().flatten().tolist()
        if not keep:  # never return an empty abstraction: keep the strongest primitive
            keep = [int(torch.argmax(logits))]
        prims = self.layout.to_primitives(self.layout.clamp(params[keep].double().cpu()))
        return [p for p in prims if _is_valid(p)]


def _pad_primitives(init: list[SweepPrimitive], k: int, rng: np.random.Generator,
                    settings: FitSettings, occupancy: np.ndarray) -> list[SweepPrimitive]:
    """Fill up to k primitives with short spare ones inside the shape (at random occupied
    cells, random directions, two cells thick) for the fit to switch on where needed."""
    out = list(init)
    res = occupancy.shape[0]
    cells = np.argwhere(occupancy)
    while len(out) < k:
        centre = (cells[rng.integers(len(cells))] + 0.5) / res - 0.5
        direction = rng.normal(size=3)
        direction /= np.linalg.norm(direction)
        half = 3.0 / res
        cps = centre + np.linspace(-half, half, settings.control_points)[:, None] * direction
        out.append(SweepPrimitive(np.clip(cps, -0.5, 0.5), a=2.0 / res, b=2.0 / res,
                                  degree=2.0, scaling=(0.0,) * settings.scaling_degree,
                                  color=palette_color(len(out))))
    return out


def _warm_start(shape: Shape, settings: FitSettings, layout: ParamLayout, seed: int,
                skeleton_branches: Sequence) -> list[SweepPrimitive]:
    """The warm-start primitives of one restart: one per skeleton piece (at most K, at
    least one), jittered slightly for seeds other than 0."""
    init = warm_start_primitives(skeleton_branches, settings.primitives,
                                 settings.control_points, settings.scaling_degree)
    rng = np.random.default_rng(seed)
    if not init:  # no usable branch (a blob): one short spare inside the shape
        init = _pad_primitives([], 1, rng, settings, shape.occupancy)
    if seed:
        torch.manual_seed(seed)
        params = layout.from_primitives(init, dtype=torch.float64)
        params = layout.clamp(params + 0.01 * torch.randn_like(params))
        jittered = layout.to_primitives(params)
        for new, old in zip(jittered, init, strict=True):
            new.name, new.color = old.name, old.color
        init = [p for p in jittered if _is_valid(p)] or init
    return init


def _is_valid(primitive: SweepPrimitive) -> bool:
    try:
        primitive.validate()
    except ValueError:
        return False
    return True


def scoring_points(shape: Shape, locked: Sequence[SweepPrimitive],
                   settings: FitSettings) -> ScoringPoints:
    """The points refinement fits and scores for a shape (ScoringPoints): the grid's
    cells, the near-surface samples, the surface samples of the coverage term and the
    shell pairs, with the settings' weights; `locked` primitives stay fixed."""
    shell, shell_labels = shape.shell_samples(SHELL_SAMPLES, SHELL_OFFSET, seed=1)
    return ScoringPoints(shape.winding_occupancy, shape.samples.points[: shape.samples.n_near],
                         shape.samples.labels[: shape.samples.n_near], locked,
                         surface=shape.surface_samples(SURFACE_SAMPLES, seed=0),
                         surface_weight=settings.surface_weight, shell=shell,
                         shell_labels=shell_labels, shell_weight=settings.shell_weight)


def fit_abstraction(shape: Shape, settings: FitSettings | None = None, *,
                    locked: Sequence[SweepPrimitive] = (),
                    callback: Callable[[FitProgress], None] | None = None,
                    cancel: threading.Event | None = None) -> FitResult:
    """Fit sweep primitives to a shape: for each of `restarts` seeds, the warm start, the
    network stage (method "network" only), then direct refinement and pruning
    (sweepedit.fitting.refine); the best seed by the refinement score (IoU over the grid
    cells and near-surface samples plus weighted surface coverage).

    Locked primitives are kept unchanged and come first in the result. With a time limit,
    the best abstraction found within it is returned (the warm start at worst).
    """
    from sweepedit.analysis.skeleton import compute_skeleton
    from sweepedit.io.shapes import check_fittable

    settings = settings or FitSettings()
    settings.validate()
    check_fittable(shape)  # a shape that encloses nothing stops here, not in a step
    device = resolve_device(settings.device)
    configure_threads()
    cancel = cancel or threading.Event()
    timings = StageTimings()
    layout = ParamLayout(settings.control_points, settings.scaling_degree)

    # With `auto` each pass's steps follow its own count (per 8 primitives), which the
    # shape decides; the progress estimate takes half the most it may use.
    steps = REFINE_STEPS_PER_8 if settings.auto and settings.refine_iterations is None \
        else settings.refine_steps
    refine = RefineSettings(iterations=steps, start_sharpness=settings.sharpness,
                            min_gain=settings.keep_gain,
                            residual_rounds=settings.rounds if steps else 0,
                            residual_iterations=steps // 2, device=device,
                            steps_per_8=settings.auto, fold_weight=settings.fold_weight,
                            axis_weight=settings.axis_weight)
    network_steps = settings.iterations if settings.method == "network" else 0
    per_restart = network_steps + refine.total_steps(max(settings.primitives // 2, 8))
    total_iterations = per_restart * settings.restarts
    clock = _Clock(settings.time_limit, cancel, total_iterations)

    with timings.measure("voxelise"):
        target = np.asarray(shape.occupancy, dtype=bool)
        if not target.any():
            raise SweepeditError(f"{shape.path}: the shape has no volume to fit "
                                 "(empty occupancy)")
        scoring = scoring_points(shape, locked, settings)
    with timings.measure("skeleton"):
        skeleton = compute_skeleton(shape.occupancy)

    def make_abstraction(prims: list[SweepPrimitive]) -> Abstraction:
        named = []
        for i, p in enumerate(prims):
            # Renumbered in order: residual rounds bring their own "primitive 1.." names.
            p.name = primitive_label(len(locked) + i)
            p.color = palette_color(len(locked) + i)
            named.append(p)
        return Abstraction([q.copy() for q in locked] + named,
                           normalization=shape.normalization)

    def report(done: int, restart: int, losses: dict[str, float], prims: list[SweepPrimitive],
               stage: str, fraction: float) -> None:
        if callback:
            callback(FitProgress(done, total_iterations, restart, losses,
                                 make_abstraction([p.copy() for p in prims]), stage,
                                 float(min(max(fraction, 0.0), 1.0)),
                                 clock.seconds_left(done)))

    accurate = None
    if settings.auto:
        with timings.measure("scoring"):
            agreement = SurfaceAgreement(shape, settings.tolerance, AGREEMENT_SAMPLES)

        def accurate(prims: list[SweepPrimitive]) -> bool:
            return agreement([*locked, *prims]) >= AUTO_AGREEMENT

    stopped: str | None = None
    best: tuple[float, list[SweepPrimitive], dict[str, float], np.ndarray | None,
                str | None] | None = None
    for restart in range(settings.restarts):
        if restart and clock.stop():
            break
        seed = settings.seed + restart
        base = restart * per_restart
        with timings.measure("warm start"):
            prims = _warm_start(shape, settings, layout, seed, skeleton.branches)
        report(base, restart, {}, prims, "warm start", 1.0)
        losses: dict[str, float] = {}
        if network_steps and not clock.stop():
            with timings.measure("network"):
                prims, losses = _network_stage(shape, settings, seed, locked, skeleton, prims,
                                               device, clock, base, restart, report)
        occupancy = None
        if clock.stop():
            # Cancelled or out of time: no refinement. A single run has nothing to be
            # compared with, so it is not scored either.
            score = math.nan
            if settings.restarts > 1:
                occupancy = scoring.occupancy(prims)
                score = scoring.score(occupancy.any(axis=0))
        else:
            def on_refine_step(step: RefineStep, restart: int = restart, base: int = base,
                               losses: dict[str, float] = losses) -> None:
                report(base + network_steps + step.step + 1, restart,
                       {**losses, **step.losses}, step.primitives, step.stage, step.fraction)

            refined = refine_primitives(
                prims, layout, scoring, refine, budget=settings.primitives, seed=seed,
                stop=clock.stop, on_step=on_refine_step, report_every=settings.progress_every,
                timings=timings, accurate=accurate)
            prims, score, occupancy = refined.primitives, refined.score, refined.occupancy
            stopped = refined.stopped
        if best is None or score > best[0] or math.isnan(best[0]):
            best = (score, prims, losses, occupancy, stopped)

    if best is None:
        raise SweepeditError(f"{shape.path}: fitting produced no valid primitive")
    score, prims, losses, occupancy, stopped = best
    with timings.measure("simplify"):
        simple = simplify_primitives(prims, SIMPLIFY_TOLERANCE)
    changed = [i for i, (p, q) in enumerate(zip(prims, simple, strict=True)) if p is not q]
    if changed and stopped == "accurate" and accurate is not None:
        with timings.measure("scoring"):
            if not accurate(simple):  # simplifying must not undo why the count stopped
                simple, changed = prims, []
    # What the restarts were judged by includes surface coverage; the record reports
    # the plain IoU over the scoring points, which a user can compare across settings.
    iou = math.nan
    if occupancy is not None and not math.isnan(score):
        with timings.measure("scoring"):
            if changed:  # the simplified primitives' rows, tested again
                occupancy = occupancy.copy()
                occupancy[changed] = scoring.occupancy([simple[i] for i in changed],
                                                       refine.scoring_t_samples)
            iou = scoring.iou(occupancy.any(axis=0))
    prims = simple
    abstraction = make_abstraction(prims)
    seconds = clock.elapsed()
    abstraction.source = {"path": str(shape.path), "sha256": shape.sha256}
    record: dict[str, Any] = {k: v for k, v in asdict(settings).items() if k != "weights"}
    record.update({"weights": asdict(settings.weights), "seconds": round(seconds, 3),
                   "refine_steps": steps, "cancelled": cancel.is_set(), "locked": len(locked),
                   "device": device, "timed_out": clock.timed_out,
                   "stage_seconds": {k: round(v, 3) for k, v in timings.seconds.items()},
                   "fit_iou": None if math.isnan(iou) else round(iou, 6),
                   "stopped": stopped,
                   "stopped_because": STOP_REASONS.get(stopped or "")})
    if settings.auto:
        with timings.measure("scoring"):
            record["agreement"] = round(agreement([*locked, *prims]), 4)
    abstraction.fit = record
    return FitResult(abstraction, seconds, losses, iou, cancel.is_set(), timings.seconds,
                     clock.timed_out, stopped)


def _network_stage(shape: Shape, settings: FitSettings, seed: int,
                   locked: Sequence[SweepPrimitive], skeleton: Any,
                   init: list[SweepPrimitive], device: str, clock: _Clock, base: int,
                   restart: int, report: Callable[..., None],
                   ) -> tuple[list[SweepPrimitive], dict[str, float]]:
    """SweepNet's per-shape network stage from the warm start: Adam on the heads for
    `settings.iterations` steps; the primitives of the step with the lowest
    reconstruction loss, and the last losses."""
    run = _Run(shape, settings, seed, locked, skeleton.all_points(), init, device)
    best_loss, best_snap, losses = math.inf, run.snapshot(), {}
    for it in range(settings.iterations):
        if clock.stop():
            break
        losses = run.step(it / max(settings.iterations - 1, 1))
        # Judge by reconstruction: the other terms are priors, not the goal.
        if losses["reconstruction"] < best_loss:
            current = run.snapshot()
            if current is not None:
                best_loss, best_snap = losses["reconstruction"], current
        last = it == settings.iterations - 1
        if it % settings.progress_every == 0 or last:
            current = run.snapshot() or best_snap
            if current is not None:
                report(base + it + 1, restart, losses, run.primitives(*current, final=False),
                       "network", (it + 1) / settings.iterations)
    if best_snap is None:
        return init, losses
    return run.primitives(*best_snap, final=True) or init, losses
