"""One shape of a batch: load, fit, measure, mesh -- run inside a worker.

`run_job` never writes into the output folder: it returns the parameter file's text and
the mesh's bytes, and the driver writes them (atomically, the mesh first and the
parameter file last, so a parameter file on disk means a complete shape). The output
folder therefore only has to exist on the driver's machine; the inputs have to be
readable where the workers run (on a multi-machine cluster, shared storage).

Errors with the shape (a bad file, an empty mesh, a fit that fails) come back as a failed
`JobOutcome` with the reason; they do not raise, so Ray does not retry them. What kills
the worker process (a segfault, the kernel's OOM killer) is the engine's to report.
"""

from __future__ import annotations

import hashlib
import json
import os
import socket
import time
import traceback
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

from sweepedit.errors import SweepeditError
from sweepedit.fitting.fit import FitSettings

MESH_FORMATS = ("glb", "obj", "ply", "stl")
# The parameter file's fit record keeps the batch's own facts under this key.
RECORD_KEY = "batch"


@dataclass(frozen=True)
class JobSpec:
    """What every shape of a job gets: the fit settings of `sweepedit fit`, the mesh
    format, the metric protocol of `sweepedit eval` (samples per side, seed = the fit's
    seed) and the worker's resources (torch threads = CPUs per task)."""

    settings: FitSettings
    mesh_format: str = "glb"
    samples: int = 100_000
    threads: int = 1
    gpus: float = 0.0

    def validate(self) -> None:
        """The fit settings' own checks and the job's; SweepeditError names the option."""
        self.settings.validate()
        if self.mesh_format not in MESH_FORMATS:
            raise SweepeditError(f"mesh format must be one of {', '.join(MESH_FORMATS)}")
        if self.samples < 1:
            raise SweepeditError("metric samples must be at least 1")
        if self.threads < 1:
            raise SweepeditError("CPUs per task must be at least 1")
        if not self.gpus >= 0:  # NaN too
            raise SweepeditError("GPUs per task must be 0 or more")

    def fingerprint(self) -> str:
        """A hash of everything that shapes a result: a rerun reuses a shape's outputs
        only when it is the same (different settings refit)."""
        settings = asdict(self.settings)
        data = {"settings": settings, "mesh_format": self.mesh_format, "samples": self.samples}
        text = json.dumps(data, sort_keys=True, default=str)
        return hashlib.sha256(text.encode()).hexdigest()[:16]


@dataclass
class JobOutcome:
    """A shape's result. status "ok": `params_text` and `mesh_bytes` are to be written;
    "failed": `error` says why. seconds: load and fit (not the metrics)."""

    name: str
    input: str
    status: str
    metrics: dict[str, float] = field(default_factory=dict)
    primitives: int = 0
    seconds: float = 0.0
    timed_out: bool = False
    stages: dict[str, float] = field(default_factory=dict)
    node: str = ""
    error: str = ""
    params_text: str | None = None
    mesh_bytes: bytes | None = None


def input_stamp(path: Path) -> dict[str, int]:
    """Size and modification time of an input: a rerun refits a shape whose file changed."""
    stat = path.stat()
    return {"size": stat.st_size, "mtime_ns": stat.st_mtime_ns}


def node_id() -> str:
    """The Ray node this runs on, or the host name outside Ray."""
    try:
        import ray

        if ray.is_initialized():
            return ray.get_runtime_context().get_node_id()
    except ImportError:
        pass
    return socket.gethostname()


def run_job(path: str | Path, name: str, spec: JobSpec) -> JobOutcome:
    """Fit one shape; a failed outcome (never an exception) for anything wrong with it."""
    path = Path(path)
    node = node_id()
    try:
        return _fit_one(path, name, spec, node)
    except SweepeditError as exc:
        return JobOutcome(name, str(path), "failed", node=node, error=str(exc))
    except MemoryError:
        return JobOutcome(name, str(path), "failed", node=node,
                          error="out of memory (MemoryError while fitting)")
    except Exception as exc:  # a bug, reported with where it happened
        where = traceback.extract_tb(exc.__traceback__)[-1]
        return JobOutcome(name, str(path), "failed", node=node,
                          error=f"unexpected {type(exc).__name__}: {exc} "
                                f"({Path(where.filename).name}:{where.lineno})")


def _fit_one(path: Path, name: str, spec: JobSpec, node: str) -> JobOutcome:
    import torch

    if spec.settings.method == "network":
        # The network stage's torch.optim imports torch._dynamo with its first optimizer
        # (1.5-4 s, once per process): a worker's warm-up, kept off the first shape's
        # seconds. The direct method's refinement has its own Adam and never needs it.
        import torch._dynamo

    from sweepedit.analysis.metrics import evaluate
    from sweepedit.fitting.fit import fit_abstraction
    from sweepedit.io.params import dumps_abstraction
    from sweepedit.io.shapes import load_shape

    # This task's CPUs and no more: two fits on one machine never share cores.
    torch.set_num_threads(spec.threads)
    settings = replace(spec.settings)
    if settings.device == "auto" and not spec.gpus:
        settings.device = "cpu"  # a task without a GPU leaves the node's GPUs alone
    stamp = input_stamp(path) if path.exists() else {}
    start = time.perf_counter()
    shape = load_shape(path)
    loaded = time.perf_counter()
    result = fit_abstraction(shape, settings)
    seconds = time.perf_counter() - start
    abstraction = result.abstraction
    metrics = evaluate(abstraction, shape, n_samples=spec.samples, seed=settings.seed)
    metrics["samples"] = spec.samples
    metrics["seconds"] = seconds
    stages = {"load": loaded - start, **result.stage_seconds}
    abstraction.fit = {**(abstraction.fit or {}), "metrics": metrics,
                       RECORD_KEY: {"input": str(path), **stamp, "job": spec.fingerprint(),
                                    "node": node, "pid": os.getpid(),
                                    "load_seconds": round(loaded - start, 3)}}
    abstraction.validate()  # as write_abstraction does: never a file that cannot be read
    mesh_bytes = _mesh_bytes(abstraction, spec.mesh_format)
    return JobOutcome(name, str(path), "ok", metrics=metrics,
                      primitives=len(abstraction.primitives), seconds=seconds,
                      timed_out=result.timed_out, stages=stages, node=node,
                      params_text=dumps_abstraction(abstraction), mesh_bytes=mesh_bytes)


def _mesh_bytes(abstraction: Any, fmt: str) -> bytes:
    """The union's solid mesh as the bytes of a `fmt` file (through the export code)."""
    import tempfile

    from sweepedit.io.mesh_export import export_abstraction

    with tempfile.TemporaryDirectory(prefix="sweepedit-batch-") as tmp:
        out = Path(tmp) / f"mesh.{fmt}"
        export_abstraction(abstraction, out)
        return out.read_bytes()
