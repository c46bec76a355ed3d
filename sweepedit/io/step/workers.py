"""The primitives' solids of a STEP export built on two cores.

OpenCascade's calls keep Python's interpreter lock, so a second thread cannot build a
solid beside the first; a second process can. A folding primitive's solid takes 0.4-3 s
of mostly single-threaded work (slicing, lofting, checks), and a union of 8 with several
of them spent about half its time building them (BENCHMARKS.md, STEP export).

The helper is a fresh interpreter (`python -m sweepedit.io.step`), not a fork: a
fork made after OpenCascade's thread pool has run deadlocks in its first boolean check
(the pool's threads do not exist in a fork). A fresh one takes about 5 s to import
OpenCascade and load the compiled kernels, so it is started by the first export that can
use it and kept for the next ones (it leaves on its own after HELPER_IDLE_S idle, or
when this process ends). Until it says it is ready everything is built here; then it
takes the likely slow primitives from the front of the list while this process takes
the others from the back, so the two finish close together. Each solid comes back in
OpenCascade's binary format, which keeps every number as built. Where the helper dies
or stalls, what it had is built here: it can make an export faster, never fail it.
"""

from __future__ import annotations

import atexit
import io
import itertools
import os
import pickle
import queue
import subprocess
import sys
import threading
import time
from collections import deque
from collections.abc import Callable, Sequence
from typing import Any, BinaryIO

from sweepedit.errors import SweepeditError
from sweepedit.geometry.model import Normalization, SweepPrimitive

# With fewer likely slow primitives than this, this process alone is as quick.
MIN_SLOW_FOR_HELPER = 2
# An export with this many starts the helper itself, late as it is ready: they take
# longer to build than the helper takes to start. Below, only a helper already started
# (start_helper: the app, the benchmark) is used, so that a one-off export does not pay
# for starting one.
MIN_SLOW_TO_START = 6
POLL_S = 0.1  # how often a wait for the helper lets the caller check for a cancel
HELPER_PATIENCE_S = 60.0  # a solid the helper has not sent by then is built here
HELPER_IDLE_S = 300.0  # the helper leaves after this long without work

Built = tuple[Any, float, bool]  # (solid, seconds, built here)


def two_cores_available() -> bool:
    """Whether this process may use a second core (at least two are its to run on)."""
    try:
        return len(os.sched_getaffinity(0)) >= 2
    except AttributeError:  # no affinity on this platform
        return (os.cpu_count() or 1) >= 2


def start_helper() -> None:
    """Start the helper now, where there are two cores and none is running, for the
    exports to come (a process that makes several: the app, a benchmark)."""
    if two_cores_available():
        _Helper.running()


def build_all(chosen: Sequence[tuple[int, SweepPrimitive]],
              normalization: Normalization | None, build: Callable[[int], Any],
              slow: Sequence[bool], started: Callable[[int, int], None],
              waiting: Callable[[int], None]) -> list[Built]:
    """The first solid of each of `chosen` [(index, primitive)] -> [(solid, seconds,
    built here)], in order. build(k) builds the k-th here (export_step's
    primitive_solids); the helper builds it the same way (in the frame of
    `normalization`). slow (len(chosen),): which are likely slow (their sections cross);
    with at least MIN_SLOW_FOR_HELPER the helper shares the work where one is running
    (start_helper), or is started with MIN_SLOW_TO_START; it takes work from the moment
    it is ready. started(k, done) is called before this process builds the k-th with
    `done` finished so far, waiting(done) every POLL_S while it waits for the helper;
    either may raise to cancel (the helper is then stopped), as may build. An error
    building a solid is raised as it was, from either process."""
    count = len(chosen)
    if len(slow) != count:
        raise ValueError(f"{len(slow)} slowness flags for {count} solids")
    helper = None
    if sum(slow) >= MIN_SLOW_FOR_HELPER and two_cores_available():
        helper = _Helper.running() if sum(slow) >= MIN_SLOW_TO_START else _Helper.current()
    if helper is None:
        results = []
        for k in range(count):
            started(k, k)
            results.append(_built_here(build, k))
        return results
    return _Share(helper, chosen, normalization, build, slow).run(started, waiting)


def _built_here(build: Callable[[int], Any], k: int) -> Built:
    """build(k) in this process, timed."""
    begun = time.perf_counter()
    solid = build(k)
    return solid, time.perf_counter() - begun, True


class _Share:
    """One export's solids shared between this process and the helper: the helper is
    sent the next from the front of the list as soon as it sends one back (by a thread
    here), this process takes them from the back."""

    def __init__(self, helper: _Helper, chosen: Sequence[tuple[int, SweepPrimitive]],
                 normalization: Normalization | None, build: Callable[[int], Any],
                 slow: Sequence[bool]) -> None:
        self._helper, self._chosen, self._normalization = helper, chosen, normalization
        self._build = build
        self._todo = deque(sorted(range(len(chosen)), key=lambda k: not slow[k]))
        self._results: dict[int, Built] = {}
        self._failure: BaseException | None = None
        self._sent: int | None = None  # the one at the helper
        self._sent_at = 0.0
        self._lock = threading.Lock()
        self._over = threading.Event()  # run() has ended

    def run(self, started: Callable[[int, int], None],
            waiting: Callable[[int], None]) -> list[Built]:
        token = self._helper.claim()
        feeder = threading.Thread(target=self._feed, args=(token,), daemon=True)
        feeder.start()
        finished = False
        try:
            while True:
                with self._lock:
                    self._raise_failure()
                    if not self._todo:
                        break
                    k = self._todo.pop()
                started(k, len(self._results))
                built = _built_here(self._build, k)
                with self._lock:
                    self._results.setdefault(k, built)
            while True:
                with self._lock:
                    self._raise_failure()
                    if len(self._results) == len(self._chosen):
                        finished = True
                        return [self._results[k] for k in range(len(self._chosen))]
                    # Here, only the helper's solid is missing.
                    stalled = (not feeder.is_alive() or not self._helper.alive()
                               or time.perf_counter() - self._sent_at > HELPER_PATIENCE_S)
                    left = [k for k in range(len(self._chosen)) if k not in self._results]
                if stalled:  # what the helper had, built here
                    self._helper.stop()
                    for k in left:
                        started(k, len(self._results))
                        self._results[k] = _built_here(self._build, k)
                    continue
                waiting(len(self._results))
                feeder.join(POLL_S)
        finally:
            self._over.set()
            if not finished and self._sent is not None:
                self._helper.stop()  # its solid is no longer wanted
            self._helper.release(token)
            feeder.join()

    def _raise_failure(self) -> None:
        if self._failure is not None:
            raise self._failure

    def _send_next(self, token: int) -> None:
        """Under the lock: the front of the list to the helper, if any is left."""
        self._sent = self._todo.popleft() if self._todo else None
        if self._sent is not None:
            index, primitive = self._chosen[self._sent]
            self._sent_at = time.perf_counter()
            self._helper.send((token, self._sent, primitive, index, self._normalization))

    def _feed(self, token: int) -> None:
        """The thread here: each solid the helper sends back is kept and the next sent,
        until none is left at the helper; ends early where the helper stops. The first
        is sent once the helper is ready."""
        while not self._helper.ready.wait(POLL_S):
            if self._over.is_set() or not self._helper.alive():
                return
        with self._lock:
            self._send_next(token)
            if self._sent is None:
                return
        while True:
            reply = self._helper.receive(token)
            if reply is None:
                return  # stopped or released: run() decides
            k, data, seconds, error = reply
            with self._lock:
                if error is not None:
                    self._failure, self._sent = error, None  # the helper is idle again
                    return
                self._results.setdefault(k, (solid_from_bytes(data), seconds, False))
                self._send_next(token)
                if self._sent is None:
                    return


class _Helper:
    """The helper process and a thread here reading its replies; one per process,
    started by the first export that wants it (running())."""

    _current: _Helper | None = None
    _start_lock = threading.Lock()

    def __init__(self) -> None:
        replies_read, replies_write = os.pipe()
        # Its replies come on their own pipe: OpenCascade prints to stdout.
        self._process = subprocess.Popen(
            [sys.executable, "-m", "sweepedit.io.step", str(replies_write)],
            stdin=subprocess.PIPE, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
            pass_fds=(replies_write,), close_fds=True)
        os.close(replies_write)
        self._replies = os.fdopen(replies_read, "rb")
        self.ready = threading.Event()
        self._inbox: queue.Queue[Any] = queue.Queue()
        self._tokens = itertools.count(1)
        threading.Thread(target=self._read, daemon=True).start()
        atexit.register(self.stop)  # it holds nothing to keep

    @classmethod
    def current(cls) -> _Helper | None:
        """The helper if one is running (ready or not), else None."""
        with cls._start_lock:
            if cls._current is not None and cls._current.alive():
                return cls._current
            return None

    @classmethod
    def running(cls) -> _Helper | None:
        """The helper, started now if there is none (it is ready some seconds later);
        None where it cannot be started."""
        with cls._start_lock:
            if cls._current is None or not cls._current.alive():
                try:
                    cls._current = _Helper()
                except OSError:
                    cls._current = None
            return cls._current

    def alive(self) -> bool:
        return self._process.poll() is None

    def claim(self) -> int:
        """A token for one export's messages (replies to earlier ones are dropped)."""
        return next(self._tokens)

    def release(self, token: int) -> None:
        """The export with `token` is over: its feeder, if still waiting, returns."""
        self._inbox.put((token, "released"))

    def send(self, message: tuple[Any, ...]) -> None:
        try:
            pickle.dump(message, self._process.stdin)
            self._process.stdin.flush()
        except (OSError, ValueError):
            self.stop()

    def receive(self, token: int) -> tuple[Any, ...] | None:
        """The next reply for `token`: (k, data, seconds, error), or None once the
        helper is stopped or the token released."""
        while True:
            reply = self._inbox.get()
            if reply is None:
                self._inbox.put(None)  # stopped: for every later reader too
                return None
            if reply[0] == token:
                return None if reply[1] == "released" else reply[1:]

    def stop(self) -> None:
        """End the helper (the next export that wants one starts another)."""
        self._process.kill()
        self._process.wait()
        self._inbox.put(None)
        with _Helper._start_lock:
            if _Helper._current is self:
                _Helper._current = None

    def _read(self) -> None:
        try:
            while True:
                reply = pickle.load(self._replies)
                if reply == "ready":
                    self.ready.set()
                else:
                    self._inbox.put(reply)
        except (EOFError, OSError, pickle.UnpicklingError):
            self._inbox.put(None)  # the helper has ended


def _serve(replies: BinaryIO, requests: BinaryIO) -> None:
    """The helper's loop: each request (token, k, primitive, index, normalization) is
    answered with (token, k, binary solid or None, seconds, error or None)."""
    import numpy as np

    from sweepedit.geometry.inside import inside_union
    from sweepedit.io.step.occ import load_occ
    from sweepedit.io.step.solids import primitive_solids

    load_occ()
    # The compiled inside test loaded before the first solid is asked for.
    inside_union(np.zeros((1, 3)), [SweepPrimitive([[0, 0, 0], [0.1, 0, 0], [0.2, 0, 0]],
                                                   a=0.1, b=0.1, degree=2.0)])

    def reply(message: Any) -> None:
        pickle.dump(message, replies)
        replies.flush()

    last = [time.monotonic()]  # when it last finished a solid; 0 while building one

    def leave_when_idle() -> None:
        while True:
            time.sleep(5.0)
            if last[0] and time.monotonic() - last[0] > HELPER_IDLE_S:
                os._exit(0)

    threading.Thread(target=leave_when_idle, daemon=True).start()
    reply("ready")
    while True:
        try:
            token, k, primitive, index, normalization = pickle.load(requests)
        except EOFError:
            return
        last[0] = 0.0
        begun = time.perf_counter()
        try:
            solid = next(primitive_solids(primitive, index, normalization))
            reply((token, k, solid_bytes(solid), time.perf_counter() - begun, None))
        except Exception as error:  # sent back and raised there
            reply((token, k, None, 0.0, _picklable(error)))
        last[0] = time.monotonic()


def _picklable(error: Exception) -> Exception:
    """The error itself where it can be sent to the other process, else its message."""
    try:
        pickle.dumps(error)
    except Exception:  # not picklable
        return SweepeditError(f"{type(error).__name__}: {error}")
    return error


def solid_bytes(solid: Any) -> bytes:
    """An OpenCascade shape in its binary format (every number as it is)."""
    from OCP.BinTools import BinTools

    stream = io.BytesIO()
    BinTools.Write_s(solid, stream)
    return stream.getvalue()


def solid_from_bytes(data: bytes) -> Any:
    """The TopoDS_Solid that solid_bytes wrote."""
    from OCP.BinTools import BinTools
    from OCP.TopoDS import TopoDS, TopoDS_Shape

    shape = TopoDS_Shape()
    BinTools.Read_s(shape, io.BytesIO(data))
    return TopoDS.Solid(shape)


def serve_helper(replies_fd: int) -> None:
    """The helper process's whole life (`python -m sweepedit.io.step REPLIES_FD`): requests
    on stdin, replies on the inherited file descriptor."""
    with os.fdopen(replies_fd, "wb") as replies_out:
        _serve(replies_out, sys.stdin.buffer)
