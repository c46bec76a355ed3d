"""Render docs/mirror.png: a mirrored edit in the app, driven as a user would.

The official SweepNet parameters of a plane: one wing is deleted, the other mirrored
through the Y plane (Edit > Mirror > Y), symmetric editing is turned on, and one wing
gets a control point inserted and its tip dragged up along Z: both wings bend together.

    xvfb-run -a -s "-screen 0 1600x1000x24" .venv/bin/python scripts/mirror_screenshot.py \
        /work/shared/sweepnet_params/plane.txt docs/mirror.png
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
from PySide6.QtCore import QSettings
from PySide6.QtWidgets import QApplication

from sweepedit.app.commands import move_control_point


def main(params: str, png: str) -> int:
    app = QApplication.instance() or QApplication(sys.argv)
    from sweepedit.app.window import MainWindow

    settings = QSettings(str(Path(png).with_suffix(".ini")), QSettings.Format.IniFormat)
    window = MainWindow(settings=settings, preload_fit=False)
    window.resize(1500, 900)
    window.show()
    app.processEvents()
    if not window.open_params(params, ask=False):
        return 1
    doc = window.doc
    # The wings are the primitives reaching farthest along y, one on each side.
    reach = [float(p.control_points[:, 1].max()) for p in doc.primitives]
    left = int(np.argmax(reach))
    right = int(np.argmin([float(p.control_points[:, 1].min()) for p in doc.primitives]))
    doc.select(right)
    window.delete_primitive()
    left -= int(right < left)
    doc.select(left)
    window.mirror_selection(1)  # Edit > Mirror > Y
    window.act_symmetric.setChecked(True)
    window.toggle_symmetric()
    doc.select(left)
    window.scene.insert_control_point(None)
    tip = int(np.argmax(np.abs(doc.primitive(left).control_points[:, 1])))
    point = doc.primitive(left).control_points[tip] + np.array([0.0, 0.0, 0.12])
    window.stack.push(move_control_point(doc, left, tip, point))
    from sweepedit.geometry.axis_edit import is_mirror_pair

    assert is_mirror_pair(doc.primitive(left), doc.primitive(len(doc) - 1), 1, tol=0.0)
    window.scene.view_preset("right")  # from the nose: the wings span the picture
    camera = window.plotter.renderer.GetActiveCamera()
    camera.Elevation(18.0)
    camera.Azimuth(30.0)
    camera.OrthogonalizeViewUp()
    window.plotter.renderer.ResetCamera()
    window.show_status("Mirror Y, then symmetric editing: one wing's tip dragged up, the "
                       "other follows", 0)
    for _ in range(20):
        app.processEvents()
    ok = window.save_screenshot(png, full_window=True)
    doc.set_dirty(False)
    window.close()
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main(*sys.argv[1:3]))
