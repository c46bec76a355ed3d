"""Per-shape SweepNet fitting: warm start, Adam on the network, best result kept.

`fit_abstraction` is what the CLI and the app call. It reports progress through a
callback (every few iterations, with the current primitives as a valid Abstraction),
stops within an iteration when `cancel` is set, and always returns a valid abstraction:
parameters pass through the range mapping, and a step that produces a non-finite value
is never taken as a result.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
import torch

from sweepedit.errors import SweepeditError
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
from sweepedit.fitting.refine import RefineSettings, ScoringPoints, refine_primitives
from sweepedit.fitting.sweepers import load_sweeper
from sweepedit.fitting.warmstart import warm_start_primitives
from sweepedit.geometry.inside import inside_union
from sweepedit.geometry.model import Abstraction, SweepPrimitive, palette_color
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
# Surface samples for the refinement score's coverage term.
SURFACE_SAMPLES = 2048


@dataclass
class FitSettings:
    """How to fit. `primitives` is K, the number of new primitives (locked ones come on top)."""

    primitives: int = 8
    iterations: int = 300
    sweeper: str = "analytic"
    seed: int = 0
    restarts: int = 1
    control_points: int = 3
    scaling_degree: int = 2
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
    # long as the first pass), while fewer than `primitives` are kept.
    residual_rounds: int = 2
    # What a primitive must add to the refinement score (IoU plus weighted surface
    # coverage) to be kept: higher keeps fewer primitives.
    min_gain: float = 0.001
    # Weight of surface coverage against IoU in the refinement score
    # (sweepedit.fitting.refine): higher spends primitives on thin parts that IoU
    # alone would leave out.
    surface_weight: float = 1.0

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
            (self.iterations >= 1, "iterations must be at least 1"),
            (self.refine_iterations is None or self.refine_iterations >= 0,
             "refine iterations must be >= 0"),
            (self.residual_rounds >= 0, "residual rounds must be >= 0"),
            (0.0 <= self.min_gain < 1.0, "min gain must be in [0, 1)"),
            (self.surface_weight >= 0.0, "surface weight must be >= 0"),
            (self.restarts >= 1, "restarts must be at least 1"),
            (self.control_points >= 3, "control points must be at least 3"),
            (self.scaling_degree >= 0, "scaling degree must be >= 0"),
            (self.sweeper in ("analytic", "neural"), "sweeper must be 'analytic' or 'neural'"),
            (self.encoder in ("auto", "voxel", "points"), "encoder must be auto, voxel or points"),
        ]
        for ok, message in checks:
            if not ok:
                raise SweepeditError(f"fit settings: {message}")


@dataclass
class FitProgress:
    """A snapshot for progress bars and live previews."""

    iteration: int
    total: int
    restart: int
    losses: dict[str, float]
    abstraction: Abstraction


@dataclass
class FitResult:
    """The fitted abstraction; iou is its IoU over the grid cells and near-surface
    samples (sweepedit.fitting.refine.ScoringPoints), NaN for a cancelled single run."""

    abstraction: Abstraction
    seconds: float
    losses: dict[str, float]
    iou: float
    cancelled: bool


class _Run:
    """One fit from one seed: the network, the sweeper and the data as tensors."""

    def __init__(self, shape: Shape, settings: FitSettings, seed: int,
                 locked: Sequence[SweepPrimitive]) -> None:
        from sweepedit.analysis.skeleton import compute_skeleton

        self.settings = settings
        self.layout = ParamLayout(settings.control_points, settings.scaling_degree)
        torch.manual_seed(seed)
        self.rng = np.random.default_rng(seed)
        K = settings.primitives

        skeleton = compute_skeleton(shape.occupancy)
        init = warm_start_primitives(skeleton.branches, K, settings.control_points,
                                     settings.scaling_degree)
        n_warm = len(init)
        init = _pad_primitives(init, K, self.rng, settings, shape.occupancy)
        init_params = self.layout.from_primitives(init, dtype=torch.float32)
        # Different seeds start from slightly different places: jitter the warm start.
        if seed:
            init_params = init_params + 0.01 * torch.randn_like(init_params)
            init_params = self.layout.clamp(init_params)

        point_input = settings.encoder == "points" or (
            settings.encoder == "auto" and shape.kind == "points")
        self.net = SweepNet(K, self.layout.size, point_input=point_input)
        self.net.warm_start(self.layout.to_unconstrained(init_params),
                            torch.tensor([_WARM_SELECTION_LOGIT] * n_warm
                                         + [_SPARE_SELECTION_LOGIT] * (K - n_warm)))
        self.encoder_input = self._encoder_input(shape, point_input)
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

        samples = shape.samples
        self.points = torch.as_tensor(samples.points, dtype=torch.float32)
        self.labels = torch.as_tensor(samples.labels, dtype=torch.float32)
        # Locked primitives do not move: their exact occupancy at the samples is fixed.
        self.locked = list(locked)
        self.locked_occupancy = torch.as_tensor(
            inside_union(samples.points, self.locked), dtype=torch.float32) if locked else None
        self.skeleton = torch.as_tensor(skeleton.all_points(), dtype=torch.float32)
        self.t_axis = torch.linspace(0.0, 1.0, _AXIS_SAMPLES)

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
        idx = torch.as_tensor(self.rng.integers(0, len(self.points), s.batch_points))
        queries, target = self.points[idx], self.labels[idx]
        params, logits = self.outputs()
        selection = torch.sigmoid(logits)
        occupancy = self.sweeper(params[None], queries[None])  # (1, K, Q)
        if self.locked_occupancy is not None:
            occupancy = torch.cat([occupancy, self.locked_occupancy[idx][None, None]], dim=1)
            selection_all = torch.cat([selection, torch.ones(1)])
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
        prims = self.layout.to_primitives(self.layout.clamp(params[keep].double()))
        valid = []
        for p in prims:
            try:
                p.validate()
            except ValueError:
                continue
            valid.append(p)
        return valid


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


def fit_abstraction(shape: Shape, settings: FitSettings | None = None, *,
                    locked: Sequence[SweepPrimitive] = (),
                    callback: Callable[[FitProgress], None] | None = None,
                    cancel: threading.Event | None = None) -> FitResult:
    """Fit sweep primitives to a shape: for each of `restarts` seeds, the network stage,
    then direct refinement and pruning (sweepedit.fitting.refine); the best seed by the
    refinement score (IoU over the grid cells and near-surface samples plus weighted
    surface coverage).

    Locked primitives are kept unchanged and come first in the result.
    """
    settings = settings or FitSettings()
    settings.validate()
    cancel = cancel or threading.Event()
    start = time.perf_counter()
    target = np.asarray(shape.occupancy, dtype=bool)
    if not target.any():
        raise SweepeditError(f"{shape.path}: the shape has no volume to fit (empty occupancy)")
    best: tuple[float, list[SweepPrimitive], dict[str, float]] | None = None
    scoring = ScoringPoints(shape.winding_occupancy, shape.samples.points[: shape.samples.n_near],
                            shape.samples.labels[: shape.samples.n_near], locked,
                            surface=shape.surface_samples(SURFACE_SAMPLES, seed=0),
                            surface_weight=settings.surface_weight)
    steps = settings.refine_steps
    refine = RefineSettings(iterations=steps, start_sharpness=settings.sharpness,
                            min_gain=settings.min_gain,
                            residual_rounds=settings.residual_rounds if steps else 0,
                            residual_iterations=steps // 2)
    per_restart = settings.iterations + refine.total_steps
    total_iterations = per_restart * settings.restarts

    def make_abstraction(prims: list[SweepPrimitive]) -> Abstraction:
        named = []
        for i, p in enumerate(prims):
            p.name = p.name or f"primitive {len(locked) + i + 1}"
            p.color = palette_color(len(locked) + i)
            named.append(p)
        return Abstraction([q.copy() for q in locked] + named,
                           normalization=shape.normalization)

    for restart in range(settings.restarts):
        if cancel.is_set():
            break
        run = _Run(shape, settings, settings.seed + restart, locked)
        snap = run.snapshot()
        best_loss, best_snap, losses = math.inf, snap, {}
        for it in range(settings.iterations):
            if cancel.is_set():
                break
            losses = run.step(it / max(settings.iterations - 1, 1))
            # Judge by reconstruction: the other terms are priors, not the goal.
            if losses["reconstruction"] < best_loss:
                current = run.snapshot()
                if current is not None:
                    best_loss, best_snap = losses["reconstruction"], current
            done = restart * per_restart + it + 1
            if callback and (it % settings.progress_every == 0 or it == settings.iterations - 1):
                current = run.snapshot() or best_snap
                if current is not None:
                    callback(FitProgress(done, total_iterations, restart, losses,
                                         make_abstraction(run.primitives(*current, final=False))))
        if best_snap is None:
            continue
        prims = run.primitives(*best_snap, final=True)
        if cancel.is_set():
            # A cancelled run returns at once: no refinement, and a single run has
            # nothing to be compared with, so it is not scored either.
            score = scoring.score(scoring.occupancy(prims).any(axis=0)) \
                if settings.restarts > 1 else math.nan
        else:
            def on_refine_step(step: int, refine_losses: dict[str, float],
                               current: list[SweepPrimitive], restart: int = restart,
                               losses: dict[str, float] = losses) -> None:
                if callback:
                    done = restart * per_restart + settings.iterations + step + 1
                    callback(FitProgress(done, total_iterations, restart,
                                         {**losses, **refine_losses},
                                         make_abstraction([p.copy() for p in current])))

            prims, score = refine_primitives(prims, run.layout, scoring, refine,
                                             budget=settings.primitives,
                                             seed=settings.seed + restart, cancel=cancel,
                                             on_step=on_refine_step,
                                             report_every=settings.progress_every)
        if best is None or score > best[0] or math.isnan(best[0]):
            best = (score, prims, losses)

    if best is None:
        raise SweepeditError(f"{shape.path}: fitting produced no valid primitive")
    score, prims, losses = best
    # What the restarts were judged by includes surface coverage; the record reports
    # the plain IoU over the scoring points, which a user can compare across settings.
    iou = math.nan if math.isnan(score) else scoring.iou(scoring.occupancy(prims).any(axis=0))
    abstraction = make_abstraction(prims)
    seconds = time.perf_counter() - start
    abstraction.source = {"path": str(shape.path), "sha256": shape.sha256}
    record: dict[str, Any] = {k: v for k, v in asdict(settings).items() if k != "weights"}
    record.update({"weights": asdict(settings.weights), "seconds": round(seconds, 3),
                   "refine_steps": steps, "cancelled": cancel.is_set(), "locked": len(locked),
                   "fit_iou": None if math.isnan(iou) else round(iou, 6)})
    abstraction.fit = record
    return FitResult(abstraction, seconds, losses, iou, cancel.is_set())
