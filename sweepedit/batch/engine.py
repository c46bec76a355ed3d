"""Where the shapes of a batch run: Ray (local or a cluster), or this process.

Both engines have one small interface for the runner (sweepedit.batch.runner):
`slots()` (how many shapes may be in flight), `submit(shape, spec)` -> a handle,
`wait(handles, timeout)` -> the finished (handle, JobOutcome) pairs, `kill(handle,
reason)` and `shutdown()`. Whatever goes wrong with a shape comes back as a failed
JobOutcome with its reason, never as an exception.

RayEngine: an embedded local Ray instance by default (`workers` tasks of
`cpus_per_task` CPUs each), or an existing cluster (`address` "auto" or
"ray://HOST:PORT"; an instance already started in this process, as tests and notebooks
do, is used as it is). Each task asks for its CPUs (and GPUs), and its worker runs with
OMP/MKL threads set to match before torch loads. A worker that dies (segfault, OOM
killer, a lost node) is retried by Ray up to `max_retries` times, then the shape fails
with that reason. `kill` force-cancels a task (its worker is killed), for a fit that runs
far past its time limit.

InProcessEngine: one shape after another in this process, no Ray: for machines without
it and to measure Ray's overhead. A crash here ends the run, and a time limit can only
stop the fit itself (FitSettings.time_limit), not kill it.
"""

from __future__ import annotations

import logging
import os
import socket
import time
from typing import Any

from sweepedit.batch.inputs import ShapeInput
from sweepedit.batch.jobs import JobOutcome, JobSpec, run_job
from sweepedit.errors import SweepeditError

RAY_MISSING = ("Ray is not installed: pip install 'sweepedit[batch]' to run shapes in "
               "parallel or on a cluster")
# Object store of an embedded instance: results are a parameter file and a mesh each.
_OBJECT_STORE_BYTES = 256 * 2**20
_THREAD_VARIABLES = ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS")
# How often a cluster's size is asked again (nodes join and leave).
_RESOURCE_REFRESH_S = 5.0


def ray_available() -> bool:
    try:
        import ray  # noqa: F401
    except ImportError:
        return False
    return True


def machine_cores() -> int:
    """The cores this process may use (a scheduler's CPU set, not the machine's count)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


def _check_reachable(address: str, timeout: float = 5.0) -> None:
    """A HOST:PORT (or ray://HOST:PORT) that takes no connection is an error now, not
    after Ray's own minutes of retrying; "auto" is left to Ray."""
    target = address.removeprefix("ray://")
    host, sep, port = target.rpartition(":")
    if address == "auto" or not sep or not port.isdigit():
        return
    try:
        socket.create_connection((host, int(port)), timeout=timeout).close()
    except OSError as exc:
        raise SweepeditError(f"--address {address}: nothing answers there "
                             f"({exc.strerror or exc})") from None


def _token_auth() -> None:
    """Joining a cluster by its address (HOST:PORT or ray://HOST:PORT), Ray sends this
    machine's auth token only when RAY_AUTH_MODE says "token"; unlike a local ray.init
    (and --address auto), it does not turn that on when a token is there (Ray 2.60: a
    `ray start --head` with its default token answered with 24 s of InvalidAuthToken,
    and Ray Client timed out). Left as the user set it, if they did."""
    if "RAY_AUTH_MODE" in os.environ:
        return
    try:
        from ray._private.authentication.authentication_token_setup import (
            maybe_enable_token_auth_if_token_available,
        )
    except ImportError:  # a Ray without token authentication
        return
    maybe_enable_token_auth_if_token_available(warn_if_disabled=False)


class InProcessEngine:
    """Runs each submitted shape in this process, one at a time, when waited for."""

    name = "in-process"

    def __init__(self) -> None:
        self._pending: dict[int, tuple[ShapeInput, JobSpec]] = {}
        self._next = 0

    def slots(self) -> int:
        return 1

    def submit(self, shape: ShapeInput, spec: JobSpec) -> int:
        self._next += 1
        self._pending[self._next] = (shape, spec)
        return self._next

    def wait(self, handles: list[int], timeout: float) -> list[tuple[int, JobOutcome | str]]:
        if not handles:
            return []
        handle = handles[0]
        shape, spec = self._pending.pop(handle)
        return [(handle, run_job(shape.path, shape.name, spec))]

    def kill(self, handle: int, reason: str) -> None:
        """Nothing to kill in this process: the fit's own time limit is what stops it."""

    def cancel_all(self, handles: list[int]) -> None:
        for handle in handles:
            self._pending.pop(handle, None)

    def shutdown(self) -> None:
        self._pending.clear()


class RayEngine:
    """Shapes as Ray tasks; see the module docstring."""

    name = "ray"

    def __init__(self, *, workers: int | None, cpus_per_task: int, gpus_per_task: float,
                 address: str | None, max_retries: int) -> None:
        try:
            import ray
        except ImportError:
            raise SweepeditError(RAY_MISSING) from None
        self._ray = ray
        self._cpus = cpus_per_task
        self._gpus = gpus_per_task
        self._workers = workers
        self._max_retries = max_retries
        self._owns = False
        if not ray.is_initialized():
            self._init(address, workers)
        try:
            self._check_resources()
        except SweepeditError:
            self.shutdown()
            raise
        env = {name: str(cpus_per_task) for name in _THREAD_VARIABLES}
        self._remote = ray.remote(run_job).options(
            num_cpus=cpus_per_task, num_gpus=gpus_per_task, max_retries=max_retries,
            retry_exceptions=False, runtime_env={"env_vars": env})
        self._reasons: dict[Any, str] = {}
        self._slots = 1
        self._slots_at = -_RESOURCE_REFRESH_S

    def _init(self, address: str | None, workers: int | None) -> None:
        quiet = {"logging_level": logging.ERROR, "log_to_driver": False,
                 "configure_logging": True}
        # Retries of a task that Ray's memory monitor killed have their own budget,
        # unbounded by default in recent Ray: bound it too (read by this process's core
        # worker, which owns the tasks).
        os.environ.setdefault("RAY_task_oom_retries", str(self._max_retries))
        try:
            if address:
                _check_reachable(address)
                _token_auth()
                self._ray.init(address=address, **quiet)
            else:
                # "local": a Ray instance of its own, as the README promises, even when a
                # `ray start` head runs here, a dead one left its session file, or
                # RAY_ADDRESS is set (--address auto joins those).
                count = workers or max(1, machine_cores() // self._cpus)
                self._ray.init(address="local", num_cpus=count * self._cpus,
                               include_dashboard=False,
                               object_store_memory=_OBJECT_STORE_BYTES, **quiet)
        except (ConnectionError, ValueError, RuntimeError) as exc:
            where = f"at {address}" if address else "on this machine"
            raise SweepeditError(f"cannot start or reach a Ray cluster {where}: "
                                 f"{str(exc).splitlines()[0] if str(exc) else exc}") from None
        self._owns = True

    def _check_resources(self) -> None:
        """Fail now, not hang: a task that no node can hold would wait forever."""
        nodes = [n for n in self._ray.nodes() if n.get("Alive")]
        cpus = max((n["Resources"].get("CPU", 0.0) for n in nodes), default=0.0)
        if cpus < self._cpus:
            raise SweepeditError(f"--cpus-per-task {self._cpus}: no Ray node has that many "
                                 f"CPUs (the largest has {cpus:g})")
        if self._gpus:
            gpus = max((n["Resources"].get("GPU", 0.0) for n in nodes), default=0.0)
            if gpus < self._gpus:
                raise SweepeditError(f"--gpus-per-task {self._gpus:g}: no Ray node has "
                                     f"that many GPUs (the largest has {gpus:g})")

    def slots(self) -> int:
        """Tasks to keep in flight: --workers, else as many as the cluster's CPUs (or GPUs)
        hold now -- asked again every few seconds, as nodes come and go."""
        if self._workers:
            return self._workers
        now = time.monotonic()
        if now - self._slots_at >= _RESOURCE_REFRESH_S:
            resources = self._ray.cluster_resources()
            count = int(resources.get("CPU", 0.0) // self._cpus)
            if self._gpus:
                count = min(count, int(resources.get("GPU", 0.0) // self._gpus))
            self._slots, self._slots_at = max(count, 1), now
        return self._slots

    def submit(self, shape: ShapeInput, spec: JobSpec) -> Any:
        # Absolute: a worker's current folder is not the driver's on every cluster.
        return self._remote.remote(str(shape.path.absolute()), shape.name, spec)

    def wait(self, handles: list[Any], timeout: float) -> list[tuple[Any, JobOutcome | str]]:
        """Finished tasks: each one's JobOutcome, or the reason it has none (a string)."""
        if not handles:
            return []
        ready, rest = self._ray.wait(handles, num_returns=1, timeout=timeout)
        if ready and rest:  # everything else that is done as well, without waiting
            more, _ = self._ray.wait(rest, num_returns=len(rest), timeout=0)
            ready += more
        return [(ref, self._outcome(ref)) for ref in ready]

    def _outcome(self, ref: Any) -> JobOutcome | str:
        """The task's JobOutcome, or the reason it has none (a string)."""
        exceptions = self._ray.exceptions
        try:
            return self._ray.get(ref)
        except exceptions.TaskCancelledError:
            return self._reasons.pop(ref, "cancelled")
        except exceptions.OutOfMemoryError:
            return "out of memory: Ray's memory monitor killed the worker"
        except exceptions.WorkerCrashedError:
            attempts = self._max_retries + 1
            tries = f"each of {attempts} attempts" if attempts > 1 else "its only attempt"
            return f"the worker process died (crash, out of memory or killed) on {tries}"
        except exceptions.RayError as exc:
            lines = [ln for ln in str(exc).splitlines() if ln.strip()]
            return f"Ray: {type(exc).__name__}: {lines[-1] if lines else ''}"[:500]

    def kill(self, handle: Any, reason: str) -> None:
        self._reasons[handle] = reason
        self._ray.cancel(handle, force=True)

    def cancel_all(self, handles: list[Any]) -> None:
        for ref in handles:
            self._ray.cancel(ref, force=True)

    def shutdown(self) -> None:
        if self._owns:
            self._ray.shutdown()
            self._owns = False
