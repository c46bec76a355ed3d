"""`sweepedit batch`: inputs, resume, failure isolation and Ray (a real local instance,
a worker killed mid-shape, the driver killed and rerun, a two-node simulated cluster).

The fits are tiny (K = 2, a few refinement steps, 2,000 metric samples): these tests are
about the job around the fit, not its quality.
"""

from __future__ import annotations

import csv
import json
import os
import signal
import subprocess
import sys
import threading
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import trimesh

from sweepedit.analysis.metrics import evaluate
from sweepedit.batch import BatchOptions, JobSpec, expand_inputs, run_batch
from sweepedit.batch.inputs import unique_names
from sweepedit.batch.summary import completed
from sweepedit.cli import main
from sweepedit.errors import SweepeditError
from sweepedit.fitting.fit import FitSettings
from sweepedit.io.params import read_abstraction
from sweepedit.io.shapes import load_shape

ray = pytest.importorskip("ray")

ROOT = Path(__file__).resolve().parents[1]
CACTUS = ROOT / "resources" / "examples" / "cactus.off"
FAST = ["-k", "2", "--refine-iterations", "10", "--residual-rounds", "0",
        "--samples", "2000", "--no-sheet", "--quiet"]
SETTINGS = FitSettings(primitives=2, refine_iterations=10, residual_rounds=0)
SPEC = JobSpec(SETTINGS, samples=2000)


def _capsule(path: Path) -> Path:
    """A capsule along x (length 0.6 + 2 x 0.15): a shape every fit can follow."""
    mesh = trimesh.creation.capsule(height=0.6, radius=0.15, count=[16, 16])
    mesh.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, [0, 1, 0]))
    mesh.export(path)
    return path


def _good_shapes(folder: Path, copies: int = 1) -> list[Path]:
    folder.mkdir(parents=True, exist_ok=True)
    shapes = [_capsule(folder / "capsule.stl")]
    for i in range(copies):
        target = folder / f"cactus{i or ''}.off"
        target.write_bytes(CACTUS.read_bytes())
        shapes.append(target)
    return shapes


def _rows(outdir: Path) -> dict[str, dict[str, str]]:
    with open(outdir / "summary.csv", encoding="utf-8", newline="") as handle:
        return {r["shape"]: r for r in csv.DictReader(handle)}


def _stamp(paths: list[Path]) -> dict[Path, tuple[int, bytes]]:
    return {p: (p.stat().st_mtime_ns, p.read_bytes()) for p in paths}


@pytest.fixture(scope="module")
def _ray_module():
    yield
    if ray.is_initialized():
        ray.shutdown()


@pytest.fixture
def local_ray(_ray_module):
    """One local Ray instance (2 CPUs) for the module; batch uses it as it finds it."""
    if not ray.is_initialized():
        ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False,
                 logging_level="ERROR", object_store_memory=100 * 2**20)
    return ray


# --------------------------------------------------------------------------- inputs


def test_inputs_folders_globs_lists_and_names(tmp_path: Path) -> None:
    data = tmp_path / "data"
    (data / "a").mkdir(parents=True)
    (data / "b").mkdir()
    (data / ".hidden").mkdir()
    for p in ("a/cat.obj", "b/cat.obj", "b/dog.stl", "b/dog.ply", ".hidden/x.obj",
              "notes.txt", "manifest.json"):
        (data / p).write_text("x")
    out = data / "out"
    out.mkdir()
    (out / "cat.glb").write_text("x")  # outputs inside an input folder are not inputs
    shapes = expand_inputs([data], exclude=out)
    assert [s.path.relative_to(data).as_posix() for s in shapes] == [
        "a/cat.obj", "b/cat.obj", "b/dog.ply", "b/dog.stl"]
    assert [s.name for s in shapes] == ["a__cat", "b__cat", "dog_ply", "dog_stl"]

    cloud = tmp_path / "cloud.txt"
    cloud.write_text("0 0 0\n1 1 1\n")
    listing = tmp_path / "list.csv"
    listing.write_text("id,path\n1,data/b/dog.stl\n2,cloud.txt\n3,missing.off\n")
    shapes = expand_inputs([listing, str(data / "a" / "*.obj"), cloud])
    assert [s.path.name for s in shapes] == ["dog.stl", "cloud.txt", "missing.off", "cat.obj"]
    text_list = tmp_path / "shapes.txt"
    text_list.write_text("# two shapes\ndata/a/cat.obj\n\n" + str(data / "b" / "dog.stl") + "\n")
    assert [s.path.name for s in expand_inputs([text_list])] == ["cat.obj", "dog.stl"]

    (tmp_path / "empty").mkdir()
    for bad in (tmp_path / "nothing", str(tmp_path / "*.nope"), tmp_path / "empty"):
        with pytest.raises(SweepeditError):
            expand_inputs([bad])
    assert unique_names([Path("x/a.obj"), Path("y/a.obj"), Path("x/b.obj")]) == [
        "x__a", "y__a", "b"]


def test_usage_errors_exit_2(tmp_path: Path, capsys) -> None:
    assert main(["batch", str(tmp_path / "none"), "-o", str(tmp_path / "o")]) == 2
    assert "no such file or folder" in capsys.readouterr().err
    file_out = tmp_path / "file"
    file_out.write_text("x")
    assert main(["batch", str(CACTUS), "-o", str(file_out), *FAST]) == 2
    assert main(["batch", str(CACTUS), "-o", str(tmp_path / "o"), "--gpus-per-task", "-1"]) == 2
    assert "GPUs per task" in capsys.readouterr().err
    for bad in (["--workers", "0"], ["-k", "0"]):  # argparse's usage errors
        with pytest.raises(SystemExit) as exc:
            main(["batch", str(CACTUS), "-o", str(tmp_path / "o"), *bad])
        assert exc.value.code == 2


# --------------------------------------------------------------------------- in process


def test_in_process_without_ray_and_resume_rules(tmp_path: Path, monkeypatch, capsys) -> None:
    """Without Ray: one line about the extra, the same outputs; a rerun skips the shape,
    other settings or a changed input refit it."""
    import sweepedit.batch.runner as runner

    monkeypatch.setattr(runner, "ray_available", lambda: False)
    shape = _good_shapes(tmp_path / "in")[1]
    out = tmp_path / "out"
    assert main(["batch", str(shape), "-o", str(out), *FAST]) == 0
    err = capsys.readouterr().err
    assert "pip install 'sweepedit[batch]'" in err
    assert _rows(out)["cactus"]["status"] == "ok"
    (item,) = expand_inputs([shape])
    assert completed(out, item, SPEC) is not None
    assert completed(out, item, replace(SPEC, samples=3000)) is None
    assert completed(out, item, JobSpec(replace(SETTINGS, seed=1), samples=2000)) is None
    assert completed(out, item, replace(SPEC, mesh_format="obj")) is None  # no mesh yet
    before = _stamp([out / "cactus.json", out / "cactus.glb"])
    report = run_batch([item], BatchOptions(out, SPEC, engine="inprocess", progress=False))
    assert (report.skipped, report.fitted) == (1, 0)
    assert _stamp(list(before)) == before
    os.utime(shape, ns=(time.time_ns(), time.time_ns()))  # the input changed: refit
    assert completed(out, item, SPEC) is None


# --------------------------------------------------------------------------- Ray


def test_good_corrupt_and_empty_give_outputs_two_failed_rows_exit_1(
        tmp_path: Path, local_ray) -> None:
    folder = tmp_path / "in"
    _good_shapes(folder)
    (folder / "corrupt.obj").write_text("v 1 2 3\nf 1 2 zz\n")
    (folder / "empty.off").write_text("OFF\n0 0 0\n")
    out = tmp_path / "out"
    assert main(["batch", str(folder), "-o", str(out), *FAST]) == 1
    rows = _rows(out)
    assert {k: r["status"] for k, r in rows.items()} == {
        "capsule": "ok", "cactus": "ok", "corrupt": "failed", "empty": "failed"}
    assert "corrupt.obj: cannot read the .obj file" in rows["corrupt"]["error"]
    assert "empty.off: no geometry found" in rows["empty"]["error"]
    assert not (out / "corrupt.json").exists() and not (out / "empty.glb").exists()
    for name in ("capsule", "cactus"):
        abstraction = read_abstraction(out / f"{name}.json")
        assert len(abstraction.primitives) == int(rows[name]["primitives"]) >= 1
        mesh = trimesh.load(out / f"{name}.glb", force="mesh")
        assert mesh.is_watertight and mesh.volume > 0
    # The row holds the `eval` protocol's numbers for the written file.
    metrics = evaluate(read_abstraction(out / "capsule.json"),
                       load_shape(folder / "capsule.stl"), n_samples=2000, seed=0)
    assert float(rows["capsule"]["iou"]) == pytest.approx(metrics["iou"], rel=1e-5)
    assert float(rows["capsule"]["cd_l1"]) == pytest.approx(metrics["cd_l1"], rel=1e-5)
    # A capsule is one sweep: even this tiny fit covers most of it.
    assert float(rows["capsule"]["iou"]) > 0.5
    assert (out / "summary.md").read_text().count("error:") == 2


def test_bench_is_batch_plus_the_table(tmp_path: Path, local_ray, capsys) -> None:
    folder = tmp_path / "set"
    folder.mkdir()
    _capsule(folder / "capsule.stl")
    out = tmp_path / "bench" / "bench.md"
    # --workers 1: one CPU per task, as the earlier tests, so Ray reuses their warm workers.
    fast = [x for x in FAST if x not in ("--no-sheet", "--quiet")]
    assert main(["bench", "--shapes", str(folder), "--out", str(out), "--workers", "1",
                 *fast]) == 0
    table = out.read_text()
    assert "| capsule |" in table and "| **median** |" in table and "| refinement |" in table
    assert table in capsys.readouterr().out
    assert json.loads(out.with_suffix(".json").read_text())["rows"][0]["shape"] == "capsule"
    assert out.with_suffix(".png").stat().st_size > 0
    abstraction = read_abstraction(out.parent / "params" / "capsule.json")
    assert abstraction.fit["batch"]["node"]  # fitted through batch, on a Ray node


def _task_pids(function: str = "run_job") -> list[int]:
    """PIDs of this test's Ray workers now executing `function`: Ray titles them
    ray::<function>, and their parent is a raylet of this session (never another job's)."""
    session = ray._private.worker._global_node.get_session_dir_path().encode()
    pids = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            if not (entry / "cmdline").read_bytes().startswith(f"ray::{function}".encode()):
                continue
            parent = (entry / "stat").read_text().rsplit(")", 1)[1].split()[1]
            if session in Path(f"/proc/{parent}/cmdline").read_bytes():
                pids.append(int(entry.name))
        except OSError:
            continue
    return pids


def test_worker_killed_mid_shape_is_retried(tmp_path: Path, local_ray) -> None:
    shape = _good_shapes(tmp_path / "in")[1]
    out = tmp_path / "out"
    box: dict[str, object] = {}
    options = BatchOptions(out, SPEC, engine="ray", max_retries=2, progress=False)
    thread = threading.Thread(
        target=lambda: box.setdefault("report", run_batch(expand_inputs([shape]), options)))
    thread.start()
    deadline = time.monotonic() + 60
    while not (pids := _task_pids()) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert pids, "the task never started"
    os.kill(pids[0], signal.SIGKILL)
    thread.join(120)
    report = box["report"]
    assert [o.status for o in report.outcomes] == ["ok"]  # type: ignore[attr-defined]
    record = read_abstraction(out / "cactus.json").fit["batch"]
    assert record["pid"] != pids[0]  # finished by another worker, the retry


def test_time_limit_hard_kill_is_a_failed_row(tmp_path: Path, local_ray) -> None:
    shape = _good_shapes(tmp_path / "in")[1]
    # The default fit (seconds; the test's fast one can finish inside the 0.5 s).
    spec = JobSpec(FitSettings(), samples=2000)
    options = BatchOptions(tmp_path / "out", spec, engine="ray", kill_after=0.5,
                           progress=False)
    report = run_batch(expand_inputs([shape]), options)
    (outcome,) = report.outcomes
    assert outcome.status == "failed" and outcome.error.startswith("killed after")


def test_driver_sigkill_then_rerun_fits_only_the_missing(tmp_path: Path, local_ray) -> None:
    folder = tmp_path / "in"
    _good_shapes(folder, copies=2)  # capsule, cactus, cactus1
    out = tmp_path / "out"
    # The driver joins this test's instance (--address: an existing cluster), as a
    # second driver would; its shapes are its own job, its death ends them.
    address = ray.get_runtime_context().gcs_address
    command = [sys.executable, "-m", "sweepedit.cli", "batch", str(folder), "-o", str(out),
               "--address", address, "--workers", "1", *FAST]
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    driver = subprocess.Popen(command, env=env, stdout=subprocess.DEVNULL,
                              stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 90
    while not list(out.glob("*.json")) and time.monotonic() < deadline:
        time.sleep(0.05)
    driver.send_signal(signal.SIGKILL)
    driver.wait(10)
    time.sleep(1.0)  # the instance's workers go with their driver
    done = sorted(p.stem for p in out.glob("*.json"))
    assert 1 <= len(done) < 3
    files = [out / f"{n}.{ext}" for n in done for ext in ("json", "glb")]
    before = _stamp(files)
    report = run_batch(expand_inputs([folder], exclude=out),
                       BatchOptions(out, SPEC, engine="ray", progress=False))
    assert report.skipped == len(done) and report.fitted == 3 - len(done)
    assert not report.failed
    assert _stamp(files) == before  # finished shapes: not refitted, files untouched
    assert {r["status"] for r in _rows(out).values()} == {"ok"} and len(_rows(out)) == 3


def test_two_node_cluster_runs_tasks_on_both_nodes(tmp_path: Path, _ray_module) -> None:
    from ray.cluster_utils import Cluster

    if ray.is_initialized():
        ray.shutdown()
    cluster = Cluster(initialize_head=True, head_node_args={
        "num_cpus": 1, "include_dashboard": False, "object_store_memory": 80 * 2**20})
    try:
        cluster.add_node(num_cpus=1, object_store_memory=80 * 2**20)
        cluster.wait_for_nodes()
        ray.init(address=cluster.address, log_to_driver=False, logging_level="ERROR")
        folder = tmp_path / "in"
        _good_shapes(folder)
        out = tmp_path / "out"
        report = run_batch(expand_inputs([folder]), BatchOptions(out, SPEC, progress=False))
        assert not report.failed
        nodes = {n["NodeID"] for n in ray.nodes() if n["Alive"]}
        assert len(nodes) == 2
        assert {r["node"] for r in _rows(out).values()} == nodes
    finally:
        ray.shutdown()
        cluster.shutdown()


def test_without_an_address_batch_starts_its_own_ray_whatever_this_machine_says(
        _ray_module, monkeypatch) -> None:
    """No --address: a local instance of its own, even where RAY_ADDRESS (or a `ray start`
    head's session file) names another cluster, here one that is not there."""
    from sweepedit.batch.engine import RayEngine

    if ray.is_initialized():
        ray.shutdown()
    monkeypatch.setenv("RAY_ADDRESS", "127.0.0.1:9")
    engine = RayEngine(workers=1, cpus_per_task=1, gpus_per_task=0.0, address=None,
                       max_retries=0)
    try:
        assert ray.is_initialized() and engine.slots() == 1
        assert ray.cluster_resources().get("CPU") == 1.0
    finally:
        engine.shutdown()
