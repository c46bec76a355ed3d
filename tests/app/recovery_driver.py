"""A driven editor for the kill-and-recover test and benchmark (not a test module).

    python recovery_driver.py edit SHAPE PARAMS SEED EDITS [--forever]
    python recovery_driver.py recover OUT.json

`edit` opens the real window on SHAPE and PARAMS, makes EDITS seeded edits through the
command stack as the panels and the mouse do, waits for the autosave, prints
"ready <hash>" and then, after one more edit, "edited <hash>"; with --forever it goes on
editing every 20 ms until killed. Each autosave prints "writing <hash>" before and
"wrote <hash>" after it. `recover` starts an editor, recovers without asking (as
`sweepedit gui --recover yes`), prints "recovered <hash>" and saves the document to
OUT.json. The data folder is the standard one: point XDG_DATA_HOME somewhere private.
"""

from __future__ import annotations

import hashlib
import json
import sys
import time

import numpy as np

from sweepedit.app.commands import CommandStack, move_control_point, set_field
from sweepedit.app.document import Document
from sweepedit.geometry.model import Abstraction


def state_hash(abstraction: Abstraction) -> str:
    """A digest of everything a parameter file holds (exact floats)."""
    from sweepedit.io.params import abstraction_to_json

    text = json.dumps(abstraction_to_json(abstraction), sort_keys=True, allow_nan=False)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def make_edit(doc: Document, rng: np.random.Generator):
    """One edit as a user makes it: a control point moved or a profile half-axis set."""
    i = int(rng.integers(len(doc)))
    prim = doc.primitive(i)
    if rng.random() < 0.6:
        j = int(rng.integers(prim.n_control_points))
        return move_control_point(doc, i, j, prim.control_points[j] + rng.uniform(-0.01, 0.01, 3))
    return set_field(doc, i, "a", float(np.clip(prim.a * rng.uniform(0.9, 1.1), 0.02, 0.4)),
                     merge=False)


def apply_edits(doc: Document, stack: CommandStack, rng: np.random.Generator, n: int) -> None:
    for _ in range(n):
        stack.push(make_edit(doc, rng))
        stack.close_merge()


def _say(text: str) -> None:
    print(text, flush=True)


def _window():
    from sweepedit.app.main import _application
    from sweepedit.app.window import MainWindow

    app = _application()
    window = MainWindow(preload_fit=False)
    window.report_error = lambda title, message: _say(f"error {title}: {message}")
    window.resize(1000, 700)
    window.show()
    app.processEvents()
    return app, window


def _spin(app, seconds: float, until=None) -> None:
    end = time.perf_counter() + seconds
    while time.perf_counter() < end and not (until and until()):
        app.processEvents()
        time.sleep(0.005)


def edit(shape: str, params: str, seed: int, edits: int, forever: bool) -> None:
    app, window = _window()
    autosave = window.autosave
    write = autosave.write_now

    def traced_write() -> bool:
        h = state_hash(window.doc.abstraction)
        _say(f"writing {h}")
        ok = write()
        if ok and autosave.path.is_file():
            _say(f"wrote {h}")
        return ok

    autosave.write_now = traced_write
    autosave._timer.timeout.disconnect()
    autosave._timer.timeout.connect(traced_write)
    assert window.open_shape(shape) and window.open_params(params)
    rng = np.random.default_rng(seed)
    apply_edits(window.doc, window.stack, rng, edits)
    done = autosave.written
    _spin(app, 30.0, until=lambda: autosave.written > done and not autosave.pending)
    _say(f"ready {state_hash(window.doc.abstraction)} {autosave.path}")
    apply_edits(window.doc, window.stack, rng, 1)
    _say(f"edited {state_hash(window.doc.abstraction)}")
    while True:  # until killed from outside
        if forever:
            apply_edits(window.doc, window.stack, rng, 1)
        _spin(app, 0.02)


def recover(out: str) -> None:
    app, window = _window()
    ok = window.offer_recovery(True)
    _spin(app, 0.1)
    doc = window.doc
    _say(f"recovered {state_hash(doc.abstraction) if ok else 'nothing'} dirty={doc.dirty} "
         f"path={doc.path} shape={doc.shape_path}")
    from sweepedit.io.params import write_abstraction

    write_abstraction(doc.abstraction, out)
    doc.set_dirty(False)
    window.close()
    app.processEvents()


if __name__ == "__main__":
    if sys.argv[1] == "edit":
        edit(sys.argv[2], sys.argv[3], int(sys.argv[4]), int(sys.argv[5]),
             "--forever" in sys.argv[6:])
    elif sys.argv[1] == "recover":
        recover(sys.argv[2])
    else:
        raise SystemExit(__doc__)
