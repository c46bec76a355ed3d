"""Fuzzing the readers (issue 18): mutated real files of every format sweepedit reads
either load or raise sweepedit's own error naming the file -- never another exception,
never over 5 s, never over 2 GiB (the reader runs in a worker process whose address
space is limited; see tests/fuzzing.py). A bounded number of cases per format runs here;
benchmarks/bench_fuzz.py runs the large campaign.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest
from fuzzing import FORMATS, HypothesisChooser, Worker, describe, kind_of, mutate, write_seeds
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

EXAMPLES_PER_FORMAT = 25


@pytest.fixture(scope="module")
def seeds(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    return write_seeds(tmp_path_factory.mktemp("seeds"))


@pytest.fixture(scope="module")
def worker():
    worker = Worker()
    yield worker
    worker.close()


@pytest.mark.parametrize("fmt", list(FORMATS))
def test_mutated_files_load_or_fail_with_a_clear_error(fmt: str, seeds: dict[str, Path],
                                                        worker: Worker, tmp_path: Path):
    seed = seeds[fmt].read_bytes()
    # The unmutated seed is a good file: the cases below start from something that loads.
    first = worker.run(seeds[fmt], kind_of(fmt))
    assert first.result == "loaded", describe(first, fmt, [])
    target = tmp_path / f"case{seeds[fmt].suffix}"

    @settings(max_examples=EXAMPLES_PER_FORMAT, deadline=None, derandomize=True,
              database=None, suppress_health_check=list(HealthCheck))
    @given(st.data())
    def case(data: st.DataObject) -> None:
        mutated, names = mutate(seed, fmt, HypothesisChooser(data))
        target.write_bytes(mutated)
        outcome = worker.run(target, kind_of(fmt))
        assert outcome.ok, describe(outcome, fmt, names)

    case()


def _huge_headers(seeds: dict[str, Path]) -> dict[str, tuple[str, bytes]]:
    """Files whose headers claim far more than they hold: name -> (seed format, bytes)."""
    ply_a = seeds["ply_ascii"].read_bytes()
    ply_b = seeds["ply_binary"].read_bytes()
    off = seeds["off"].read_bytes()
    npy = seeds["npy"].read_bytes()
    glb = bytearray(seeds["glb"].read_bytes())
    json_length = int.from_bytes(glb[12:16], "little")
    glb[20 + json_length:24 + json_length] = (4_000_000_000).to_bytes(4, "little")
    return {
        "ply ascii, 10^12 faces": ("ply_ascii", re.sub(rb"element face \d+",
                                                       b"element face 1000000000000", ply_a)),
        "ply ascii, 10^12 vertices": ("ply_ascii", re.sub(rb"element vertex \d+",
                                                          b"element vertex 1000000000000",
                                                          ply_a)),
        "ply binary, 10^12 faces": ("ply_binary", re.sub(rb"element face \d+",
                                                         b"element face 1000000000000", ply_b)),
        "off, 10^12 vertices": ("off", re.sub(rb"\A(C?OFF\s+)\d+", rb"\g<1>1000000000000", off)),
        "npy, 10^12 cells": ("npy", npy.replace(b"(24, 24, 24)", b"(10000, 10000, 10000)")),
        "npy, 1.2 GB claimed": ("npy", npy.replace(b"(24, 24, 24)", b"(1200, 1000, 1000)")),
        "glb, a 4 GB chunk": ("glb", bytes(glb)),
        "binvox, 10^12 cells": ("binvox", seeds["binvox"].read_bytes().replace(
            b"dim 24 24 24", b"dim 10000 10000 10000")),
        "json, an integer of 5,000 digits": ("json", seeds["json"].read_bytes().replace(
            b'"version": 1', b'"version": ' + b"1" * 5000)),
    }


def test_headers_claiming_huge_counts_fail_at_once(seeds: dict[str, Path], tmp_path: Path):
    # A worker of its own: the peak memory is a high-water mark of the worker's life, and
    # the shared worker may have loaded big mutated meshes before.
    worker = Worker()
    try:
        for name, (fmt, data) in _huge_headers(seeds).items():
            assert data != seeds[fmt].read_bytes(), f"{name}: the seed changed; update the case"
            path = tmp_path / f"huge{seeds[fmt].suffix}"
            path.write_bytes(data)
            outcome = worker.run(path, kind_of(fmt))
            assert outcome.result == "error", f"{name}: {describe(outcome, fmt, [])}"
            assert outcome.seconds < 1.0 and outcome.peak_rss_mib < 1024, name
    finally:
        worker.close()
