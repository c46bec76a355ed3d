"""`run_batch`: every shape through an engine, outputs written as they come, resumable.

The driver keeps at most `engine.slots()` shapes in flight (so a killed driver loses only
those, and a job of 100,000 shapes is never 100,000 tasks at once), writes each finished
shape's mesh and then its parameter file atomically, rewrites summary.csv every few
seconds and at the end, and kills a task that runs far past the time limit. Ctrl-C
cancels the shapes in flight and keeps everything finished: the same command resumes.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from sweepedit.batch.engine import RAY_MISSING, InProcessEngine, RayEngine, ray_available
from sweepedit.batch.inputs import ShapeInput
from sweepedit.batch.jobs import JobOutcome, JobSpec
from sweepedit.batch.summary import completed, mesh_path, params_path, write_summary
from sweepedit.errors import SweepeditError
from sweepedit.io.params import atomic_write_bytes, atomic_write_text

ENGINES = ("auto", "ray", "inprocess")
# summary.csv is rewritten at most this often while shapes finish (and always at the end),
# and less often for long jobs (a rewrite of 100,000 rows costs the driver ~0.3 s).
_SUMMARY_EVERY_S = 2.0
_SUMMARY_S_PER_ROW = 2e-4
# How long one wait for finished shapes blocks (the bar and the kill check run between).
_POLL_S = 0.5
# Without --kill-after, a task is killed this long past twice the time limit.
_KILL_MARGIN_S = 60.0


@dataclass
class BatchOptions:
    """How to run a batch; `spec` is what each shape gets (fit settings, mesh, metrics,
    threads = CPUs per task, GPUs per task)."""

    outdir: Path
    spec: JobSpec
    engine: str = "auto"
    workers: int | None = None
    address: str | None = None
    max_retries: int = 2
    # Seconds after which a task is killed (None: twice the time limit plus a minute;
    # no kill without a time limit).
    kill_after: float | None = None
    resume: bool = True
    progress: bool = True

    def kill_seconds(self) -> float | None:
        if self.kill_after is not None:
            return self.kill_after
        limit = self.spec.settings.time_limit
        return None if limit is None else 2 * limit + _KILL_MARGIN_S


@dataclass
class BatchReport:
    """All shapes' outcomes in input order; `skipped`: done before and not refitted."""

    outcomes: list[JobOutcome]
    skipped: int
    seconds: float
    engine: str
    fitted: int = 0

    @property
    def failed(self) -> list[JobOutcome]:
        return [o for o in self.outcomes if o.status != "ok"]

    @property
    def ok(self) -> list[JobOutcome]:
        return [o for o in self.outcomes if o.status == "ok"]


def make_engine(options: BatchOptions) -> RayEngine | InProcessEngine:
    """The engine the options ask for. auto: Ray if installed, else this process (with a
    one-line note on stderr); ray without Ray installed is an error."""
    if options.engine not in ENGINES:
        raise SweepeditError(f"engine must be one of {', '.join(ENGINES)}")
    if options.engine == "inprocess":
        if options.address or (options.workers or 1) > 1:
            raise SweepeditError("--engine inprocess runs one shape at a time here: "
                                 "no --address, no --workers above 1")
        return InProcessEngine()
    if options.engine == "auto" and not ray_available():
        if options.address:
            raise SweepeditError(RAY_MISSING)
        print(f"sweepedit: {RAY_MISSING}; running one shape at a time in this process",
              file=sys.stderr)
        return InProcessEngine()
    return RayEngine(workers=options.workers, cpus_per_task=options.spec.threads,
                     gpus_per_task=options.spec.gpus, address=options.address,
                     max_retries=options.max_retries)


def run_batch(shapes: Sequence[ShapeInput], options: BatchOptions) -> BatchReport:
    """Fit every shape not already done in options.outdir; see the module docstring."""
    started = time.perf_counter()
    outdir = Path(options.outdir)
    if outdir.exists() and not outdir.is_dir():
        raise SweepeditError(f"{outdir}: the output folder is a file")
    options.spec.validate()  # one error line before anything starts
    outdir.mkdir(parents=True, exist_ok=True)
    results: dict[str, JobOutcome] = {}
    if options.resume:
        for shape in shapes:
            done = completed(outdir, shape, options.spec)
            if done is not None:
                results[shape.name] = done
    skipped = len(results)
    todo = [s for s in shapes if s.name not in results]
    report = BatchReport([], skipped, 0.0, "none")
    if todo:
        engine = make_engine(options)
        report.engine = engine.name
        try:
            _Driver(engine, options, shapes, results).run(todo)
        finally:
            engine.shutdown()
    report.outcomes = [results[s.name] for s in shapes if s.name in results]
    report.fitted = len(report.outcomes) - skipped
    report.seconds = time.perf_counter() - started
    write_summary(outdir, report.outcomes)
    return report


class _Driver:
    """The loop of one run: fill the slots, collect, write, kill the overdue, show."""

    def __init__(self, engine: Any, options: BatchOptions, shapes: Sequence[ShapeInput],
                 results: dict[str, JobOutcome]) -> None:
        self.engine = engine
        self.options = options
        self.outdir = Path(options.outdir)
        self.shapes = list(shapes)
        self.results = results
        self.inflight: dict[Any, tuple[ShapeInput, float]] = {}
        self.killed: set[Any] = set()
        self.summary_at = time.monotonic()
        self.summary_dirty = False
        self.finished_here = 0
        self.started = time.monotonic()

    def run(self, todo: list[ShapeInput]) -> None:
        from tqdm import tqdm

        queue = list(reversed(todo))
        self.bar = tqdm(total=len(self.shapes), initial=len(self.results), unit="shape",
                        desc=f"batch ({self.engine.name})", dynamic_ncols=True,
                        disable=not self.options.progress, file=sys.stderr,
                        bar_format="{desc}: {percentage:3.0f}%|{bar}| {n}/{total} "
                                   "[{elapsed}<{remaining}{postfix}]")
        try:
            while queue or self.inflight:
                while queue and len(self.inflight) < self.engine.slots():
                    shape = queue.pop()
                    handle = self.engine.submit(shape, self.options.spec)
                    self.inflight[handle] = (shape, time.monotonic())
                self._show()
                for handle, outcome in self.engine.wait(list(self.inflight), _POLL_S):
                    self._finish(handle, outcome)
                self._kill_overdue()
                every = max(_SUMMARY_EVERY_S, _SUMMARY_S_PER_ROW * len(self.results))
                if self.summary_dirty and time.monotonic() - self.summary_at > every:
                    self._write_summary()
            self._show()
        except BaseException:
            # Ctrl-C, a full disk, a lost cluster: stop the shapes in flight, keep the rest.
            in_flight = list(self.inflight)
            self.engine.cancel_all(in_flight)
            self._write_summary()
            self.bar.close()
            if in_flight:
                print(f"sweepedit: {len(in_flight)} shape(s) in flight cancelled; the same "
                      "command resumes the rest", file=sys.stderr)
            raise
        finally:
            self.bar.close()

    def _finish(self, handle: Any, outcome: JobOutcome | str) -> None:
        shape, _ = self.inflight.pop(handle)
        if isinstance(outcome, str):
            outcome = JobOutcome(shape.name, str(shape.path), "failed", error=outcome)
        if outcome.status == "ok":
            self._write_outputs(outcome)
        self.results[shape.name] = outcome
        self.finished_here += 1
        self.summary_dirty = True
        self.bar.update(1)

    def _write_outputs(self, outcome: JobOutcome) -> None:
        """The mesh, then the parameter file: a parameter file means a complete shape.
        The bytes are dropped once written (a long job keeps only the rows)."""
        assert outcome.params_text is not None and outcome.mesh_bytes is not None
        atomic_write_bytes(mesh_path(self.outdir, outcome.name, self.options.spec.mesh_format),
                           outcome.mesh_bytes)
        atomic_write_text(params_path(self.outdir, outcome.name), outcome.params_text)
        outcome.params_text, outcome.mesh_bytes = None, None

    def _kill_overdue(self) -> None:
        limit = self.options.kill_seconds()
        if limit is None:
            return
        time_limit = self.options.spec.settings.time_limit
        why = (f"far past the time limit of {time_limit:g} s (kill after {limit:g} s)"
               if self.options.kill_after is None and time_limit is not None
               else f"past --kill-after {limit:g} s")
        now = time.monotonic()
        for handle, (_shape, since) in list(self.inflight.items()):
            if handle not in self.killed and now - since > limit:
                self.killed.add(handle)
                self.engine.kill(handle, f"killed after {now - since:.0f} s: {why}")

    def _write_summary(self) -> None:
        write_summary(self.outdir, [self.results[s.name] for s in self.shapes
                                    if s.name in self.results])
        self.summary_at, self.summary_dirty = time.monotonic(), False

    def _show(self) -> None:
        failed = sum(o.status != "ok" for o in self.results.values())
        minutes = (time.monotonic() - self.started) / 60
        rate = self.finished_here / minutes if minutes > 0 else 0.0
        self.bar.set_postfix_str(f"ok {len(self.results) - failed}, failed {failed}, "
                                 f"running {len(self.inflight)}, {rate:.1f} shapes/min",
                                 refresh=True)

