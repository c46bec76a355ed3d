"""`sweepedit batch` on Ray: throughput, the engine's overhead, a simulated cluster that
loses a node, and the scale on paper (BENCHMARKS.md, "Batch on Ray").

    OMP_NUM_THREADS=1 .venv/bin/python benchmarks/bench_batch.py [--shapes DIR]
        [--out bench-out/batch] [--price 0.045] [--smoke]

1. Throughput: every shape of DIR (30 in ../shared/shapes) at a short fit of fixed work
   (K = 8, 100 refinement steps, 1 residual round: no time limit, so a slower core
   shows as time, not as a worse fit), 1 CPU per task, through a Ray instance of 1 and
   of 2 workers (started before the clock: the time is the job's). Target: 2 workers
   >= 1.8 x the shapes per minute of 1.
2. Overhead: a few shapes (OVERHEAD_SHAPES) at the default fit, one at a time on 1 CPU,
   in this process without Ray and through Ray with 1 worker (the worker's start and
   imports counted). Target: Ray <= 5 % slower.
3. Cluster: ray.cluster_utils.Cluster with a 1-CPU head and 2 one-CPU worker nodes on
   this machine, 8 shapes at the short fit; once a worker node has a shape running it is
   removed. Every shape must still finish (Ray retries the lost tasks); the nodes each
   shape ran on are listed.
4. Scale on paper: hours and cost of 10,000 and 100,000 shapes on N one-CPU workers from
   the default fit's measured seconds per shape (step 2, Ray), at --price dollars per
   vCPU-hour.

Prints Markdown for BENCHMARKS.md and writes OUT/bench_batch.json. --smoke: 3 shapes,
tiny fits, no cluster node removal timing -- only to check that the script runs.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import threading
import time
from dataclasses import replace
from pathlib import Path

import ray

from sweepedit.batch import BatchOptions, JobSpec, expand_inputs, run_batch
from sweepedit.batch.inputs import ShapeInput
from sweepedit.fitting.fit import FitSettings

DEFAULT_SHAPES = Path(__file__).resolve().parents[1].parent / "shared" / "shapes"
SHORT = FitSettings(primitives=8, refine_iterations=100, residual_rounds=1)
# Default-fit times (2 threads, BENCHMARKS.md) of 11 to 23.5 s around the set's median 18.2.
OVERHEAD_SHAPES = ("cactus", "dino", "hand", "glyph_S")
QUIET = {"include_dashboard": False, "log_to_driver": False, "logging_level": "ERROR"}


def _run(shapes: list[ShapeInput], out: Path, spec: JobSpec, engine: str,
         workers: int | None = None) -> dict[str, float]:
    """One job from scratch; wall seconds, shapes per minute, median seconds per shape."""
    start = time.perf_counter()
    report = run_batch(shapes, BatchOptions(out, spec, engine=engine, workers=workers,
                                            resume=False, progress=False))
    wall = time.perf_counter() - start
    if report.failed:
        print(f"  failed: {[(o.name, o.error) for o in report.failed]}", file=sys.stderr)
    seconds = [o.seconds for o in report.ok]
    return {"shapes": len(report.outcomes), "failed": len(report.failed), "wall_s": wall,
            "shapes_per_min": 60 * len(report.ok) / wall,
            "median_shape_s": statistics.median(seconds) if seconds else float("nan"),
            "mean_iou": statistics.fmean(o.metrics["iou"] for o in report.ok)
            if seconds else float("nan")}


def throughput(shapes: list[ShapeInput], out: Path, spec: JobSpec) -> dict:
    results = {}
    for workers in (1, 2):
        ray.init(num_cpus=workers, object_store_memory=200 * 2**20, **QUIET)
        try:
            results[workers] = _run(shapes, out / f"throughput_{workers}", spec, "ray")
        finally:
            ray.shutdown()
        print(f"  {workers} worker(s): {results[workers]}", file=sys.stderr)
    results["speedup"] = results[2]["shapes_per_min"] / results[1]["shapes_per_min"]
    return results


def overhead(shapes: list[ShapeInput], out: Path, spec: JobSpec) -> dict:
    inprocess = _run(shapes, out / "overhead_inprocess", spec, "inprocess")
    print(f"  in-process: {inprocess}", file=sys.stderr)
    ray.init(num_cpus=1, object_store_memory=200 * 2**20, **QUIET)
    try:
        through_ray = _run(shapes, out / "overhead_ray", spec, "ray")
    finally:
        ray.shutdown()
    print(f"  ray, 1 worker: {through_ray}", file=sys.stderr)
    return {"inprocess": inprocess, "ray": through_ray,
            "overhead": through_ray["wall_s"] / inprocess["wall_s"] - 1}


def cluster_node_loss(shapes: list[ShapeInput], out: Path, spec: JobSpec) -> dict:
    """A head and two worker nodes (1 CPU each); a worker node removed mid-run."""
    from ray.cluster_utils import Cluster

    from sweepedit.batch.summary import read_summary

    cluster = Cluster(initialize_head=True, head_node_args={
        "num_cpus": 1, "object_store_memory": 100 * 2**20, "include_dashboard": False})
    workers = [cluster.add_node(num_cpus=1, object_store_memory=100 * 2**20)
               for _ in range(2)]
    cluster.wait_for_nodes()
    ray.init(address=cluster.address, log_to_driver=False, logging_level="ERROR")
    box: dict = {}
    try:
        job = threading.Thread(target=lambda: box.setdefault("report", run_batch(
            shapes, BatchOptions(out / "cluster", spec, resume=False, progress=False,
                                 max_retries=3))))
        start = time.perf_counter()
        job.start()
        victim = workers[0]
        # Remove it mid-fit: once three shapes run, one runs there (1 CPU per node).
        while len(_running_tasks()) < 3 and job.is_alive():
            time.sleep(0.1)
        time.sleep(2.0)
        cluster.remove_node(victim)
        removed_at = time.perf_counter() - start
        job.join()
        report = box["report"]
        rows = read_summary(out / "cluster" / "summary.csv")
        nodes = {n: sum(r["node"] == n for r in rows) for n in sorted({r["node"] for r in rows})}
        return {"shapes": len(report.outcomes), "ok": len(report.ok),
                "failed": [(o.name, o.error) for o in report.failed],
                "removed_node": victim.node_id, "removed_at_s": removed_at,
                "wall_s": time.perf_counter() - start,
                "shapes_per_node": nodes}
    finally:
        ray.shutdown()
        cluster.shutdown()


def _running_tasks() -> list[int]:
    """PIDs of this session's Ray workers executing a shape now (Ray titles them
    ray::run_job; their parent is a raylet of this session)."""
    session = ray._private.worker._global_node.get_session_dir_path().encode()
    pids = []
    for entry in Path("/proc").iterdir():
        try:
            if not entry.name.isdigit() or not (entry / "cmdline").read_bytes().startswith(
                    b"ray::run_job"):
                continue
            parent = (entry / "stat").read_text().rsplit(")", 1)[1].split()[1]
            if session in Path(f"/proc/{parent}/cmdline").read_bytes():
                pids.append(int(entry.name))
        except OSError:
            continue
    return pids


def scale_on_paper(seconds_per_shape: float, price: float) -> str:
    lines = ["| shapes | workers (1 CPU each) | hours | cost at "
             f"${price:g}/vCPU-h |", "|---|---|---|---|"]
    for count in (10_000, 100_000):
        for workers in (2, 16, 64, 256):
            hours = count * seconds_per_shape / workers / 3600
            cost = count * seconds_per_shape / 3600 * price
            lines.append(f"| {count:,} | {workers} | {hours:.1f} | ${cost:,.0f} |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--shapes", type=Path, default=DEFAULT_SHAPES)
    parser.add_argument("--out", type=Path, default=Path("bench-out/batch"))
    parser.add_argument("--price", type=float, default=0.045,
                        help="dollars per vCPU-hour for the scale on paper (0.045)")
    parser.add_argument("--smoke", action="store_true", help="3 shapes, tiny fits")
    args = parser.parse_args(argv)

    shapes = expand_inputs([args.shapes])
    short = SHORT
    default = FitSettings()
    chosen = [s for s in shapes if s.name in OVERHEAD_SHAPES] or shapes[:4]
    if args.smoke:
        shapes = shapes[:3]
        short = replace(SHORT, primitives=2, refine_iterations=10, residual_rounds=0)
        default = short
        chosen = shapes[:2]
    results: dict = {"date": time.strftime("%Y-%m-%d"), "shapes": len(shapes),
                     "short_fit": vars(short) | {"weights": None}}
    print("throughput ...", file=sys.stderr)
    results["throughput"] = throughput(shapes, args.out, JobSpec(short, threads=1))
    print("overhead ...", file=sys.stderr)
    results["overhead"] = overhead(chosen, args.out, JobSpec(default, threads=1))
    print("cluster ...", file=sys.stderr)
    cluster_shapes = (shapes * 3)[:8] if not args.smoke else shapes[:3]
    # Unique names for repeated shapes: each is its own job.
    cluster_shapes = [ShapeInput(s.path, f"{s.name}_{i}") for i, s in enumerate(cluster_shapes)]
    results["cluster"] = cluster_node_loss(cluster_shapes, args.out, JobSpec(short, threads=1))

    t = results["throughput"]
    o = results["overhead"]
    c = results["cluster"]
    per_shape = o["ray"]["wall_s"] / max(o["ray"]["shapes"], 1)
    print(f"### Throughput ({len(shapes)} shapes, K = {short.primitives}, "
          f"{short.refine_steps} refinement steps, {short.residual_rounds} residual round)\n")
    print("| workers | wall s | shapes/min | median s per shape | mean IoU |")
    print("|---|---|---|---|---|")
    for w in (1, 2):
        r = t[w]
        print(f"| {w} | {r['wall_s']:.1f} | {r['shapes_per_min']:.2f} | "
              f"{r['median_shape_s']:.1f} | {r['mean_iou']:.3f} |")
    print(f"\n2 workers / 1 worker: **{t['speedup']:.2f}x** (target >= 1.8x)\n")
    print(f"### Overhead ({', '.join(s.name for s in chosen)}, default fit, 1 CPU)\n")
    print("| engine | wall s | median s per shape |\n|---|---|---|")
    print(f"| in-process | {o['inprocess']['wall_s']:.1f} | "
          f"{o['inprocess']['median_shape_s']:.1f} |")
    print(f"| Ray, 1 worker | {o['ray']['wall_s']:.1f} | {o['ray']['median_shape_s']:.1f} |")
    print(f"\nRay's overhead: **{100 * o['overhead']:+.1f} %** (target <= 5 %)\n")
    print(f"### Simulated cluster (head + 2 worker nodes, 1 CPU each; one removed at "
          f"{c['removed_at_s']:.0f} s)\n")
    print(f"{c['ok']} of {c['shapes']} shapes ok, failed: {c['failed'] or 'none'}; "
          "shapes finished per node: "
          + ", ".join(f"{n[:8]}{' (removed)' if n == c['removed_node'] else ''} {k}"
                      for n, k in c["shapes_per_node"].items())
          + f"; wall {c['wall_s']:.0f} s\n")
    print(f"### Scale on paper ({per_shape:.1f} s per shape at the default fit on one CPU, "
          f"measured above through Ray)\n")
    print(scale_on_paper(per_shape, args.price))
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "bench_batch.json").write_text(json.dumps(results, indent=1, default=str))
    return 0


if __name__ == "__main__":
    sys.exit(main())
