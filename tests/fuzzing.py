"""Fuzzing sweepedit's readers (issue 18): seed files, mutations, and a worker process.

Shared by tests/test_fuzz.py (hypothesis, a bounded number of cases per format) and
benchmarks/bench_fuzz.py (a large random campaign).

- `write_seeds(folder)` writes one real file per format that sweepedit reads, made from
  the bundled cactus by the writers users have (trimesh's exporters, numpy, sweepedit's
  own parameter writers, the binvox run-length layout).
- `mutate(seed, fmt, chooser)` returns mutated bytes: truncations, flipped and
  overwritten bytes, deleted and repeated runs, huge counts in headers, and for JSON
  wrong types and missing keys anywhere in the document. A `Chooser` supplies every
  choice, so hypothesis (`HypothesisChooser`) can shrink a failure and a campaign
  (`RandomChooser`) can run without it.
- `Worker` runs the reader in a subprocess whose address space is limited to what it
  held after its imports plus MEMORY_LIMIT, one case at a time; every case is classified
  (`Outcome`): loaded, a SweepeditError naming the file, or a failure -- another
  exception, over TIME_LIMIT_S, out of memory, a crash or a hang.

Run as a script (`python tests/fuzzing.py --worker`) it is the worker.
"""

from __future__ import annotations

import json
import os
import random
import re
import select
import struct
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
CACTUS = ROOT / "resources" / "examples" / "cactus.off"
OFFICIAL_TXT = ROOT.parent / "shared" / "sweepnet_params" / "ant.txt"

# format name -> file name of its seed (the extension picks the reader)
FORMATS = {
    "obj": "seed.obj", "ply_ascii": "seed_ascii.ply", "ply_binary": "seed_binary.ply",
    "stl_ascii": "seed_ascii.stl", "stl_binary": "seed_binary.stl", "off": "seed.off",
    "glb": "seed.glb", "binvox": "seed.binvox", "npy": "seed.npy", "npz": "seed.npz",
    "xyz": "seed.xyz", "json": "seed.json", "txt": "seed.txt",
}
PARAMETER_FORMATS = ("json", "txt")
TIME_LIMIT_S = 5.0
MEMORY_LIMIT = 2 << 30  # bytes above what the worker holds after its imports
# The suite loads shapes on a coarse grid (the readers and checks are what is fuzzed, and
# it must stay fast); the campaign uses the default grid, as users do.
FUZZ_RESOLUTION = 16
FUZZ_SAMPLES = 256
# A case the worker does not answer within this is a hang (the worker is killed).
HANG_S = 60.0
HUGE_COUNTS = (2**31 - 1, 2**31, 2**32 - 1, 2**32, 10**9, 10**12, 2**63 - 1, 10**30, -1, 0)


# --------------------------------------------------------------------------- seeds


def write_seeds(folder: Path) -> dict[str, Path]:
    """One seed file per format in `folder`; returns format -> path."""
    import trimesh

    from sweepedit.io.params import read_official_txt, write_abstraction, write_official_txt

    folder.mkdir(parents=True, exist_ok=True)
    paths = {fmt: folder / name for fmt, name in FORMATS.items()}
    mesh = trimesh.load(CACTUS, process=False)
    mesh.export(paths["obj"])
    mesh.export(paths["ply_ascii"], encoding="ascii")
    mesh.export(paths["ply_binary"], encoding="binary")
    mesh.export(paths["stl_ascii"], file_type="stl_ascii")
    mesh.export(paths["stl_binary"], file_type="stl")
    paths["off"].write_bytes(CACTUS.read_bytes())
    mesh.export(paths["glb"])
    grid = _occupancy(mesh, 24)
    paths["binvox"].write_bytes(binvox_bytes(grid))
    np.save(paths["npy"], grid)
    np.savez_compressed(paths["npz"], occupancy=grid)
    # The cactus's arms are too thin for the point-cloud inside test on a coarse grid.
    points, _ = trimesh.sample.sample_surface(trimesh.creation.capsule(1.0, 0.5), 2000, seed=0)
    np.savetxt(paths["xyz"], points, fmt="%.6f")
    if OFFICIAL_TXT.is_file():
        paths["txt"].write_bytes(OFFICIAL_TXT.read_bytes())
    else:  # without the shared folder: the same layout from sweepedit's own writer
        write_official_txt(_random_abstraction(), paths["txt"])
    abstraction = read_official_txt(paths["txt"])
    abstraction.fit = {"primitives": len(abstraction.primitives), "seconds": 1.5}
    write_abstraction(abstraction, paths["json"])
    return paths


def _occupancy(mesh: Any, resolution: int) -> np.ndarray:
    lo, hi = mesh.bounds
    centres = (np.indices((resolution,) * 3).reshape(3, -1).T + 0.5) / resolution
    points = lo + centres * (hi - lo).max()
    from sweepedit.io.occupancy import mesh_inside

    return mesh_inside(mesh, points).reshape((resolution,) * 3)


def _random_abstraction() -> Any:
    from sweepedit.geometry.model import Abstraction, SweepPrimitive

    rng = np.random.default_rng(0)
    prims = [SweepPrimitive(rng.uniform(-0.4, 0.4, (3, 3)), a=0.1, b=0.08, degree=2.0,
                            scaling=(0.1, -0.2)) for _ in range(6)]
    return Abstraction(prims)


def binvox_bytes(grid: np.ndarray) -> bytes:
    """A binvox file of an (X, Y, Z) bool grid: run-length (value, count) pairs of the
    cells in [x, z, y] order (y fastest), as binvox stores them."""
    flat = np.ascontiguousarray(grid.transpose(0, 2, 1)).ravel().astype(np.uint8)
    out = bytearray(f"#binvox 1\ndim {grid.shape[0]} {grid.shape[2]} {grid.shape[1]}\n"
                    "translate 0 0 0\nscale 1\ndata\n".encode())
    start = 0
    while start < flat.size:
        end = start
        while end < flat.size and flat[end] == flat[start] and end - start < 255:
            end += 1
        out += bytes((int(flat[start]), end - start))
        start = end
    return bytes(out)


# --------------------------------------------------------------------------- mutations


class Chooser(Protocol):
    """Where every random choice of a mutation comes from."""

    def integer(self, low: int, high: int) -> int: ...  # low..high inclusive

    def raw(self, size: int) -> bytes: ...

    def json_value(self) -> Any: ...


class RandomChooser:
    """Choices from a seeded random.Random (the benchmark's campaign)."""

    def __init__(self, seed: int) -> None:
        self.rng = random.Random(seed)

    def integer(self, low: int, high: int) -> int:
        return self.rng.randint(low, high)

    def raw(self, size: int) -> bytes:
        return self.rng.randbytes(size)

    def json_value(self, depth: int = 0) -> Any:
        kind = self.rng.randrange(9 if depth < 2 else 7)
        scalars = [None, True, self.rng.randint(-2**70, 2**70),
                   self.rng.choice([0.0, -1.0, 1e308, 1e-320, float("nan"), float("inf")]),
                   self.rng.choice(["", "x", "#zzzzzz", "primitive", "\u00e9\u4e2d"]),
                   [], {}]
        if kind < 7:
            return scalars[kind]
        if kind == 7:
            return [self.json_value(depth + 1) for _ in range(self.rng.randrange(4))]
        return {self.rng.choice(["a", "scale", "format", "x"]): self.json_value(depth + 1)
                for _ in range(self.rng.randrange(3))}


class HypothesisChooser:
    """Choices drawn from hypothesis's `st.data()`, so failures shrink."""

    def __init__(self, data: Any) -> None:
        from hypothesis import strategies as st

        self.data = data
        self.st = st

    def integer(self, low: int, high: int) -> int:
        return self.data.draw(self.st.integers(low, high))

    def raw(self, size: int) -> bytes:
        return self.data.draw(self.st.binary(min_size=size, max_size=size))

    def json_value(self) -> Any:
        st = self.st
        leaves = (st.none() | st.booleans() | st.integers() | st.floats()
                  | st.text(max_size=8))
        return self.data.draw(st.recursive(
            leaves, lambda inner: st.lists(inner, max_size=3)
            | st.dictionaries(st.text(max_size=6), inner, max_size=3), max_leaves=6))


def _position(data: bytes, choose: Chooser) -> int:
    """A byte position, in the first 512 bytes (headers) half the time."""
    if not data:
        return 0
    head = min(len(data), 512)
    return choose.integer(0, head - 1) if choose.integer(0, 1) else choose.integer(
        0, len(data) - 1)


def _truncate(data: bytes, choose: Chooser) -> bytes:
    return data[: _position(data, choose)]


def _flip(data: bytes, choose: Chooser) -> bytes:
    out = bytearray(data)
    for _ in range(choose.integer(1, 8)):
        if out:
            out[_position(data, choose)] ^= 1 << choose.integer(0, 7)
    return bytes(out)


def _overwrite(data: bytes, choose: Chooser) -> bytes:
    at = _position(data, choose)
    chunk = choose.raw(choose.integer(1, 16))
    return data[:at] + chunk + data[at + len(chunk):]


def _delete(data: bytes, choose: Chooser) -> bytes:
    at = _position(data, choose)
    return data[:at] + data[at + choose.integer(1, 64):]


def _repeat(data: bytes, choose: Chooser) -> bytes:
    at = _position(data, choose)
    chunk = data[at: at + choose.integer(1, 64)]
    return data[:at] + chunk * choose.integer(2, 50) + data[at:]


_NUMBER = re.compile(rb"-?\d+")


def _huge_count(data: bytes, choose: Chooser) -> bytes:
    """Replace a number of the header (text headers, or the JSON chunk of a GLB) by a huge
    or negative count, or the 4-byte count of a binary STL."""
    value = HUGE_COUNTS[choose.integer(0, len(HUGE_COUNTS) - 1)]
    head = data[:2048]
    numbers = list(_NUMBER.finditer(head))
    if data[:5] != b"solid" and len(data) >= 84 and (not numbers or choose.integer(0, 3) == 0):
        return data[:80] + struct.pack("<I", value % 2**32) + data[84:]
    if not numbers:
        return data
    match = numbers[choose.integer(0, len(numbers) - 1)]
    return data[: match.start()] + str(value).encode() + data[match.end():]


def _json_nodes(node: Any, out: list[tuple[Any, Any]]) -> list[tuple[Any, Any]]:
    """(container, key) of every value in a parsed JSON document, depth first."""
    items = node.items() if isinstance(node, dict) else enumerate(node) \
        if isinstance(node, list) else ()
    for key, value in items:
        out.append((node, key))
        _json_nodes(value, out)
    return out


def _json_retype(data: bytes, choose: Chooser) -> bytes:
    """Replace or delete one value anywhere in a JSON document (wrong types, missing
    keys); bytes that do not parse are flipped instead."""
    try:
        doc = json.loads(data)
    except ValueError:
        return _flip(data, choose)
    nodes = _json_nodes(doc, [])
    if not nodes:
        return json.dumps(choose.json_value()).encode()
    container, key = nodes[choose.integer(0, len(nodes) - 1)]
    if isinstance(container, dict) and choose.integer(0, 3) == 0:
        del container[key]
    else:
        container[key] = choose.json_value()
    return json.dumps(doc).encode()


BYTE_MUTATIONS = (_truncate, _flip, _overwrite, _delete, _repeat, _huge_count)


def mutate(seed: bytes, fmt: str, choose: Chooser) -> tuple[bytes, list[str]]:
    """1 to 3 mutations of the seed's bytes; returns the bytes and the mutations' names."""
    mutations = BYTE_MUTATIONS + ((_json_retype,) * 4 if fmt == "json" else ())
    data, names = seed, []
    for _ in range(choose.integer(1, 3)):
        mutation = mutations[choose.integer(0, len(mutations) - 1)]
        data = mutation(data, choose)
        names.append(mutation.__name__.lstrip("_"))
    return data, names


# --------------------------------------------------------------------------- outcomes


@dataclass
class Outcome:
    """What one case gave. result: "loaded", "error" (a SweepeditError naming the file)
    or a failure: "other exception", "unnamed error" (a SweepeditError without the file),
    "slow", "memory", "crash", "hang"."""

    result: str
    seconds: float = 0.0
    error: str = ""
    message: str = ""
    peak_rss_mib: float = 0.0

    @property
    def ok(self) -> bool:
        return self.result in ("loaded", "error")


def _peak_rss_kib() -> int:
    """This process's peak resident memory (KiB): VmHWM, which starts afresh at exec.
    (ru_maxrss keeps the parent's across fork and exec, so a worker started from the
    whole suite's big process would report that.)"""
    with open("/proc/self/status") as status:
        return next(int(line.split()[1]) for line in status if line.startswith("VmHWM"))


def _worker_main() -> None:
    """Read one JSON request per line ({"path", "kind", "resolution"}), answer one JSON
    outcome per line on the original stdout (what the readers print goes to stderr)."""
    import resource
    import traceback

    protocol = os.fdopen(os.dup(1), "w")
    os.dup2(2, 1)
    from sweepedit.errors import SweepeditError
    from sweepedit.io.params import read_abstraction
    from sweepedit.io.shapes import load_shape

    with open("/proc/self/status") as status:
        held = next(int(line.split()[1]) * 1024 for line in status if line.startswith("VmSize"))
    resource.setrlimit(resource.RLIMIT_AS, (held + MEMORY_LIMIT, resource.RLIM_INFINITY))
    baseline = _peak_rss_kib()
    for line in sys.stdin:
        request = json.loads(line)
        path = request["path"]
        start = time.perf_counter()
        outcome = Outcome("loaded")
        try:
            if request["kind"] == "params":
                read_abstraction(path)
            else:
                load_shape(path, resolution=request["resolution"], n_samples=FUZZ_SAMPLES)
        except SweepeditError as exc:
            message = str(exc)
            named = path in message
            memory = "not enough memory" in message
            outcome = Outcome("memory" if memory else "error" if named else "unnamed error",
                              error=type(exc).__name__, message=message[:300])
        except MemoryError as exc:
            outcome = Outcome("memory", error=type(exc).__name__, message=str(exc)[:300])
        except Exception as exc:  # what the fuzzing looks for
            outcome = Outcome("other exception", error=type(exc).__name__,
                              message=(str(exc)[:200] + " | "
                                       + traceback.format_exc(limit=-3)[-600:]))
        outcome.seconds = time.perf_counter() - start
        if outcome.ok and outcome.seconds > TIME_LIMIT_S:
            outcome.result = "slow"
        peak = _peak_rss_kib()
        outcome.peak_rss_mib = peak / 1024
        if outcome.ok and (peak - baseline) * 1024 > MEMORY_LIMIT:
            outcome.result = "memory"
        protocol.write(json.dumps(outcome.__dict__) + "\n")
        protocol.flush()


class Worker:
    """The reader in a subprocess, restarted after a crash or a hang."""

    def __init__(self) -> None:
        self.process: subprocess.Popen[str] | None = None

    def _start(self) -> subprocess.Popen[str]:
        env = {**os.environ, "OMP_NUM_THREADS": "1", "PYTHONWARNINGS": "ignore"}
        return subprocess.Popen([sys.executable, str(Path(__file__).resolve()), "--worker"],
                                stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                stderr=subprocess.DEVNULL, text=True, env=env, cwd=ROOT)

    def run(self, path: Path, kind: str, resolution: int = FUZZ_RESOLUTION) -> Outcome:
        """Read `path` ("shape" or "params"; shapes on a resolution^3 grid) in the worker
        and classify what happened."""
        if self.process is None or self.process.poll() is not None:
            self.process = self._start()
        process = self.process
        assert process.stdin is not None and process.stdout is not None
        start = time.perf_counter()
        try:
            process.stdin.write(json.dumps({"path": str(path), "kind": kind,
                                            "resolution": resolution}) + "\n")
            process.stdin.flush()
        except BrokenPipeError:
            return self._lost(start)
        ready, _, _ = select.select([process.stdout], [], [], HANG_S)
        if not ready:
            self.close()
            return Outcome("hang", seconds=time.perf_counter() - start)
        line = process.stdout.readline()
        if not line:
            return self._lost(start)
        return Outcome(**json.loads(line))

    def _lost(self, start: float) -> Outcome:
        code = self.process.wait() if self.process else None
        self.process = None
        return Outcome("crash", seconds=time.perf_counter() - start,
                       message=f"the worker died (exit status {code})")

    def close(self) -> None:
        if self.process is not None:
            self.process.kill()
            self.process.wait()
            self.process = None


def kind_of(fmt: str) -> str:
    return "params" if fmt in PARAMETER_FORMATS else "shape"


def describe(outcome: Outcome, fmt: str, mutations: list[str]) -> str:
    """One line for a failure report."""
    return (f"{fmt} ({', '.join(mutations)}): {outcome.result} after {outcome.seconds:.2f} s"
            f" {outcome.error}: {outcome.message}")


if __name__ == "__main__" and sys.argv[1:] == ["--worker"]:
    _worker_main()
