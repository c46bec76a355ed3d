"""`sweepedit`: the one command-line entry point.

`sweepedit [FILE]` opens the app; subcommands do the rest (see `sweepedit --help`).
Every user-facing failure is a SweepeditError: it is printed as one line naming the
file and the problem, with exit status 2 and no traceback.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

from sweepedit.errors import SweepeditError
from sweepedit.io.benchmark_set import BENCHMARK_DIR

if TYPE_CHECKING:  # only for annotations: the command line imports these lazily

    from sweepedit.batch import BatchOptions, BatchReport
    from sweepedit.fitting.fit import FitProgress, FitSettings

EXIT_USER_ERROR = 2
EXIT_INTERRUPTED = 130
EXIT_BROKEN_PIPE = 141  # 128 + SIGPIPE, as Unix tools exit
# When the command started (main), for time limits that count the whole command.
_STARTED = time.perf_counter()
# Of a `fit --time-limit`, the seconds kept for writing the file and its metrics, which
# are then taken on fewer surface samples (the protocol's 100,000 take about a second).
_WRITE_RESERVE_S = 0.6
_QUICK_METRIC_SAMPLES = 20_000
# The benchmark set that ships inside the package (sweepedit/resources/benchmark).
DEFAULT_SHAPES = BENCHMARK_DIR


def _cmd_export(args: argparse.Namespace) -> int:
    from sweepedit.api import export, load, load_shape
    from sweepedit.io.mesh_export import MESH_FORMATS

    abstraction = load(args.params)
    options: dict[str, object] = {}
    if Path(args.output).suffix.lower() in MESH_FORMATS:
        options = {"stations": args.stations, "profile_points": args.profile_points}
    if args.target:
        if Path(args.output).suffix.lower() != ".blend":
            raise SweepeditError("--target is for .blend files (the shape beside the curves)")
        options["target_mesh"] = load_shape(args.target)
    written = export(abstraction, args.output, per_primitive=args.per_primitive,
                     original_frame=args.original_frame, union=args.union,
                     progress=not args.quiet, **options)
    for path in written:
        print(path)
    return 0


def _cmd_convert(args: argparse.Namespace) -> int:
    from sweepedit.api import load

    load(args.input).save(args.output)
    print(args.output)
    return 0


def _int_at_least(minimum: int, multiple_of: int = 1) -> Callable[[str], int]:
    """An argparse type: an int >= minimum (and a multiple of `multiple_of`); a bad value is
    argparse's one-line usage error, not a traceback from deep inside."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not a whole number") from None
        if value < minimum:
            raise argparse.ArgumentTypeError(f"{value} is less than {minimum}")
        if value % multiple_of:
            raise argparse.ArgumentTypeError(f"{value} is not a multiple of {multiple_of}")
        return value

    parse.__name__ = "int"
    return parse


def _primitive_count(text: str) -> int | str:
    """An argparse type for --primitives: a whole number >= 1, or "auto"."""
    if text.strip().lower() == "auto":
        return "auto"
    return _int_at_least(1)(text)


_primitive_count.__name__ = "count"


def _load_points(path: str) -> "np.ndarray":  # noqa: F821, UP037
    import numpy as np

    if not Path(path).is_file():
        raise SweepeditError(f"{path}: no such file")
    try:
        points = np.load(path, allow_pickle=False)
    except (OSError, ValueError):  # numpy's own words name pickles and magic strings
        raise SweepeditError(f"{path}: not a .npy array; save the points (N, 3) with "
                             "numpy.save") from None
    if not isinstance(points, np.ndarray):  # an .npz archive
        raise SweepeditError(f"{path}: expected a .npy array of points, not an archive")
    if points.dtype.kind not in "biuf":
        raise SweepeditError(f"{path}: expected numbers, got an array of {points.dtype}")
    if points.ndim != 2 or points.shape[1] != 3:
        raise SweepeditError(f"{path}: expected an (N, 3) array of points, got {points.shape}")
    if not np.all(np.isfinite(points)):
        raise SweepeditError(f"{path}: the points contain NaN or infinite values")
    return points.astype(np.float64)


def _cmd_inside(args: argparse.Namespace) -> int:
    import io

    import numpy as np

    from sweepedit.api import inside, load
    from sweepedit.io.params import atomic_write_bytes

    abstraction = load(args.params)
    points = _load_points(args.points)
    if args.sweeper == "exact":
        occupancy = inside(abstraction, points)
    else:
        from sweepedit.fitting.sweepers import soft_union_occupancy

        occupancy = soft_union_occupancy(abstraction.primitives, points, args.sweeper)
    buffer = io.BytesIO()
    np.save(buffer, occupancy)
    atomic_write_bytes(args.output, buffer.getvalue())
    inside = float(np.mean(occupancy > 0.5)) if len(occupancy) else 0.0
    print(f"{len(points)} points, {inside:.1%} inside ({args.sweeper}) -> {args.output}")
    return 0


def _cmd_eval(args: argparse.Namespace) -> int:
    from sweepedit.api import evaluate, load, load_shape

    abstraction = load(args.params)
    shape = load_shape(args.shape)
    metrics = evaluate(abstraction, shape, n_samples=args.samples, seed=args.seed).to_dict()
    print(f"shape      {args.shape}")
    print(f"params     {args.params}")
    print(f"primitives {metrics['n_primitives']}")
    print(f"IoU        {metrics['iou']:.4f}")
    print(f"CD-L1      {metrics['cd_l1']:.5f}")
    print(f"CD-L2      {metrics['cd_l2']:.6f}")
    print(f"F1@0.05    {metrics['f1_0.05']:.4f}")
    print(f"F1@0.01    {metrics['f1_0.01']:.4f}")
    if args.json:
        # Strict JSON: a distance that does not exist (no primitives) is null, not Infinity.
        print(json.dumps({k: None if isinstance(v, float) and not math.isfinite(v) else v
                          for k, v in metrics.items()}, allow_nan=False))
    return 0


def _cmd_inspect(args: argparse.Namespace) -> int:
    import numpy as np

    from sweepedit.analysis.skeleton import compute_skeleton
    from sweepedit.io.shapes import load_shape

    shape = load_shape(args.shape)
    skeleton = compute_skeleton(shape.occupancy)
    print(f"shape        {args.shape} ({shape.kind})")
    print(f"normalised   centre {np.round(shape.normalization.center, 6).tolist()}, "
          f"scale {shape.normalization.scale:.6g}")
    if shape.cloud is not None:
        print(f"points       {len(shape.cloud)} input points")
    if shape.mesh is not None:
        mesh = shape.mesh
        # For voxels and point clouds the surface is made from the grid (for display).
        label = "mesh        " if shape.kind == "mesh" else "grid surface"
        print(f"{label} {len(mesh.vertices)} vertices, {len(mesh.faces)} faces, "
              f"watertight {mesh.is_watertight}, components {shape.n_components}")
    occupancy = np.asarray(shape.occupancy)
    print(f"occupancy    {occupancy.shape[0]}^3, {occupancy.mean():.2%} inside")
    print(f"skeleton     {len(skeleton.branches)} branches, {len(skeleton.junctions)} junctions, "
          f"length {skeleton.total_length:.3f}")
    if args.screenshot:
        from sweepedit.analysis.render import render_shape

        render_shape(shape, skeleton, args.screenshot)
        print(f"screenshot   {args.screenshot}")
    return 0


def _fit_options(args: argparse.Namespace) -> dict[str, object]:
    """The fit settings the options name, as keywords of sweepedit.fit."""
    return {"max_primitives": args.max_primitives, "tolerance": args.tolerance,
            "method": args.method, "iterations": args.iterations,
            "time_limit": args.time_limit, "device": args.device, "sweeper": args.sweeper,
            "seed": args.seed, "restarts": args.restarts,
            "control_points": args.control_points, "scaling_degree": args.scaling_degree,
            "refine_iterations": args.refine_iterations,
            "residual_rounds": args.residual_rounds, "min_gain": args.min_gain,
            "surface_weight": args.surface_weight}


def _fit_settings(args: argparse.Namespace) -> FitSettings:
    from sweepedit.api import fit_settings

    return fit_settings(args.primitives, **_fit_options(args))


def count_explanation(settings: FitSettings, kept: int, record: dict) -> str:
    """One line on how many primitives a fit kept and why, where there is something to
    say: with `auto`, why it stopped adding (the fit record's stopped_because); else
    when it kept fewer than asked."""
    if settings.auto:
        because = record.get("stopped_because")
        return (f"auto: {kept} primitives (at most {settings.primitives}, tolerance "
                f"{settings.tolerance:g}){'; ' + because if because else ''}")
    if kept < settings.primitives:
        return (f"kept {kept} of the {settings.primitives} primitives asked for: the fit "
                "drops primitives that add nothing the others do not already cover")
    return ""


def _json_line(record: dict[str, object]) -> None:
    """One line of --progress-json: a JSON object, flushed at once (a reader follows it)."""
    print(json.dumps(record, allow_nan=False), flush=True)


def _progress_json(p: FitProgress) -> None:
    _json_line({"event": "progress", "fraction": round(p.iteration / max(p.total, 1), 4),
                "stage": p.stage, "stage_fraction": round(p.stage_fraction, 4),
                "seconds_left": None if p.seconds_left is None else round(p.seconds_left, 1),
                "primitives": len(p.abstraction.primitives)})


def _cmd_fit(args: argparse.Namespace) -> int:
    import threading

    from sweepedit.io.mesh_export import mesh_format
    from sweepedit.io.params import require_folder

    if Path(args.output).suffix.lower() not in (".json", ".txt"):
        raise SweepeditError(f"{args.output}: parameter files end in .json or .txt")
    # Every file the fit is for must be writable before it runs, not after, and before
    # torch is imported (2 s). The picture's folder is made (render_abstraction).
    require_folder(args.output)
    if args.mesh:
        mesh_format(require_folder(args.mesh))

    from sweepedit.api import evaluate, fit, load_shape

    settings = _fit_settings(args)  # checked before the shape loads and the bar is drawn
    shape = load_shape(args.shape)
    options = _fit_options(args)
    if settings.time_limit is not None:
        # The limit is the command's: loading (and importing torch) came out of it, and
        # writing the file and its metrics must fit in it too.
        spent = time.perf_counter() - _STARTED
        options["time_limit"] = max(settings.time_limit - spent - _WRITE_RESERVE_S, 0.05)
    progress = _progress_json if args.progress_json else not args.quiet
    abstraction = fit(shape, args.primitives, progress=progress, cancel=threading.Event(),
                      **options)
    record = abstraction.fit or {}
    abstraction.save(args.output)  # the result is safe before the metrics
    samples = _QUICK_METRIC_SAMPLES if args.time_limit else 100_000
    metrics = evaluate(abstraction, shape, seed=args.seed, n_samples=samples).to_dict()
    metrics["samples"] = samples
    metrics["seconds"] = record.get("seconds")
    abstraction.fit = {**record, "metrics": metrics}
    abstraction.save(args.output)
    state = ("cancelled, best so far" if record.get("cancelled")
             else "time limit reached, best so far" if record.get("timed_out") else "done")
    why = count_explanation(settings, len(abstraction.primitives), record)
    if args.progress_json:
        _json_line({"event": "done", "state": state, "output": str(args.output),
                    "primitives": len(abstraction.primitives), "explanation": why,
                    "metrics": {k: v if not isinstance(v, float) or math.isfinite(v) else None
                                for k, v in metrics.items()}})
    else:
        print(f"{state}: {len(abstraction.primitives)} primitives in "
              f"{record.get('seconds', 0.0):.1f} s; {_metrics_text(metrics)} -> {args.output}")
        if why:
            print(why)
    if args.mesh:
        abstraction.export(args.mesh)
        if not args.progress_json:
            print(f"mesh -> {args.mesh}")
    if args.screenshot:
        abstraction.plot(shape, screenshot=args.screenshot)
        if not args.progress_json:
            print(f"picture -> {args.screenshot}")
    return 0


def _metrics_text(metrics: dict[str, float]) -> str:
    return (f"IoU {metrics['iou']:.3f}, CD-L1 {metrics['cd_l1']:.4f}, "
            f"F1@0.05 {metrics['f1_0.05']:.3f}, F1@0.01 {metrics['f1_0.01']:.3f}")


def _batch_options(args: argparse.Namespace, outdir: Path, *, resume: bool,
                   cpus_per_task: int) -> BatchOptions:
    from sweepedit.batch import BatchOptions, JobSpec

    settings = _fit_settings(args)
    settings.validate()
    spec = JobSpec(settings, mesh_format=args.mesh_format, samples=args.samples,
                   threads=cpus_per_task, gpus=args.gpus_per_task)
    return BatchOptions(outdir, spec, engine=args.engine, workers=args.workers,
                        address=args.address, max_retries=args.max_retries,
                        kill_after=args.kill_after, resume=resume,
                        progress=not getattr(args, "quiet", False))


def _print_failed(report: BatchReport) -> None:
    for o in report.failed:
        print(f"failed: {o.name}: {o.error}", file=sys.stderr)


def _cmd_batch(args: argparse.Namespace) -> int:
    from sweepedit.batch import expand_inputs, run_batch
    from sweepedit.batch.report import SHEET_NAME, bench_rows, draw_sheet, write_table
    from sweepedit.fitting.bench import format_means

    outdir = Path(args.output)
    options = _batch_options(args, outdir, resume=not args.no_resume,
                             cpus_per_task=args.cpus_per_task)
    shapes = expand_inputs(args.inputs, exclude=outdir)
    report = run_batch(shapes, options)
    print(f"{len(report.outcomes)} shapes: {report.fitted} fitted ({report.engine}), "
          f"{report.skipped} already done, {len(report.failed)} failed, "
          f"{report.seconds:.1f} s")
    print(format_means(bench_rows(report.outcomes)), end="")
    print(f"summary -> {outdir / 'summary.csv'}, table -> "
          f"{write_table(outdir, report.outcomes, options.spec.settings)}")
    if not args.no_sheet:
        sheet = draw_sheet(outdir, report.outcomes, outdir / SHEET_NAME, args.sheet_max)
        if sheet:
            print(f"contact sheet ({sheet[1]} shapes) -> {sheet[0]}")
    _print_failed(report)
    return 1 if report.failed else 0


def _cmd_bench(args: argparse.Namespace) -> int:
    """`batch` over a benchmark folder, then the full table: one code path."""
    from sweepedit.batch import expand_inputs, run_batch
    from sweepedit.batch.report import bench_rows, draw_sheet
    from sweepedit.fitting.bench import format_table, write_bench_json
    from sweepedit.io.params import atomic_write_text

    out = Path(args.out)
    outdir = out.parent / "params"
    # With no engine option, one shape at a time on every core, as bench measured before
    # batch: its seconds stay a single fit's.
    alone = args.workers is None and args.address is None and args.cpus_per_task is None
    cpus = _cores() if alone else (args.cpus_per_task or 1)
    options = _batch_options(args, outdir, resume=args.resume, cpus_per_task=cpus)
    if alone:
        options.workers = 1
    report = run_batch(expand_inputs([args.shapes], exclude=outdir), options)
    rows = bench_rows(report.outcomes)
    settings = options.spec.settings
    table = format_table(rows, settings)
    atomic_write_text(out, table)
    write_bench_json(out.with_suffix(".json"), rows, settings)
    print(table)
    sheet = draw_sheet(outdir, report.outcomes, out.with_suffix(".png"), None)
    print(f"table -> {out}, parameters and meshes -> {outdir}/"
          + (f", contact sheet -> {sheet[0]}" if sheet else ""))
    _print_failed(report)
    return 1 if report.failed else 0


def _cores() -> int:
    from sweepedit.batch.engine import machine_cores

    return machine_cores()


def _cmd_train_sweeper(args: argparse.Namespace) -> int:
    from sweepedit.fitting.sweepers import NEURAL_WEIGHTS
    from sweepedit.training.train import train_sweeper

    args.output = args.output or str(NEURAL_WEIGHTS)
    train_sweeper(args.output, steps=args.steps, batch_size=args.batch_size, lr=args.lr,
                  seed=args.seed, resume=args.resume)
    print(f"weights -> {args.output}")
    return 0


def _cmd_gui(args: argparse.Namespace) -> int:
    from sweepedit.app.main import run_app, screenshot
    from sweepedit.io.params import is_parameter_file

    if args.select is not None and not args.screenshot:
        raise SweepeditError("--select goes with --screenshot")
    if args.select is not None and args.select < 1:
        raise SweepeditError(f"--select {args.select}: primitives are counted from 1, as the "
                             "app's list names them")
    if len(args.files) > 2:
        raise SweepeditError("gui takes at most two files: a shape and its parameters")
    # The shape first, so that the parameters open onto it (and get metrics).
    files = sorted(args.files, key=is_parameter_file)
    first, also = [*files, None, None][:2]
    if args.screenshot:
        if first is None:
            raise SweepeditError("--screenshot needs a file to show")
        return screenshot(first, args.screenshot,
                          select=None if args.select is None else args.select - 1, also=also,
                          heatmap=args.heatmap)
    return run_app(first, recover=args.recover, also=also, heatmap=args.heatmap)


def _add_fit_options(p: argparse.ArgumentParser, iterations: int) -> None:
    p.add_argument("--primitives", "-k", type=_primitive_count, default=8, metavar="K|auto",
                   help="primitives to fit, or auto: as many as the shape needs, added where "
                        "it is missed until the surfaces agree within --tolerance (8)")
    # The defaults are fitting.fit's (DEFAULT_TOLERANCE, AUTO_MAX_PRIMITIVES, AUTO_ROUNDS),
    # written out: importing it here would import torch for every command's --help.
    p.add_argument("--tolerance", type=float, default=0.008, metavar="DISTANCE",
                   help="with --primitives auto: stop adding primitives once 95%% of each "
                        "surface lies within this of the other, as a share of the shape's "
                        "longest side (0.008)")
    p.add_argument("--max-primitives", type=_int_at_least(1), default=32,
                   help="with --primitives auto: the most it may use (32)")
    p.add_argument("--method", choices=("direct", "network"), default="direct",
                   help="direct: warm start from the skeleton, then refinement (fast); "
                        "network: SweepNet's per-shape network stage first, as in the paper "
                        "(direct)")
    p.add_argument("--time-limit", type=float, default=None, metavar="SECONDS",
                   help="stop by then and keep the best abstraction found (no limit)")
    p.add_argument("--device", choices=("auto", "cpu", "cuda"), default="auto",
                   help="where the fit runs: auto is CUDA when present, else the CPU (auto)")
    p.add_argument("--iterations", "-n", type=int, default=iterations,
                   help=f"network-stage steps per restart, with --method network ({iterations})")
    p.add_argument("--sweeper", choices=("analytic", "neural"), default="analytic",
                   help="differentiable sweeper of the network stage (analytic)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--restarts", type=int, default=1,
                   help="fits from different seeds; the best by score is kept (1)")
    p.add_argument("--refine-iterations", type=int, default=None,
                   help="steps of direct refinement after the network stage; 0 skips it "
                        "(300 per 8 primitives, at least 300)")
    p.add_argument("--residual-rounds", type=int, default=None,
                   help="refinement rounds that add primitives where the shape is missed "
                        "(2; with --primitives auto 6)")
    p.add_argument("--min-gain", type=float, default=0.001,
                   help="score a primitive must add to be kept, up to 8 primitives (beyond, "
                        "it shrinks as 8/K); higher keeps fewer (0.001)")
    p.add_argument("--surface-weight", type=float, default=1.0,
                   help="weight of surface coverage against IoU when refining; higher "
                        "spends primitives on thin parts (1.0)")
    p.add_argument("--control-points", type=int, default=8,
                   help="the most per axis; each primitive keeps the fewest (down to 3) "
                        "that hold its surface within 0.002 (8)")
    p.add_argument("--scaling-degree", type=int, default=3,
                   help="the most terms of f(t); each primitive keeps the fewest (down to "
                        "2) that hold its surface (3)")


def _add_batch_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--mesh-format", choices=("glb", "obj", "ply", "stl"), default="glb",
                   help="format of each shape's union mesh (glb)")
    p.add_argument("--samples", type=_int_at_least(1), default=100_000,
                   help="surface samples per side for the metrics, as `eval` (100000)")
    p.add_argument("--engine", choices=("auto", "ray", "inprocess"), default="auto",
                   help="ray, or one shape at a time in this process (inprocess); auto is "
                        "ray when installed (auto)")
    p.add_argument("--workers", type=_int_at_least(1), default=None,
                   help="shapes fitted at once (this machine's cores / --cpus-per-task; on "
                        "a cluster, as many as its CPUs hold)")
    p.add_argument("--address", metavar="auto|HOST:PORT|ray://HOST:PORT", default=None,
                   help="run on an existing Ray cluster instead of a local instance: auto "
                        "(the one started on this machine), its head's HOST:PORT, or a Ray "
                        "Client address (needs ray[client])")
    p.add_argument("--gpus-per-task", type=float, default=0.0,
                   help="GPUs per shape, where the cluster has them (0)")
    p.add_argument("--max-retries", type=_int_at_least(0), default=2,
                   help="retries of a shape whose worker or node died (2)")
    p.add_argument("--kill-after", type=float, default=None, metavar="SECONDS",
                   help="kill a shape's task after this long (twice --time-limit plus 60 s; "
                        "none without a time limit)")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="sweepedit",
        description="Abstract 3D shapes into editable sweep-surface primitives (SweepNet). "
                    "Run `sweepedit [FILE]` to open the app.")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")

    p = sub.add_parser("export", help="sweep a parameter file into a mesh (OBJ, PLY, STL, "
                                      "GLB), CAD solids (STEP) or Blender curves (.blend)")
    p.add_argument("params", help="parameter file (.json or official .txt)")
    p.add_argument("-o", "--output", required=True,
                   help="file to write: a mesh, .step/.stp for one smooth solid per "
                        "visible primitive (needs the 'cad' extra), .blend for one Blender "
                        "curve object per primitive (needs Blender's bpy), or .json/.txt")
    p.add_argument("--per-primitive", action="store_true",
                   help="write one file per primitive (OUTPUT_NN.ext) instead of the union")
    p.add_argument("--union", action="store_true",
                   help="STEP: one fused solid instead of one solid per primitive")
    p.add_argument("--quiet", action="store_true", help="STEP: no progress bar")
    p.add_argument("--target", metavar="SHAPE",
                   help=".blend: the shape file, added beside the curves as a mesh object")
    p.add_argument("--original-frame", action="store_true",
                   help="map back through the normalisation to the shape's original frame")
    p.add_argument("--stations", type=_int_at_least(2), default=64,
                   help="rings along the axis, at least 2 (64)")
    p.add_argument("--profile-points", type=_int_at_least(4, multiple_of=4), default=48,
                   help="points around the profile, a multiple of 4 (48)")
    p.set_defaults(func=_cmd_export)

    p = sub.add_parser("convert", help="convert parameters between JSON and the official txt")
    p.add_argument("input", help=".json or .txt")
    p.add_argument("output", help=".json or .txt (format chosen by extension)")
    p.set_defaults(func=_cmd_convert)

    p = sub.add_parser("inside", help="occupancy of the union of primitives at points")
    p.add_argument("params", help="parameter file")
    p.add_argument("points", help=".npy array (N, 3) of points in the normalised frame")
    p.add_argument("-o", "--output", required=True, help=".npy to write: one value per point")
    p.add_argument("--sweeper", choices=("exact", "analytic", "neural"), default="exact",
                   help="exact: bool per point; analytic/neural: soft occupancy in [0, 1]")
    p.set_defaults(func=_cmd_inside)

    p = sub.add_parser("eval", help="IoU, CD-L1/L2 and F1 of an abstraction against a shape")
    p.add_argument("params", help="parameter file")
    p.add_argument("shape", help="shape file (mesh, voxels or point cloud)")
    p.add_argument("--json", action="store_true", help="also print one JSON object, last line")
    p.add_argument("--samples", type=_int_at_least(1), default=100_000,
                   help="surface samples per side")
    p.add_argument("--seed", type=int, default=0)
    p.set_defaults(func=_cmd_eval)

    p = sub.add_parser("inspect", help="what a shape file holds, its voxels and skeleton")
    p.add_argument("shape", help="shape file")
    p.add_argument("--screenshot", metavar="PNG", help="render the shape and its skeleton")
    p.set_defaults(func=_cmd_inspect)

    p = sub.add_parser("fit", help="abstract a shape into sweep primitives")
    p.add_argument("shape", help="shape file (mesh, voxels or point cloud)")
    p.add_argument("-o", "--output", required=True, help="parameter file to write (.json/.txt)")
    _add_fit_options(p, iterations=300)
    p.add_argument("--mesh", metavar="MESH", help="also export the union mesh")
    p.add_argument("--screenshot", metavar="PNG", help="also render the result over the shape")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument("--progress-json", action="store_true",
                   help="for programs that run sweepedit (the Blender add-on): instead of the "
                        "bar and the summary, one JSON object per line on stdout, "
                        '{"event": "progress", "fraction", "stage", "stage_fraction", '
                        '"seconds_left", "primitives"} as the fit goes and {"event": "done", '
                        '"output", "primitives", "metrics", ...} at the end')
    p.set_defaults(func=_cmd_fit)

    p = sub.add_parser("batch", help="fit many shapes (files, folders, globs, lists) on Ray, "
                                     "resumable; summary.csv, table and contact sheet")
    p.add_argument("inputs", nargs="+", metavar="INPUT",
                   help="shape files, folders (recursive), quoted globs, or a .txt/.csv list")
    p.add_argument("-o", "--output", required=True, metavar="OUTDIR",
                   help="folder for <name>.json, the meshes and summary.csv; a rerun with "
                        "the same folder fits only the shapes not done yet")
    _add_fit_options(p, iterations=300)
    _add_batch_options(p)
    p.add_argument("--cpus-per-task", type=_int_at_least(1), default=1,
                   help="CPUs (and torch threads) per shape (1)")
    p.add_argument("--no-resume", action="store_true",
                   help="refit every shape, also those already done in OUTDIR")
    p.add_argument("--no-sheet", action="store_true", help="no contact sheet at the end")
    p.add_argument("--sheet-max", type=_int_at_least(1), default=64,
                   help="shapes on the contact sheet at most, spread over the job (64)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=_cmd_batch)

    p = sub.add_parser("bench", help="fit every shape of a folder and tabulate the metrics "
                                     "(batch plus the full table)")
    p.add_argument("--shapes", default=str(DEFAULT_SHAPES),
                   help="folder of shapes (the 19 bundled with sweepedit; their licences in "
                        "its manifest.json)")
    p.add_argument("--out", default="bench-out/bench.md",
                   help="table to write (Markdown); .json and a contact sheet .png beside "
                        "it, parameters and meshes in its folder's params/")
    _add_fit_options(p, iterations=300)
    _add_batch_options(p)
    p.add_argument("--cpus-per-task", type=_int_at_least(1), default=None,
                   help="CPUs (and torch threads) per shape (all cores, one shape at a "
                        "time; 1 with --workers)")
    p.add_argument("--resume", action="store_true",
                   help="keep the shapes already done under the table's params/ folder")
    p.set_defaults(func=_cmd_bench)

    p = sub.add_parser("train-sweeper", help="train the neural sweeper on random sweeps")
    p.add_argument("-o", "--output", default=None,
                   help="weights file (default: the packaged sweepedit/resources/"
                        "sweeper_neural.pt, which the neural sweeper loads)")
    p.add_argument("--steps", type=int, default=20000)
    p.add_argument("--batch-size", type=int, default=32)
    p.add_argument("--lr", type=float, default=1e-3)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--resume", action="store_true", help="continue from OUTPUT's checkpoint")
    p.set_defaults(func=_cmd_train_sweeper)

    p = sub.add_parser("gui", help="open the app on a file; --screenshot renders and quits")
    p.add_argument("files", nargs="*", metavar="FILE",
                   help="a shape, a parameter file, or both (SHAPE PARAMS)")
    p.add_argument("--heatmap", action="store_true",
                   help="show the heat map of the error: the shape coloured by its distance "
                   "to the primitives (red missed, blue excess)")
    p.add_argument("--screenshot", metavar="PNG", help="write a screenshot and quit")
    p.add_argument("--select", type=int, metavar="N",
                   help="with --screenshot: show primitive N selected (counted from 1, as "
                   "the app's list names them), with its axis and handles")
    p.add_argument("--recover", choices=("ask", "yes", "no"), default="ask",
                   help="unsaved edits left by an editor that was killed or crashed: ask "
                   "(default), or recover (yes) or keep (no) them without asking")
    p.set_defaults(func=_cmd_gui)

    return parser


def main(argv: Sequence[str] | None = None) -> int:
    global _STARTED
    _STARTED = time.perf_counter()
    argv = list(sys.argv[1:] if argv is None else argv)
    parser = build_parser()
    commands = set(parser._subparsers._group_actions[0].choices)  # type: ignore[union-attr]
    try:
        if not argv or (argv[0] not in commands and not argv[0].startswith("-")):
            return _open_app(argv)
        args = parser.parse_args(argv)
        return int(args.func(args))
    except SweepeditError as exc:
        print(f"sweepedit: error: {exc}", file=sys.stderr)
        return EXIT_USER_ERROR
    except BrokenPipeError:
        # The reader went away (`sweepedit eval ... | head`): stop quietly, and point
        # stdout at /dev/null so the interpreter's final flush does not complain either.
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return EXIT_BROKEN_PIPE
    except OSError as exc:  # missing files, permissions, full disks: say which file
        where = f"{exc.filename}: " if exc.filename else ""
        print(f"sweepedit: error: {where}{exc.strerror or exc}", file=sys.stderr)
        return EXIT_USER_ERROR
    except KeyboardInterrupt:
        print("sweepedit: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED


def _open_app(argv: list[str]) -> int:
    if len(argv) > 1:
        raise SweepeditError(f"unknown command '{argv[0]}' (see `sweepedit --help`)")
    path = argv[0] if argv else None
    if path is not None and not Path(path).exists():
        raise SweepeditError(f"{path}: no such file (and not a command; see `sweepedit --help`)")
    from sweepedit.app.main import run_app

    return run_app(path)


if __name__ == "__main__":
    sys.exit(main())
