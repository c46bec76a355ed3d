"""Training of the neural sweeper on random sweeps labelled by the exact inside test.

Data: random primitives over the ranges of docs/primitive.md (`random_sweeps`), each
with labelled query points (`label_points`): half near the surface (points of the exact
swept surface and caps, jittered), a quarter uniform in the primitive's bounding box and
a quarter uniform in the cube [-0.6, 0.6]^3, labelled with
sweepedit.geometry.inside.inside_primitive. Labelling is slow-ish in numpy, so a pool of
labelled sweeps is generated once (in a background process while training starts) and
cached as chunk files; batches are drawn from it.

Training: binary cross-entropy on the occupancy logits, Adam with cosine decay, tqdm
progress, periodic checkpoints (model, optimizer, step) that `resume=True` continues
from, and the final weights + architecture config in one small file that
sweepedit.fitting.sweepers.load_neural reads.
"""

from __future__ import annotations

import json
import math
import multiprocessing as mp
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch.nn.functional import binary_cross_entropy_with_logits

from sweepedit.errors import FileFormatError
from sweepedit.fitting.sweepers import NEURAL_WEIGHTS, NeuralSweeper, build_neural
from sweepedit.geometry.inside import inside_primitive
from sweepedit.geometry.model import SweepPrimitive
from sweepedit.geometry.sweep import axis_frames, scaling_factor, superellipse, sweep_surface

DEFAULT_POOL_DIR = Path("/tmp/sweepedit_sweeper_pool")
CHUNK_SWEEPS = 250
MIN_SCALE = 0.05

ProgressCallback = Callable[[int, int, dict[str, float]], None]


# ----------------------------------------------------------------------------------------
# Random sweeps and labelled points
# ----------------------------------------------------------------------------------------


def random_sweeps(rng: np.random.Generator, n: int, wild_fraction: float = 0.5,
                  log_uniform_size: bool = True) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """n random primitives (n = 3 control points, k = 2) over the ranges of docs/primitive.md.

    A share `wild_fraction` has its 3 control points uniform in [-0.5, 0.5]^3; the rest
    are shape-like: a start point in the cube, a random direction and length in
    [0.1, 0.9], the middle control point pushed off the chord by up to half its length,
    clipped into the cube. a, b in [0.01, 0.5] (log-uniform if log_uniform_size, so thin
    profiles are common, else uniform); d log-uniform in [0.3, 5]; s1, s2 uniform in
    [-0.5, 0.5], redrawn while f drops below 0.05 on [0, 1].
    Returns control_points (n, 3, 3), profile (n, 3) = [a, b, d], scaling (n, 2).
    """
    cps = rng.uniform(-0.5, 0.5, (n, 3, 3))
    tame = rng.random(n) >= wild_fraction
    m = int(tame.sum())
    if m:
        start = rng.uniform(-0.45, 0.45, (m, 3))
        direction = rng.normal(size=(m, 3))
        direction /= np.linalg.norm(direction, axis=1, keepdims=True)
        length = rng.uniform(0.1, 0.9, (m, 1))
        end = start + direction * length
        side = rng.normal(size=(m, 3))
        side -= (side * direction).sum(1, keepdims=True) * direction
        side /= np.maximum(np.linalg.norm(side, axis=1, keepdims=True), 1e-9)
        bend = rng.uniform(0.0, 0.5, (m, 1)) * length * (rng.random((m, 1)) < 0.8)
        mid = (start + end) / 2 + side * bend
        cps[tame] = np.clip(np.stack([start, mid, end], axis=1), -0.5, 0.5)
    if log_uniform_size:
        ab = np.exp(rng.uniform(np.log(0.01), np.log(0.5), (n, 2)))
    else:
        ab = rng.uniform(0.01, 0.5, (n, 2))
    d = np.exp(rng.uniform(np.log(0.3), np.log(5.0), (n, 1)))
    scaling = rng.uniform(-0.5, 0.5, (n, 2))
    t = np.linspace(0.0, 1.0, 65)
    while True:
        bad = scaling_factor(scaling, t).min(axis=1) < MIN_SCALE
        if not bad.any():
            break
        scaling[bad] = rng.uniform(-0.5, 0.5, (int(bad.sum()), 2))
    return cps, np.concatenate([ab, d], axis=1), scaling


def to_primitive(cps: np.ndarray, profile: np.ndarray, scaling: np.ndarray) -> SweepPrimitive:
    """One row of random_sweeps' arrays -> SweepPrimitive."""
    return SweepPrimitive(cps, a=float(profile[0]), b=float(profile[1]),
                          degree=float(profile[2]), scaling=tuple(float(s) for s in scaling))


def surface_points(cps: np.ndarray, profile: np.ndarray, scaling: np.ndarray,
                   rng: np.random.Generator, n: int, cap_share: float = 0.15) -> np.ndarray:
    """n points on one primitive's surface (side and caps), (n, 3) float64."""
    n_cap = round(n * cap_share)
    n_side = n - n_cap
    m = math.ceil(math.sqrt(n_side)) + 1
    t = np.sort(rng.random(m))
    theta = rng.uniform(0.0, 2.0 * np.pi, m)
    side = sweep_surface(cps[None], profile[None], scaling[None], t, theta)[0].reshape(-1, 3)
    side = side[rng.choice(len(side), n_side, replace=False)]
    ends = np.array([0.0, 1.0])
    fr = axis_frames(cps[None], ends)
    f = scaling_factor(scaling[None], ends)[0]
    which = rng.integers(0, 2, n_cap)
    x, y = superellipse(rng.uniform(0.0, 2.0 * np.pi, n_cap), profile[None])
    r = np.sqrt(rng.random(n_cap)) * f[which]
    caps = (fr.points[0, which] + r[:, None] * (x[0][:, None] * fr.U[0, which]
                                                + y[0][:, None] * fr.V[0, which]))
    return np.concatenate([side, caps])


def label_points(cps: np.ndarray, profile: np.ndarray, scaling: np.ndarray,
                 rng: np.random.Generator, n: int = 2048) -> tuple[np.ndarray, np.ndarray]:
    """Query points around one primitive and their exact labels: (n, 3) float32, (n,) bool.

    Half near the surface (surface points plus Gaussian noise, σ log-uniform in
    [0.0005, 0.05] for half of them and a fraction in [0.02, 0.5] of the thinner profile
    half-axis for the other half), a quarter uniform in the primitive's padded bounding
    box, a quarter uniform in [-0.6, 0.6]^3.
    """
    n_near = n // 2
    n_box = n // 4
    n_cube = n - n_near - n_box
    surf = surface_points(cps, profile, scaling, rng, n_near)
    sigma_abs = np.exp(rng.uniform(np.log(5e-4), np.log(0.05), n_near))
    f_mean = float(np.mean(scaling_factor(scaling[None], np.linspace(0, 1, 9))))
    sigma_rel = rng.uniform(0.02, 0.5, n_near) * min(profile[0], profile[1]) * f_mean
    sigma = np.where(rng.random(n_near) < 0.5, sigma_abs, sigma_rel)
    near = surf + rng.normal(size=(n_near, 3)) * sigma[:, None]
    lo, hi = surf.min(axis=0) - 0.02, surf.max(axis=0) + 0.02
    box = rng.uniform(lo, hi, (n_box, 3))
    cube = rng.uniform(-0.6, 0.6, (n_cube, 3))
    pts = np.concatenate([near, box, cube])
    labels = inside_primitive(pts, to_primitive(cps, profile, scaling))
    return pts.astype(np.float32), labels


def make_chunk(seed: int, n_sweeps: int = CHUNK_SWEEPS,
               points: int = 2048) -> dict[str, np.ndarray]:
    """n_sweeps labelled sweeps from one seed: params (S, 14), points (S, Pt, 3), labels."""
    rng = np.random.default_rng(seed)
    cps, profile, scaling = random_sweeps(rng, n_sweeps)
    pts = np.zeros((n_sweeps, points, 3), dtype=np.float32)
    lab = np.zeros((n_sweeps, points), dtype=bool)
    for i in range(n_sweeps):
        pts[i], lab[i] = label_points(cps[i], profile[i], scaling[i], rng, points)
    params = np.concatenate([cps.reshape(n_sweeps, 9), profile, scaling], axis=1)
    return {"params": params.astype(np.float32), "points": pts, "labels": lab}


def _chunk_path(pool_dir: Path, index: int, points: int) -> Path:
    return pool_dir / f"chunk_{points}_{index:05d}.npz"


def generate_pool(pool_dir: str | Path, n_chunks: int, points: int = 2048,
                  seed: int = 0, start: int = 0) -> None:
    """Write chunk files start..n_chunks-1 that do not exist yet (atomically).

    Chunk i uses seed (seed, i); the evaluation draws from other seeds.
    """
    torch.set_num_threads(1)
    pool_dir = Path(pool_dir)
    pool_dir.mkdir(parents=True, exist_ok=True)
    for i in range(start, n_chunks):
        path = _chunk_path(pool_dir, i, points)
        if path.exists():
            continue
        chunk = make_chunk(int(np.random.SeedSequence([seed, i]).generate_state(1)[0]),
                           points=points)
        tmp = path.with_suffix(".tmp.npz")
        np.savez(tmp, **chunk)
        tmp.replace(path)


class Pool:
    """The labelled sweeps available on disk; refresh() picks up new chunks."""

    def __init__(self, pool_dir: Path, n_chunks: int, points: int) -> None:
        self.pool_dir, self.n_chunks, self.points = pool_dir, n_chunks, points
        self.loaded: set[int] = set()
        self.params: list[np.ndarray] = []
        self.pts: list[np.ndarray] = []
        self.labels: list[np.ndarray] = []
        self._cat: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None

    def refresh(self) -> int:
        for i in range(self.n_chunks):
            path = _chunk_path(self.pool_dir, i, self.points)
            if i in self.loaded or not path.exists():
                continue
            with np.load(path) as z:
                self.params.append(z["params"])
                self.pts.append(z["points"])
                self.labels.append(z["labels"])
            self.loaded.add(i)
            self._cat = None
        return self.size

    @property
    def size(self) -> int:
        return sum(len(p) for p in self.params)

    def batch(self, rng: np.random.Generator, batch_size: int,
              queries: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """params (B, 1, 14), queries (B, Qb, 3), labels (B, 1, Qb) float."""
        if self._cat is None:
            self._cat = (np.concatenate(self.params), np.concatenate(self.pts),
                         np.concatenate(self.labels))
        params, pts, labels = self._cat
        idx = rng.integers(0, len(params), batch_size)
        cols = np.stack([rng.choice(pts.shape[1], queries, replace=False)
                         for _ in range(batch_size)])
        q = np.take_along_axis(pts[idx], cols[..., None], axis=1)
        lab = np.take_along_axis(labels[idx], cols, axis=1)
        return (torch.from_numpy(params[idx][:, None]), torch.from_numpy(q),
                torch.from_numpy(lab[:, None].astype(np.float32)))


# ----------------------------------------------------------------------------------------
# Training
# ----------------------------------------------------------------------------------------


@dataclass
class TrainConfig:
    """Training recipe (stored in checkpoints and in the final file)."""

    steps: int = 3000
    batch_size: int = 24
    queries: int = 1024
    lr: float = 2e-3
    lr_min: float = 1e-4
    seed: int = 0
    pool_sweeps: int = 12000
    points_per_sweep: int = 2048
    latent: int = 48
    value: int = 8
    hidden: int = 96


def _save_atomic(obj: Any, path: Path) -> None:
    tmp = path.with_name(path.name + ".tmp")
    torch.save(obj, tmp)
    tmp.replace(path)


def load_checkpoint(path: Path) -> dict[str, Any]:
    """A training checkpoint (model, optimizer, step, seconds, config) from path, read
    with torch's weights-only loader: tensors and plain containers only, so a planted
    file cannot run code while it is unpickled. Raises FileFormatError naming the file."""
    try:
        ck = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # torch raises UnpicklingError, RuntimeError, EOFError...
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise FileFormatError(path, "not a sweepedit training checkpoint, or one holding more "
                                    f"than tensors and plain values ({first})") from exc
    if not isinstance(ck, dict) or not {"model", "optimizer", "step"} <= ck.keys():
        raise FileFormatError(path, "not a sweepedit training checkpoint (it needs model, "
                                    "optimizer and step)")
    return ck


def save_weights(net: NeuralSweeper, path: str | Path, extra: dict[str, Any] | None = None,
                 half: bool = False) -> None:
    """Write {'config', 'state_dict', 'info'} (float32, or float16 if half) to path."""
    state = {k: (v.half() if half and v.is_floating_point() else v.float()).clone()
             for k, v in net.state_dict().items()}
    blob = {"config": dict(net.config), "state_dict": state, "info": dict(extra or {})}
    json.dumps(blob["config"])
    json.dumps(blob["info"])
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    _save_atomic(blob, path)


def train_sweeper(out_path: str | Path = NEURAL_WEIGHTS, steps: int = 3000,
                  batch_size: int = 24, lr: float = 2e-3, seed: int = 0,
                  resume: bool = False, *, queries: int = 1024,
                  pool_dir: str | Path = DEFAULT_POOL_DIR, pool_sweeps: int = 12000,
                  points_per_sweep: int = 2048, checkpoint_every: int = 200,
                  checkpoint_path: str | Path | None = None, threads: int | None = 2,
                  progress: bool = True, callback: ProgressCallback | None = None,
                  time_limit_s: float | None = None,
                  architecture: dict[str, int] | None = None) -> dict[str, Any]:
    """Train the neural sweeper and write its weights to out_path.

    steps, batch_size (sweeps per step), queries (points per sweep per step), lr (Adam,
    cosine decay to lr/20), seed. The labelled pool (pool_sweeps sweeps of
    points_per_sweep points) is cached in pool_dir; missing chunks are generated by a
    background process while training uses those already there. A checkpoint (model,
    optimizer, step; default out_path + '.ckpt') is written every checkpoint_every steps
    and at the end; resume=True continues from it. callback(step, steps, metrics) is
    called after every step; progress shows a tqdm bar. time_limit_s stops early (the
    weights are still written). Returns a summary dict (steps done, seconds, last loss).
    """
    from tqdm import tqdm

    if threads:
        torch.set_num_threads(threads)
    cfg = TrainConfig(steps=steps, batch_size=batch_size, queries=queries, lr=lr,
                      lr_min=lr / 20.0, seed=seed, pool_sweeps=pool_sweeps,
                      points_per_sweep=points_per_sweep, **(architecture or {}))
    out_path = Path(out_path)
    ckpt_path = Path(checkpoint_path) if checkpoint_path else out_path.with_name(
        out_path.name + ".ckpt")
    torch.manual_seed(seed)
    net = build_neural({"latent": cfg.latent, "value": cfg.value, "hidden": cfg.hidden})
    opt = torch.optim.Adam(net.parameters(), lr=lr)
    start_step, elapsed = 0, 0.0
    rng = np.random.default_rng(seed)
    if resume and ckpt_path.exists():
        ck = load_checkpoint(ckpt_path)
        net.load_state_dict(ck["model"])
        opt.load_state_dict(ck["optimizer"])
        start_step, elapsed = int(ck["step"]), float(ck.get("seconds", 0.0))
        rng = np.random.default_rng([seed, start_step])

    pool_dir = Path(pool_dir)
    n_chunks = max(1, math.ceil(pool_sweeps / CHUNK_SWEEPS))
    pool = Pool(pool_dir, n_chunks, points_per_sweep)
    worker = None
    if pool.refresh() < pool_sweeps:
        worker = mp.get_context("spawn").Process(
            target=generate_pool, args=(pool_dir, n_chunks, points_per_sweep, seed), daemon=True)
        worker.start()
        while pool.refresh() == 0:
            if not worker.is_alive() and pool.refresh() == 0:
                raise RuntimeError("the data generator stopped before writing any chunk")
            time.sleep(1.0)

    def save_checkpoint(step: int) -> None:
        _save_atomic({"model": net.state_dict(), "optimizer": opt.state_dict(), "step": step,
                      "seconds": elapsed, "config": asdict(cfg)}, ckpt_path)

    bar = tqdm(total=steps, initial=start_step, disable=not progress, desc="train sweeper")
    t0 = time.perf_counter()
    loss_ema, acc_ema = None, None
    step = start_step
    try:
        for step in range(start_step, steps):
            if step % 50 == 0:
                pool.refresh()
            frac = step / max(steps - 1, 1)
            if time_limit_s:  # decay on whichever runs out first, steps or time
                frac = max(frac, (elapsed + time.perf_counter() - t0) / time_limit_s)
            frac = min(frac, 1.0)
            for group in opt.param_groups:
                group["lr"] = cfg.lr_min + 0.5 * (lr - cfg.lr_min) * (1 + math.cos(math.pi * frac))
            params, q, labels = pool.batch(rng, batch_size, queries)
            logits = net.forward_logits(params, q)
            loss = binary_cross_entropy_with_logits(logits, labels)
            opt.zero_grad(set_to_none=True)
            loss.backward()
            torch.nn.utils.clip_grad_norm_(net.parameters(), 1.0)
            opt.step()
            with torch.no_grad():
                acc = ((logits > 0).float() == labels).float().mean().item()
            loss_ema = loss.item() if loss_ema is None else 0.98 * loss_ema + 0.02 * loss.item()
            acc_ema = acc if acc_ema is None else 0.98 * acc_ema + 0.02 * acc
            metrics = {"loss": loss_ema, "acc": acc_ema, "pool": float(pool.size),
                       "lr": opt.param_groups[0]["lr"]}
            bar.set_postfix(loss=f"{loss_ema:.4f}", acc=f"{acc_ema:.4f}", pool=pool.size)
            bar.update(1)
            if callback is not None:
                callback(step + 1, steps, metrics)
            now = time.perf_counter()
            if (step + 1) % checkpoint_every == 0:
                elapsed += now - t0
                t0 = now
                save_checkpoint(step + 1)
            if time_limit_s is not None and elapsed + (now - t0) > time_limit_s:
                step += 1
                break
        else:
            step = steps
    finally:
        bar.close()
        if worker is not None and worker.is_alive():
            worker.terminate()
            worker.join()
    elapsed += time.perf_counter() - t0
    save_checkpoint(step)
    info = {"steps": step, "seconds": round(elapsed, 1), "loss": loss_ema, "acc": acc_ema,
            "pool_sweeps": pool.size, "recipe": asdict(cfg),
            "threads": torch.get_num_threads()}
    save_weights(net, out_path, extra=info)
    return info


def main(argv: list[str] | None = None) -> None:
    """python -m sweepedit.training.train [--steps N] [--resume] ..."""
    import argparse

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out", default=str(NEURAL_WEIGHTS))
    ap.add_argument("--steps", type=int, default=3000)
    ap.add_argument("--batch-size", type=int, default=24)
    ap.add_argument("--queries", type=int, default=1024)
    ap.add_argument("--lr", type=float, default=2e-3)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--pool-sweeps", type=int, default=12000)
    ap.add_argument("--pool-dir", default=str(DEFAULT_POOL_DIR))
    ap.add_argument("--time-limit", type=float, default=None)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--resume", action="store_true")
    args = ap.parse_args(argv)
    info = train_sweeper(args.out, args.steps, args.batch_size, args.lr, args.seed, args.resume,
                         queries=args.queries, pool_dir=args.pool_dir,
                         pool_sweeps=args.pool_sweeps, time_limit_s=args.time_limit,
                         threads=args.threads)
    print(json.dumps(info, indent=1))


if __name__ == "__main__":
    main()
