"""Saves are atomic against SIGKILL (issue 18).

A child process writes a large parameter file (sweepedit.io.params.write_abstraction, the
most primitives a file may hold, of 6 control points, ~1 MB) and a large mesh
(sweepedit.io.mesh_export.write_mesh, 20k faces, binary PLY, ~1 MB) over and over,
alternating between two known contents; it is killed with SIGKILL many times: every other
time while a temporary file is being synced (the moment the test is about, made certain, not
left to timing), else at a random moment from the start of its writes or from the end of its
first complete write of both files (so that each file is seen in both versions, whatever the
machine's speed). After every kill each file must be exactly one of its two known contents
(the old complete file or the new one), and nothing but hidden temporary files of killed
writers may be left beside them; the next write removes those.
"""

from __future__ import annotations

import os
import random
import signal
import stat
import time
from pathlib import Path

import numpy as np
import pytest
import trimesh

from sweepedit.geometry.mesher import TriangleMesh
from sweepedit.geometry.model import Abstraction, SweepPrimitive
from sweepedit.io.mesh_export import write_mesh
from sweepedit.io.params import MAX_PRIMITIVES, read_abstraction, write_abstraction

KILLS = 30
PRIMITIVES = MAX_PRIMITIVES  # the most a file may hold

pytestmark = pytest.mark.skipif(not hasattr(os, "fork"), reason="needs os.fork and SIGKILL")


def _abstraction(seed: int) -> Abstraction:
    rng = np.random.default_rng(seed)
    return Abstraction([SweepPrimitive(rng.uniform(-0.4, 0.4, (6, 3)), a=0.1, b=0.05,
                                       degree=2.0, scaling=(0.1, -0.1), name=f"p{i}")
                        for i in range(PRIMITIVES)])


def _mesh(seed: int) -> TriangleMesh:
    sphere = trimesh.creation.icosphere(subdivisions=5)  # 20,480 faces
    vertices = sphere.vertices * (1.0 + 0.1 * seed)
    return TriangleMesh(vertices, np.asarray(sphere.faces), np.asarray(sphere.vertex_normals))


def _slow_disk(events: int | None = None) -> None:
    """From now on in this process, each fsync takes 40 ms more (a slow disk), so that a
    good share of the random kills land while a temporary file is open -- the moment the
    test is about -- and not only in the serialisation before it. With `events`, b"s" is
    written to that pipe as each regular file (a temporary file, before its rename) has
    been synced, and b"r" as each temporary file has been moved over its target."""
    fsync, replace = os.fsync, os.replace

    def slow_fsync(fd: int) -> None:
        fsync(fd)
        if events is not None and stat.S_ISREG(os.fstat(fd).st_mode):
            os.write(events, b"s")
        time.sleep(0.04)

    def told_replace(source, target) -> None:
        replace(source, target)
        if events is not None:
            os.write(events, b"r")

    os.fsync, os.replace = slow_fsync, told_replace


def _await(events: int, event: bytes, count: int = 1) -> None:
    """Read the child's events until `count` of `event` have come."""
    while count:
        got = os.read(events, 1)
        assert got, "the writing child died"
        count -= got == event


def _write_forever(params: Path, mesh: Path, contents: list[tuple[Abstraction, TriangleMesh]],
                   first: int, started: int) -> None:
    """The child: say so on the pipe `started`, then write version `first`, then the
    other, and so on until killed (it never returns); a byte on `started` too whenever a
    temporary file has been synced or renamed (see _slow_disk)."""
    _slow_disk(events=started)
    try:
        os.write(started, b"1")
        for i in range(10**9):
            abstraction, triangles = contents[(first + i) % 2]
            write_abstraction(abstraction, params)
            write_mesh(triangles, mesh)
    finally:
        os._exit(0)


def test_files_survive_sigkill_whole(tmp_path: Path):
    params, mesh = tmp_path / "doc.json", tmp_path / "doc.ply"
    contents = [(_abstraction(0), _mesh(0)), (_abstraction(1), _mesh(1))]
    known: dict[Path, list[bytes]] = {params: [], mesh: []}
    fsync, replace = os.fsync, os.replace
    _slow_disk()  # as in the writer, so that `cycle` is its cycle
    try:
        start = time.perf_counter()
        for abstraction, triangles in contents:  # the two complete versions of each file
            write_abstraction(abstraction, params)
            write_mesh(triangles, mesh)
            known[params].append(params.read_bytes())
            known[mesh].append(mesh.read_bytes())
        cycle = (time.perf_counter() - start) / 2  # one write of both files
    finally:
        os.fsync, os.replace = fsync, replace
    assert known[params][0] != known[params][1] and known[mesh][0] != known[mesh][1]
    assert len(known[params][0]) > 500_000 and len(known[mesh][0]) > 500_000
    assert len(read_abstraction(params).primitives) == PRIMITIVES
    assert len(trimesh.load(mesh).faces) == len(contents[1][1].faces)

    rng = random.Random(18)
    seen = {params: set(), mesh: set()}
    killed_mid_write = 0
    on_disk = 1
    for k in range(KILLS):
        started, ready = os.pipe()
        pid = os.fork()
        if pid == 0:  # the child starts with the version that is not on disk
            _write_forever(params, mesh, contents, 1 - on_disk, ready)
        # The kill's moment counts from the child's first write, not from the fork,
        # which takes long in a big process (the whole suite's).
        _await(started, b"1")
        if k % 2:  # while a temporary file is open: just after its sync, before its rename
            _await(started, b"s")
            time.sleep(rng.uniform(0.0, 0.02))
        elif k % 4:  # anywhere in the first writes
            time.sleep(rng.uniform(0.0, 1.5 * cycle))
        else:  # once both files hold the child's first version: in its second write
            _await(started, b"r", 2)
            time.sleep(rng.uniform(0.0, 0.5 * cycle))
        os.kill(pid, signal.SIGKILL)
        os.close(started)
        os.close(ready)
        os.waitpid(pid, 0)
        for path, versions in known.items():
            data = path.read_bytes()
            assert data in versions, f"{path.name} is neither complete version after a kill"
            seen[path].add(versions.index(data))
        on_disk = known[mesh].index(mesh.read_bytes())
        others = {p.name for p in tmp_path.iterdir()} - {params.name, mesh.name}
        assert all(name.startswith(".") and name.endswith(".tmp") for name in others), others
        killed_mid_write += bool(others)
    # Every other kill landed in the middle of a write (a temporary file left), and both
    # versions were left at times: the test saw what it is about.
    assert killed_mid_write >= KILLS // 2, killed_mid_write
    assert seen[params] == {0, 1} and seen[mesh] == {0, 1}

    # The next write of each file removes what killed writers left.
    write_abstraction(contents[0][0], params)
    write_mesh(contents[0][1], mesh)
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([params.name, mesh.name])
    assert params.read_bytes() == known[params][0] and mesh.read_bytes() == known[mesh][0]


def test_only_temporary_files_of_dead_writers_are_removed(tmp_path: Path):
    pid = os.fork()
    if pid == 0:
        os._exit(0)
    os.waitpid(pid, 0)  # a writer that is gone, its pid free
    target = tmp_path / "doc.json"
    dead = tmp_path / f".doc.json.{pid}.0123456789ab.tmp"
    alive = tmp_path / f".doc.json.{os.getppid()}.0123456789ab.tmp"  # pytest's parent
    mine = tmp_path / f".doc.json.{os.getpid()}.0123456789ab.tmp"
    foreign = [tmp_path / ".doc.json.notes.tmp", tmp_path / f".other.json.{pid}.0123456789ab.tmp",
               tmp_path / f"doc.json.{pid}.0123456789ab.tmp"]
    for path in [dead, alive, mine, *foreign]:
        path.write_text("partial")
    write_abstraction(_abstraction(0), target)
    assert not dead.exists()
    assert alive.exists() and mine.exists() and all(p.exists() for p in foreign)
