"""Refit a selection: optimise only some primitives, the others held fixed.

A full fit with every other primitive locked (fit.py's `locked`) starts from the skeleton
and adds K new primitives. Refitting the selection instead takes the selected primitives
as they are and refines their parameters against the part of the shape that the fixed
ones do not cover: the fixed ones enter the refinement as a constant member of the soft
union (ScoringPoints' locked occupancy, computed once with the exact inside test), so
the loss only asks the selected ones to fill what is left. Nothing is added, pruned or
reordered, and the fixed primitives come back as bit-identical copies. The result is the
best state by the refinement's exact score, so never worse than the input by it.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING

import numpy as np

from sweepedit.errors import SweepeditError
from sweepedit.fitting.fit import (
    FitProgress,
    FitResult,
    FitSettings,
    configure_threads,
    resolve_device,
    scoring_points,
)
from sweepedit.fitting.params import ParamLayout
from sweepedit.fitting.refine import (
    RefineSettings,
    RefineStep,
    StageTimings,
    optimise_primitives,
)
from sweepedit.geometry.model import Abstraction, SweepPrimitive

if TYPE_CHECKING:
    from sweepedit.io.shapes import Shape

STAGE = "refit selection"


def _check_selection(primitives: Sequence[SweepPrimitive], selected: Sequence[int]) -> list[int]:
    chosen = sorted({int(i) for i in selected})
    if not chosen:
        raise SweepeditError("refit: select the primitives to refit first")
    bad = [i for i in chosen if not 0 <= i < len(primitives)]
    if bad:
        raise SweepeditError(f"refit: there is no primitive {bad[0] + 1} (the abstraction "
                             f"has {len(primitives)})")
    locked = [i for i in chosen if primitives[i].locked]
    if locked:
        raise SweepeditError(f"refit: {primitives[locked[0]].name or f'primitive {locked[0] + 1}'}"
                             " is locked; unlock it to refit it")
    return chosen


def refit_selection(shape: Shape, primitives: Sequence[SweepPrimitive],
                    selected: Sequence[int], settings: FitSettings | None = None, *,
                    callback: Callable[[FitProgress], None] | None = None,
                    cancel: threading.Event | None = None) -> FitResult:
    """Refine primitives[i] for i in `selected` (indices into `primitives`) with all the
    others fixed; returns every primitive in the input's order, the unselected ones as
    exact copies. Steps: settings.refine_steps for the selection's size (at least
    REFINE_STEPS_PER_8); time limit and cancel keep the best state so far. Selected
    primitives with different numbers of control points or scaling terms are refined
    group by group (each group with everything else fixed)."""
    settings = settings or FitSettings()
    settings.validate()
    chosen = _check_selection(primitives, selected)
    device = resolve_device(settings.device)
    configure_threads()
    cancel = cancel or threading.Event()
    started = time.perf_counter()
    timings = StageTimings()
    current = [p.copy() for p in primitives]
    groups: dict[tuple[int, int], list[int]] = {}
    for i in chosen:
        groups.setdefault((primitives[i].n_control_points, len(primitives[i].scaling)),
                          []).append(i)
    steps = (settings.refine_iterations if settings.refine_iterations is not None
             else FitSettings(primitives=len(chosen)).refine_steps)
    refine = RefineSettings(iterations=steps, start_sharpness=settings.sharpness,
                            min_gain=settings.keep_gain, residual_rounds=0, device=device)
    total = max(steps * len(groups), 1)
    timed_out = False

    def stop() -> bool:
        nonlocal timed_out
        if cancel.is_set():
            return True
        if settings.time_limit is not None and time.perf_counter() - started >= settings.time_limit:
            timed_out = True
            return True
        return False

    score = math.nan
    iou = math.nan
    for g, ((n_points, n_scaling), members) in enumerate(groups.items()):
        if stop():
            break
        fixed = [p for i, p in enumerate(current) if i not in members]
        with timings.measure("scoring"):
            scoring = scoring_points(shape, fixed, settings)

        def on_step(step: RefineStep, g: int = g, members: list[int] = members) -> None:
            if callback is None:
                return
            shown = list(current)
            for i, p in zip(members, step.primitives, strict=True):
                shown[i] = p
            done = g * steps + step.step + 1
            elapsed = time.perf_counter() - started
            left = elapsed / done * max(total - done, 0) if done else None
            callback(FitProgress(done, total, 0, step.losses,
                                 Abstraction([p.copy() for p in shown],
                                             normalization=shape.normalization),
                                 STAGE, (g + step.fraction) / len(groups), left))

        layout = ParamLayout(n_points, n_scaling)
        with timings.measure("refinement"):
            refined, occupancy = optimise_primitives(
                [current[i] for i in members], layout, scoring, refine, steps,
                np.random.default_rng(settings.seed + g), stop, on_step,
                report_every=settings.progress_every, stage=STAGE)
        for i, p in zip(members, refined, strict=True):
            current[i] = p
        covered = occupancy.any(axis=0)
        score, iou = scoring.score(covered), scoring.iou(covered)

    abstraction = Abstraction(current, normalization=shape.normalization)
    abstraction.source = {"path": str(shape.path), "sha256": shape.sha256}
    seconds = time.perf_counter() - started
    abstraction.fit = {"method": "refit selection", "refit": [i + 1 for i in chosen],
                       "refine_steps": steps, "seconds": round(seconds, 3),
                       "cancelled": cancel.is_set(), "timed_out": timed_out, "device": device,
                       "surface_weight": settings.surface_weight,
                       "fit_iou": None if math.isnan(iou) else round(iou, 6)}
    return FitResult(abstraction, seconds, {"score": score}, iou, cancel.is_set(),
                     timings.seconds, timed_out)
