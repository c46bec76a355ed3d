"""Fitting: a known sweep is recovered, cancellation, seeds, locked primitives."""

from __future__ import annotations

import threading
from pathlib import Path

import numpy as np
import pytest

from sweepedit.fitting.fit import FitSettings, fit_abstraction
from sweepedit.geometry.mesher import sweep_mesh
from sweepedit.geometry.model import SweepPrimitive
from sweepedit.io.mesh_export import write_mesh
from sweepedit.io.shapes import load_shape

TRUTH = SweepPrimitive([[-0.4, -0.1, 0.0], [0.0, 0.35, 0.05], [0.4, -0.1, 0.0]], a=0.09,
                       b=0.06, degree=2.5, scaling=(0.2, -0.3))


@pytest.fixture(scope="module")
def arch_shape(tmp_path_factory: pytest.TempPathFactory):
    path = tmp_path_factory.mktemp("arch") / "arch.stl"
    write_mesh(sweep_mesh(TRUTH, 96, 64), path)
    return load_shape(path)


def quick(**kwargs) -> FitSettings:
    base = {"primitives": 2, "iterations": 60, "batch_points": 2048, "seed": 0}
    base.update(kwargs)
    return FitSettings(**base)


def test_short_fit_recovers_a_known_sweep(arch_shape) -> None:
    from sweepedit.analysis.metrics import evaluate

    result = fit_abstraction(arch_shape, quick(iterations=120))
    metrics = evaluate(result.abstraction, arch_shape, n_samples=20000)
    assert metrics["iou"] >= 0.8, metrics
    assert result.abstraction.fit["fit_iou"] == pytest.approx(result.iou)
    assert result.abstraction.fit["refine_steps"] == 300  # K = 2: the minimum
    for p in result.abstraction.primitives:
        p.validate()


def test_refinement_steps_grow_with_the_primitives_unless_set() -> None:
    assert [FitSettings(primitives=k).refine_steps for k in (1, 8, 12, 16, 32)] == \
        [300, 300, 450, 600, 1200]
    assert FitSettings(primitives=16, refine_iterations=0).refine_steps == 0
    assert FitSettings(primitives=16, refine_iterations=100).refine_steps == 100


def test_fit_is_reproducible_for_a_seed(arch_shape) -> None:
    a = fit_abstraction(arch_shape, quick(iterations=15))
    b = fit_abstraction(arch_shape, quick(iterations=15))
    assert len(a.abstraction) == len(b.abstraction)
    for p, q in zip(a.abstraction.primitives, b.abstraction.primitives, strict=True):
        np.testing.assert_array_equal(p.control_points, q.control_points)
        assert (p.a, p.b, p.degree, p.scaling) == (q.a, q.b, q.degree, q.scaling)


def test_cancel_returns_a_valid_best_so_far(arch_shape) -> None:
    cancel = threading.Event()
    seen = []

    def callback(progress) -> None:
        seen.append(progress.iteration)
        for p in progress.abstraction.primitives:
            p.validate()
        if progress.iteration >= 10:
            cancel.set()

    result = fit_abstraction(arch_shape, quick(iterations=10_000, progress_every=5),
                             callback=callback, cancel=cancel)
    assert result.cancelled
    assert max(seen) < 100
    assert len(result.abstraction) >= 1
    for p in result.abstraction.primitives:
        p.validate()


def test_locked_primitives_are_unchanged(arch_shape) -> None:
    locked = TRUTH.copy()
    locked.locked = True
    locked.name = "kept"
    result = fit_abstraction(arch_shape, quick(primitives=1, iterations=20), locked=[locked])
    first = result.abstraction.primitives[0]
    np.testing.assert_array_equal(first.control_points, TRUTH.control_points)
    assert (first.a, first.b, first.degree, first.scaling, first.name) == (
        TRUTH.a, TRUTH.b, TRUTH.degree, TRUTH.scaling, "kept")


def test_empty_shape_is_a_clear_error(tmp_path: Path) -> None:
    from sweepedit.errors import SweepeditError

    grid = np.zeros((16, 16, 16), dtype=bool)
    np.save(tmp_path / "empty.npy", grid)
    with pytest.raises(SweepeditError):
        fit_abstraction(load_shape(tmp_path / "empty.npy"), quick())


def test_cancel_during_refinement_keeps_a_valid_result(arch_shape) -> None:
    cancel = threading.Event()
    seen = []

    def callback(progress) -> None:
        seen.append((progress.iteration, progress.total))
        for p in progress.abstraction.primitives:
            p.validate()
        if progress.iteration > 30:
            cancel.set()

    settings = quick(refine_iterations=5_000, progress_every=5)
    result = fit_abstraction(arch_shape, settings, callback=callback, cancel=cancel)
    assert result.cancelled
    # The refinement reports on the same count as the network stage, to the same total.
    assert {total for _, total in seen} == {5_000 + 2 * 2_500}
    assert 30 < max(it for it, _ in seen) < 100
    assert len(result.abstraction) >= 1
    for p in result.abstraction.primitives:
        p.validate()


def test_refinement_improves_on_the_network_stage(arch_shape) -> None:
    from sweepedit.analysis.metrics import evaluate

    # Quadratic Bezier axes: a layout that the network's 40 steps leave coarse (with
    # the default 8 control points they already reach IoU 0.96 on this arch).
    simple = {"control_points": 3, "scaling_degree": 2}
    network = fit_abstraction(arch_shape, quick(method="network", iterations=40,
                                                refine_iterations=0, **simple))
    refined = fit_abstraction(arch_shape, quick(method="network", iterations=40,
                                                refine_iterations=100, **simple))
    m_net = evaluate(network.abstraction, arch_shape, n_samples=20000)
    m_ref = evaluate(refined.abstraction, arch_shape, n_samples=20000)
    assert m_ref["iou"] > m_net["iou"] + 0.02, (m_net, m_ref)
    assert m_ref["cd_l1"] < m_net["cd_l1"], (m_net, m_ref)


def test_progress_stages_come_in_order_with_monotone_fractions(arch_shape) -> None:
    seen: list[tuple[str, float, float | None]] = []

    def callback(p) -> None:
        for prim in p.abstraction.primitives:
            prim.validate()
        seen.append((p.stage, p.stage_fraction, p.seconds_left))

    fit_abstraction(arch_shape, quick(method="network", iterations=20, refine_iterations=60,
                                      residual_rounds=2, progress_every=5), callback=callback)
    # The first report is the warm start, a complete abstraction, before any step.
    assert seen[0][:2] == ("warm start", 1.0)
    stages = [stage for stage, _, _ in seen]
    order = list(dict.fromkeys(stages))  # each stage once, in order of appearance
    assert order[:3] == ["warm start", "network", "refinement"], order
    assert all(stage.startswith("residual round") for stage in order[3:]), order
    # Stages do not interleave: once left, a stage does not come back.
    assert [s for i, s in enumerate(stages) if i == 0 or stages[i - 1] != s] == order
    for stage in order:
        fractions = [f for s, f, _ in seen if s == stage]
        assert fractions == sorted(fractions), (stage, fractions)
        assert fractions[-1] == 1.0, (stage, fractions)
        assert all(0.0 <= f <= 1.0 for f in fractions)
    assert any(left is not None for _, _, left in seen[1:])


def test_time_limit_returns_a_valid_abstraction_in_time(arch_shape) -> None:
    import time

    start = time.perf_counter()
    result = fit_abstraction(arch_shape, quick(method="network", iterations=100_000,
                                               time_limit=1.0))
    elapsed = time.perf_counter() - start
    assert result.timed_out and not result.cancelled
    assert elapsed < 1.0 + 2.5, elapsed  # 100000 iterations would take many minutes
    assert len(result.abstraction) >= 1
    for p in result.abstraction.primitives:
        p.validate()
    assert result.abstraction.fit["timed_out"] is True


def test_unknown_method_and_missing_cuda_are_clear_errors(arch_shape) -> None:
    import torch

    from sweepedit.errors import SweepeditError

    with pytest.raises(SweepeditError, match="method"):
        fit_abstraction(arch_shape, quick(method="magic"))
    if not torch.cuda.is_available():
        with pytest.raises(SweepeditError, match="CUDA"):
            fit_abstraction(arch_shape, quick(device="cuda"))


@pytest.mark.slow
@pytest.mark.parametrize("name", ["eight", "cactus", "hand"])
def test_default_fit_is_as_good_as_the_paper_network_path(shapes_dir: Path, name: str) -> None:
    """The direct default against SweepNet's network stage (then the same refinement),
    same K, both scored by the exact inside test against the shape's winding number."""
    from sweepedit.analysis.metrics import RESOLUTION, shape_inside_grid
    from sweepedit.analysis.metrics import iou as grid_iou
    from sweepedit.geometry.inside import grid_points, inside_union

    shape = load_shape(next(shapes_dir.glob(f"{name}.*")))
    target = shape_inside_grid(shape)
    cells = grid_points(RESOLUTION)
    scores = {}
    for method in ("direct", "network"):
        result = fit_abstraction(shape, FitSettings(primitives=4, method=method))
        scores[method] = grid_iou(inside_union(cells, result.abstraction.primitives), target)
    assert scores["direct"] >= scores["network"] - 0.02, scores


def test_the_keep_threshold_shrinks_with_the_budget_beyond_eight() -> None:
    """A primitive's natural share of the shape is about 1/K: beyond 8 primitives the
    score it must add to be kept shrinks as 8/K (K = 16 kept 13.1 -> 13.4 primitives and
    put F1@0.01 ahead of Marching-Primitives, BENCHMARKS.md); up to 8 it is min_gain."""
    assert FitSettings(primitives=4, min_gain=0.002).keep_gain == 0.002
    assert FitSettings(primitives=8).keep_gain == FitSettings().min_gain
    assert FitSettings(primitives=16).keep_gain == pytest.approx(FitSettings().min_gain / 2)
    assert FitSettings(primitives=32, min_gain=0.004).keep_gain == pytest.approx(0.001)


def test_time_left_follows_the_pace_after_the_first_step(monkeypatch) -> None:
    """A slow first step (code loading) or a slow preparation does not inflate the
    estimate: it comes from the pace between reports after the first one."""
    import threading

    from sweepedit.fitting import fit as fit_module

    now = [0.0]
    monkeypatch.setattr(fit_module.time, "perf_counter", lambda: now[0])
    clock = fit_module._Clock(None, threading.Event(), total_steps=100)
    now[0] = 5.0  # preparation and a first step that compiled code
    assert clock.seconds_left(1) is None
    now[0] = 6.0  # then 0.1 s a step
    assert clock.seconds_left(11) == pytest.approx(89 * 0.1)
    now[0] = 7.0
    assert clock.seconds_left(21) == pytest.approx(79 * 0.1)
    limited = fit_module._Clock(8.0, threading.Event(), total_steps=100)
    now[0] = 11.0  # 4 s after its start: at most the 4 s left of the limit
    assert limited.seconds_left(1) == pytest.approx(4.0)


def _tubes(count: int) -> list[SweepPrimitive]:
    """count straight round tubes, parallel to z, apart from each other."""
    angles = np.linspace(0.0, 2.0 * np.pi, count, endpoint=False)
    ring = 0.0 if count == 1 else 0.3
    return [SweepPrimitive([[ring * np.cos(a), ring * np.sin(a), -0.35],
                            [ring * np.cos(a), ring * np.sin(a), 0.0],
                            [ring * np.cos(a), ring * np.sin(a), 0.35]],
                           a=0.06, b=0.06, degree=2.0, scaling=(0.0, 0.0)) for a in angles]


@pytest.fixture(scope="module")
def tube_shapes(tmp_path_factory: pytest.TempPathFactory) -> dict[int, object]:
    """Shapes made of 1, 3 and 6 separate straight tubes (one mesh file each)."""
    from sweepedit.geometry.mesher import union_mesh

    folder = tmp_path_factory.mktemp("tubes")
    shapes = {}
    for count in (1, 3, 6):
        path = folder / f"tubes_{count}.stl"
        write_mesh(union_mesh([sweep_mesh(p, 64, 48) for p in _tubes(count)]), path)
        shapes[count] = load_shape(path)
    return shapes


@pytest.mark.parametrize("count", [1, 3, 6])
def test_auto_finds_one_primitive_per_separate_tube(tube_shapes, count: int) -> None:
    """With the automatic count the shape decides: one sweep per tube, each following
    its tube, and the result says why it stopped adding."""
    from sweepedit.analysis.metrics import evaluate
    from sweepedit.fitting.refine import STOP_REASONS

    shape = tube_shapes[count]
    result = fit_abstraction(shape, FitSettings(primitives=32, auto=True))
    prims = result.abstraction.primitives
    assert len(prims) == count
    assert result.stopped in STOP_REASONS and result.abstraction.fit["stopped"] == result.stopped
    assert result.abstraction.fit["auto"] is True
    metrics = evaluate(result.abstraction, shape, n_samples=20000)
    # The truth scores IoU 1. Axes of 8 control points fit these straight tubes a little
    # thin (6 tubes: 0.947 where 3 control points give 0.981; the 30 benchmark shapes
    # prefer 8), so the bar is a gross-failure guard; the count and the axes below are
    # what this test is about.
    assert metrics["iou"] > 0.93 and metrics["f1_0.05"] > 0.99, metrics
    # Each primitive on its own tube: its axis within a tube radius of the tube's.
    centres = shape.normalization.to_normalized(np.array(
        [t.control_points[1] for t in _tubes(count)]))
    for p in prims:
        middle = p.control_points[len(p.control_points) // 2]
        assert np.min(np.linalg.norm(centres[:, :2] - middle[:2], axis=1)) < 0.06


def test_auto_stops_at_its_cap_and_when_accurate(tube_shapes) -> None:
    shape = tube_shapes[6]
    capped = fit_abstraction(shape, FitSettings(primitives=4, auto=True))
    assert len(capped.abstraction.primitives) <= 4
    # A loose tolerance is met at once: no residual round runs.
    loose = fit_abstraction(tube_shapes[1], FitSettings(primitives=32, auto=True,
                                                        tolerance=0.2))
    assert loose.stopped == "accurate"
    assert loose.abstraction.fit["agreement"] >= 0.95


@pytest.mark.slow
def test_a_known_sweep_is_recovered_to_a_sub_voxel(tmp_path: Path) -> None:
    """One primitive fitted to a fine mesh of a known sweep (the shell term and the
    default layout): its axis within 0.5% of the bounding box (a third of a 64^3 cell)
    of the true axis, its half-axes within 1%, its surface within 0.01 of the truth
    almost everywhere (the exact inside test at points 0.01 inside and outside)."""
    from scipy.spatial import cKDTree

    from sweepedit.geometry.inside import inside_primitive
    from sweepedit.geometry.sweep import axis_points

    path = tmp_path / "arch.stl"
    write_mesh(sweep_mesh(TRUTH, 256, 128), path)
    shape = load_shape(path)
    truth = TRUTH.copy()
    truth.control_points = shape.normalization.to_normalized(TRUTH.control_points)
    truth.a, truth.b = (v / shape.normalization.scale for v in (TRUTH.a, TRUTH.b))
    fitted = fit_abstraction(shape, FitSettings(primitives=1)).abstraction.primitives
    assert len(fitted) == 1
    p = fitted[0]
    t = np.linspace(0.0, 1.0, 401)
    got, want = (axis_points(q.control_points[None], t)[0] for q in (p, truth))
    assert max(cKDTree(want).query(got)[0].max(), cKDTree(got).query(want)[0].max()) < 0.005
    assert p.a == pytest.approx(truth.a, rel=0.01) and p.b == pytest.approx(truth.b, rel=0.01)
    pairs, labels = shape.shell_samples(4000, 0.01, seed=5)
    assert np.mean(inside_primitive(pairs, p) == labels) > 0.97
