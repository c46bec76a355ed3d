"""Editing speed (issue 16, "Speed"), under Xvfb on an otherwise idle machine:

    xvfb-run -a -s "-screen 0 1600x1000x24" .venv/bin/python benchmarks/bench_edit.py

Window 1600 x 1000, 8 primitives of ant.txt over ant.ply (as bench_app.py), first
primitive selected. Medians (and p95) over --moves events:

1. Mouse path: a real mouse-move QMouseEvent sent to the 3D view while a handle is
   dragged, until the frame is rendered (the render window's EndEvent) and the event
   loop is idle again; also the renders counted per move (target: 1, <= 20 ms).
2. Move + re-sweep + render: scene.drag_control_point then one synchronous render
   (target <= 12 ms).
3. Slider step: the profile's `a` slider moved one step (QSlider.setValue, as a drag of
   the slider does), until the frame is rendered (target: as fast as 1).
4. Metrics after an edit: a control-point edit until the status bar's metrics are those
   of the edited abstraction (includes the 120 ms pause that lets a drag finish; target
   <= 0.5 s); and the evaluation's own seconds.
5. Heat map of a 100k-vertex shape (eight.stl subdivided to >= 100k vertices, with
   eight.txt): HeatMapper from nothing, and after an edit of one primitive (the app's
   case, target <= 0.3 s); then in the app, an edit until the map is recoloured.

Sections 1-3 also say how their frames were drawn: reusing the picture of what did not
change (sweepedit.app.frame_reuse), taking that picture, or in full.

Runs about 2 minutes. --moves 5 --edits 2 is a smoke run (half a minute).
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path

import numpy as np
from ant_window import SHAPE, SHARED, ant_window, close_window
from ant_window import spin as spin_every

HEAT_SHAPE = SHARED / "shapes" / "eight.stl"
HEAT_PARAMS = SHARED / "sweepnet_params" / "eight.txt"
HEAT_VERTICES = 100_000


def ms(xs: list[float]) -> str:
    return (f"median {statistics.median(xs) * 1e3:7.2f} ms, "
            f"p95 {np.percentile(xs, 95) * 1e3:7.2f} ms")


def spin(app, seconds: float, until=None) -> None:
    spin_every(app, seconds, until, step=0.001)  # a finer wait than the other benchmarks'


def frame_modes(reuse) -> str:
    """How the frames since the last call were drawn (sweepedit.app.frame_reuse)."""
    counts = dict(reuse.counts)
    reuse.counts = dict.fromkeys(counts, 0)
    return (f"{counts['reuse']} reused the picture, {counts['capture']} took it, "
            f"{counts['plain']} drawn in full")


class FrameCounter:
    """Counts finished renders of a render window (its EndEvent)."""

    def __init__(self, render_window) -> None:
        self.count = 0
        self.window = render_window
        self.tag = render_window.AddObserver("EndEvent", self._tick)

    def _tick(self, *_) -> None:
        self.count += 1

    def wait_after(self, app, before: int, timeout: float = 2.0) -> bool:
        """Process events until a frame after count `before` is rendered; False if none
        came within `timeout` seconds (the event changed nothing)."""
        end = time.perf_counter() + timeout
        while self.count == before:
            app.processEvents()
            if time.perf_counter() > end:
                return False
        app.processEvents()  # the window composed with the new frame
        return True

    def close(self) -> None:
        self.window.RemoveObserver(self.tag)


def mouse_path(app, w, moves: int) -> tuple[list[float], list[int]]:
    from PySide6.QtCore import QEvent, QPointF, Qt
    from PySide6.QtGui import QMouseEvent

    plotter, scene = w.plotter, w.scene
    frames = FrameCounter(plotter.render_window)
    ratio = plotter.devicePixelRatioF()
    d = scene.world_to_display(w.doc.primitive(0).control_points[1:2])[0]
    start = QPointF(d[0] / ratio, plotter.height() - 1 - d[1] / ratio)

    def send(kind, pos, button, buttons) -> None:
        app.sendEvent(plotter, QMouseEvent(kind, pos, pos, button, buttons,
                                           Qt.KeyboardModifier.NoModifier))

    left = Qt.MouseButton.LeftButton
    send(QEvent.Type.MouseButtonPress, start, left, left)
    if not scene.dragging:
        raise RuntimeError("the press did not grab the handle")
    spin(app, 0.2)
    times, renders = [], []
    for k in range(moves):
        pos = start + QPointF(25 * np.sin(k / 7), 20 * np.cos(k / 9))
        before = frames.count
        t = time.perf_counter()
        send(QEvent.Type.MouseMove, pos, Qt.MouseButton.NoButton, left)
        if not frames.wait_after(app, before):
            print(f"   move {k}: no frame")
            continue
        times.append(time.perf_counter() - t)
        spin(app, 0.03)  # a mouse reports every ~10-30 ms: anything still due lands here
        renders.append(frames.count - before)
    send(QEvent.Type.MouseButtonRelease, start, left, Qt.MouseButton.NoButton)
    frames.close()
    return times, renders


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--moves", type=int, default=100)
    parser.add_argument("--edits", type=int, default=10)
    args = parser.parse_args()

    from PySide6.QtWidgets import QApplication

    app = QApplication.instance() or QApplication(sys.argv[:1])
    w, _ = ant_window(app, "sweepedit-bench-edit.ini", preload_fit=False)
    from sweepedit.io.params import read_abstraction
    from sweepedit.io.shapes import load_shape

    spin(app, 1.0, until=lambda: not w.metrics.running)
    size = w.plotter.render_window.GetSize()
    print(f"view {size[0]}x{size[1]} px, {len(w.doc)} primitives over {SHAPE.name}")

    # 1. mouse path
    reuse = w.scene.frame_reuse
    reuse.counts = dict.fromkeys(reuse.counts, 0)
    times, renders = mouse_path(app, w, args.moves)
    print(f"1. mouse move -> frame in the window: {ms(times)}  (target median <= 20 ms); "
          f"renders per move (renders: moves): {dict(sorted(Counter(renders).items()))}")

    print(f"   frames: {frame_modes(reuse)}")

    # 2. move + re-sweep + render
    scene, rw = w.scene, w.plotter.render_window
    cp0 = w.doc.primitive(0).control_points[1].copy()
    offsets = np.random.default_rng(0).normal(0, 0.02, (args.moves, 3))
    for k in range(min(5, args.moves)):  # warm-up
        scene.drag_control_point(0, 1, cp0 + offsets[k])
        rw.Render()
    frame_modes(reuse)  # the warm-up's frames not counted
    direct, sweep_only = [], []
    for k in range(args.moves):
        t = time.perf_counter()
        scene.drag_control_point(0, 1, cp0 + offsets[k])
        t1 = time.perf_counter()
        rw.Render()
        direct.append(time.perf_counter() - t)
        sweep_only.append(t1 - t)
    scene.end_drag()
    print(f"2. move + re-sweep + render: {ms(direct)}  (target median <= 12 ms)")
    print(f"   of which command + re-sweep + updates (panels, signals): {ms(sweep_only)}")
    print(f"   frames: {frame_modes(reuse)}")

    # 3. slider step
    frames = FrameCounter(rw)
    slider = w.props_panel.field_widgets["a"].slider
    # Back and forth between two neighbouring steps, each a change.
    low = min(max(slider.value(), slider.minimum()), slider.maximum() - 1)
    steps = []
    for k in range(args.moves):
        before = frames.count
        t = time.perf_counter()
        slider.setValue(low + (k + 1) % 2)
        if frames.wait_after(app, before):
            steps.append(time.perf_counter() - t)
        else:
            print(f"   slider step {k}: no frame")
    w.stack.close_merge()
    frames.close()
    print(f"3. slider step -> frame: {ms(steps)}  (target: as fast as 1)")
    print(f"   frames: {frame_modes(reuse)}")

    # 4. metrics after an edit
    spin(app, 10, until=lambda: not w.metrics.running)
    latencies, seconds = [], []
    for k in range(args.edits):
        previous = w.last_metrics
        t = time.perf_counter()
        scene.drag_control_point(0, 1, cp0 + offsets[k] * 2)
        scene.end_drag()
        spin(app, 30, until=lambda previous=previous: w.last_metrics is not previous
             and not w.metrics.running)
        latencies.append(time.perf_counter() - t)
        seconds.append(w.last_metrics.get("seconds", float("nan")))
    print(f"4. edit -> metrics in the status bar: {ms(latencies)}  (target median <= 500 ms); "
          f"evaluation alone: {ms(seconds)}")

    # 5. heat map, 100k vertices
    import trimesh

    from sweepedit.analysis.heatmap import HeatMapper

    mesh = trimesh.load(HEAT_SHAPE, force="mesh")
    while len(mesh.vertices) < HEAT_VERTICES:
        # A subdivided face adds about 1.5 vertices (its edge midpoints, shared).
        faces = min(len(mesh.faces), int(np.ceil((HEAT_VERTICES - len(mesh.vertices)) / 1.5)))
        mesh = mesh.subdivide(face_index=np.arange(faces))
    big = Path(tempfile.mkdtemp()) / f"{HEAT_SHAPE.stem}_fine.ply"
    mesh.export(big)
    heat_shape = load_shape(big)
    heat_prims = read_abstraction(HEAT_PARAMS).primitives
    vertices = np.asarray(heat_shape.surface.vertices, dtype=np.float64)
    mapper = HeatMapper(vertices)
    t = time.perf_counter()
    mapper.compute(heat_prims)
    cold = time.perf_counter() - t
    edits, searched = [], []
    for k in range(args.edits):
        heat_prims[0] = heat_prims[0].copy()
        heat_prims[0].control_points = heat_prims[0].control_points + 0.002 * np.sin(k + 1)
        t = time.perf_counter()
        mapper.compute(heat_prims)
        edits.append(time.perf_counter() - t)
        searched.append(mapper.searched)
    print(f"5. heat map, {len(vertices)} vertices, {len(heat_prims)} primitives: from nothing "
          f"{cold * 1e3:.0f} ms; after an edit of one primitive {ms(edits)}  "
          f"(target median <= 300 ms); vertices searched again: median "
          f"{statistics.median(searched):.0f}")
    w.open_path(big)
    w.open_params(HEAT_PARAMS, ask=False)
    w.set_heatmap_visible(True)
    view = w.heatmap
    spin(app, 60, until=lambda: view.last_distance is not None and not view.running)
    in_app, job = [], []
    w.doc.select(0)
    for k in range(args.edits):
        previous = view.last_distance
        cp = w.doc.primitive(0).control_points[1] + 0.002 * np.sin(k + 1)
        t = time.perf_counter()
        scene.drag_control_point(0, 1, cp)
        scene.end_drag()
        spin(app, 60, until=lambda previous=previous: view.last_distance is not previous
             and not view.running)
        in_app.append(time.perf_counter() - t)
        job.append(view.last_seconds)
    print(f"   in the app, edit -> map recoloured (includes the {60} ms pause): {ms(in_app)}; "
          f"the worker's computation: {ms(job)}")
    close_window(app, w)
    return 0


if __name__ == "__main__":
    sys.exit(main())
