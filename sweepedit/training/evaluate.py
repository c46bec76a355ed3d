"""Benchmark of the sweepers: accuracy against the exact inside test, and speed.

`sweeper_accuracy` draws fresh random sweeps (training.train.random_sweeps, from seeds
that training never uses), labels the cell centres of a 64^3 grid over [-0.5, 0.5]^3 plus
near-surface points with the exact test (sweepedit.geometry.inside), and compares the
sweeper's occupancy hardened at 0.5. `time_forward_backward` times forward + backward
for K primitives x Q queries.

    python -m sweepedit.training.evaluate [--sweeps 100] [--kinds analytic neural]

prints both for the analytic and the neural sweeper (for BENCHMARKS.md).
"""

from __future__ import annotations

import os
import statistics
import time
from typing import Any

import numpy as np
import torch

from sweepedit.fitting.sweepers import Sweeper, load_sweeper
from sweepedit.geometry.inside import grid_points, inside_primitive
from sweepedit.geometry.sweep import scaling_factor
from sweepedit.training.train import random_sweeps, surface_points, to_primitive

EVAL_SEED_TAG = 7919  # keeps evaluation sweeps apart from the training pool's seeds


def evaluation_sweeps(n: int, seed: int = 0, uniform_sizes: bool = False) -> torch.Tensor:
    """n fresh random sweeps as params (n, 14) float32 (not in any training pool)."""
    rng = np.random.default_rng([EVAL_SEED_TAG, seed])
    cps, profile, scaling = random_sweeps(rng, n, log_uniform_size=not uniform_sizes)
    params = np.concatenate([cps.reshape(n, 9), profile, scaling], axis=1)
    return torch.tensor(params, dtype=torch.float32)


def _near_points(params: np.ndarray, rng: np.random.Generator, n: int) -> np.ndarray:
    """n near-surface points of one primitive: surface + N(0, σ²), σ in {0.002, 0.005,
    0.01, 0.02} and 0.1-0.3 x the thinner half-axis (in equal shares)."""
    cps, profile, scaling = params[:9].reshape(3, 3), params[9:12], params[12:]
    surf = surface_points(cps, profile, scaling, rng, n)
    f_mean = float(np.mean(scaling_factor(scaling[None], np.linspace(0, 1, 9))))
    choices = np.array([0.002, 0.005, 0.01, 0.02, -1.0])
    sigma = choices[rng.integers(0, len(choices), n)]
    rel = rng.uniform(0.1, 0.3, n) * min(profile[0], profile[1]) * f_mean
    sigma = np.where(sigma < 0, rel, sigma)
    return surf + rng.normal(size=(n, 3)) * sigma[:, None]


@torch.no_grad()
def _occupancy(sweeper: Sweeper, params: torch.Tensor, queries: torch.Tensor,
               chunk: int = 32768) -> torch.Tensor:
    """params (K, P) sharing queries (Q, 3) -> occupancy (K, Q)."""
    out = []
    for start in range(0, queries.shape[0], chunk):
        out.append(sweeper(params[None], queries[None, start:start + chunk])[0])
    return torch.cat(out, dim=1)


def sweeper_accuracy(sweeper: Sweeper, n_sweeps: int = 100, seed: int = 0,
                     resolution: int = 64, near_points: int = 4096,
                     uniform_sizes: bool = False, batch: int = 8) -> dict[str, Any]:
    """IoU of the sweeper (hardened at 0.5) against the exact inside test.

    For each of n_sweeps fresh random sweeps: the resolution^3 grid of cell centres over
    [-0.5, 0.5]^3 plus near_points near-surface points. Returns iou_mean (mean over
    sweeps of the IoU over grid + near points), iou_pooled (intersections and unions
    summed over all sweeps), iou_grid_mean (grid only, sweeps with a non-empty union),
    near_accuracy (share of near-surface points labelled right), per_sweep (list),
    n_sweeps, seconds.
    """
    t0 = time.perf_counter()
    params = evaluation_sweeps(n_sweeps, seed, uniform_sizes)
    grid = grid_points(resolution)
    grid_t = torch.tensor(grid, dtype=torch.float32)
    rng = np.random.default_rng([EVAL_SEED_TAG, seed, 1])
    sweeper.eval()
    per, grid_ious = [], []
    inter_sum = union_sum = 0
    near_right = near_total = 0
    for start in range(0, n_sweeps, batch):
        block = params[start:start + batch]
        pred_grid = (_occupancy(sweeper, block, grid_t) > 0.5).numpy()
        for j in range(block.shape[0]):
            p = block[j].double().numpy()
            prim = to_primitive(p[:9].reshape(3, 3), p[9:12], p[12:])
            near = _near_points(p, rng, near_points)
            gt_grid = inside_primitive(grid, prim)
            gt_near = inside_primitive(near, prim)
            near_t = torch.tensor(near, dtype=torch.float32)
            pred_near = (_occupancy(sweeper, block[j:j + 1], near_t)[0] > 0.5).numpy()
            pg = pred_grid[j]
            inter = int((pg & gt_grid).sum() + (pred_near & gt_near).sum())
            union = int((pg | gt_grid).sum() + (pred_near | gt_near).sum())
            per.append(inter / union if union else 1.0)
            gu = int((pg | gt_grid).sum())
            if gu:
                grid_ious.append(int((pg & gt_grid).sum()) / gu)
            inter_sum += inter
            union_sum += union
            near_right += int((pred_near == gt_near).sum())
            near_total += near_points
    return {"iou_mean": float(np.mean(per)), "iou_pooled": inter_sum / max(union_sum, 1),
            "iou_grid_mean": float(np.mean(grid_ious)) if grid_ious else float("nan"),
            "near_accuracy": near_right / max(near_total, 1), "iou_min": float(np.min(per)),
            "per_sweep": per, "n_sweeps": n_sweeps, "seconds": time.perf_counter() - t0}


def time_forward_backward(sweeper: Sweeper, n_primitives: int = 8, n_queries: int = 4096,
                          repeats: int = 10, warmup: int = 2, seed: int = 0) -> dict[str, float]:
    """Wall time of forward + backward (w.r.t. the parameters) for B = 1, K x Q, in ms.

    Returns median_ms, min_ms (wall), cpu_ms (median process CPU time: with one thread,
    about the wall time on an idle machine), threads, and the 1-minute load average.
    """
    params = evaluation_sweeps(n_primitives, seed + 1000)[None]  # (1, K, 14)
    gen = torch.Generator().manual_seed(seed)
    queries = torch.rand(1, n_queries, 3, generator=gen) - 0.5
    times, cpu = [], []
    for i in range(warmup + repeats):
        p = params.clone().requires_grad_(True)
        t, c = time.perf_counter(), time.process_time()
        occ = sweeper(p, queries)
        occ.sum().backward()
        if i >= warmup:
            times.append((time.perf_counter() - t) * 1000.0)
            cpu.append((time.process_time() - c) * 1000.0)
    return {"median_ms": statistics.median(times), "min_ms": min(times),
            "cpu_ms": statistics.median(cpu), "load_average": os.getloadavg()[0],
            "threads": torch.get_num_threads()}


def main(argv: list[str] | None = None) -> None:
    """Print accuracy and timing of the sweepers."""
    import argparse
    import json

    ap = argparse.ArgumentParser(description="Benchmark the sweepers against the exact test.")
    ap.add_argument("--sweeps", type=int, default=100)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--kinds", nargs="+", default=["analytic", "neural"])
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--uniform-sizes", action="store_true",
                    help="a, b uniform in [0.01, 0.5] instead of log-uniform")
    args = ap.parse_args(argv)
    torch.set_num_threads(args.threads)
    for kind in args.kinds:
        sweeper = load_sweeper(kind)
        timing = time_forward_backward(sweeper)
        acc = sweeper_accuracy(sweeper, args.sweeps, args.seed, uniform_sizes=args.uniform_sizes)
        acc.pop("per_sweep")
        print(json.dumps({"sweeper": kind, **{k: round(v, 4) if isinstance(v, float) else v
                                               for k, v in {**acc, **timing}.items()}}))


if __name__ == "__main__":
    main()
