"""Autosave and crash recovery.

After every change of the Document a recovery file is written, atomically, at most once
every `interval_ms` (a throttle: a long drag is saved every two seconds, not only once it
ends). It holds the parameters exactly (the JSON parameter format, floats unrounded), the
document's path and the target shape's path. A clean exit or a save removes it.

Each running editor owns one recovery file, `session-<id>.json`, and holds a QLockFile
beside it while it runs: at start, files whose lock is free belong to an editor that is
gone (killed, crashed, powered off) and are offered for recovery; files of editors still
running are left alone. A recovery file older than its document (saved since) is stale
and removed without asking.
"""

from __future__ import annotations

import json
import time
import uuid
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from PySide6.QtCore import QLockFile, QObject, QStandardPaths, QTimer

from sweepedit.app.document import Connections, Document
from sweepedit.errors import FileFormatError
from sweepedit.geometry.model import Abstraction

RECOVERY_FORMAT = "sweepedit.recovery"
RECOVERY_VERSION = 1
AUTOSAVE_INTERVAL_MS = 2000
RECOVERY_FOLDER = "recovery"


def default_recovery_dir() -> Path:
    """<the user's application data folder (Qt's AppDataLocation)>/recovery."""
    base = QStandardPaths.writableLocation(QStandardPaths.StandardLocation.AppDataLocation)
    if not base:  # no writable data location on this system
        base = str(Path.home() / ".sweepedit")
    return Path(base) / RECOVERY_FOLDER


@dataclass
class Recovery:
    """One recovery file left by an editor that is gone."""

    file: Path
    saved_at: float  # seconds since the epoch, when it was written
    document_path: Path | None
    shape_path: Path | None
    frame_known: bool
    abstraction: Abstraction

    @property
    def title(self) -> str:
        """The name the user knows the document by."""
        for path in (self.document_path, self.shape_path):
            if path is not None:
                return path.name
        return "an untitled document"

    def question(self) -> str:
        """'Recover the unsaved edits of cactus.json from 14:02?'"""
        stamp = time.localtime(self.saved_at)
        when = time.strftime("%H:%M", stamp)
        if time.strftime("%Y-%m-%d", stamp) != time.strftime("%Y-%m-%d"):
            when = time.strftime("%d %b %H:%M", stamp)
        return f"Recover the unsaved edits of {self.title} from {when}?"


def recovery_json(doc: Document, saved_at: float | None = None) -> str:
    """The recovery file's text for the document as it is now."""
    from sweepedit.io.params import abstraction_to_json

    data = {
        "format": RECOVERY_FORMAT,
        "version": RECOVERY_VERSION,
        "saved_at": time.time() if saved_at is None else float(saved_at),
        "document_path": str(doc.path) if doc.path is not None else None,
        "shape_path": str(doc.shape_path) if doc.shape_path is not None else None,
        "frame_known": bool(doc.frame_known),
        "abstraction": abstraction_to_json(doc.abstraction),
    }
    return json.dumps(data, indent=1, allow_nan=False)


def read_recovery(path: Path) -> Recovery:
    """Parse a recovery file; FileFormatError when it is not one or is damaged."""
    from sweepedit.io.params import abstraction_from_json

    try:
        data = json.loads(Path(path).read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise FileFormatError(path, f"not a readable recovery file ({exc})") from exc
    if not isinstance(data, dict) or data.get("format") != RECOVERY_FORMAT:
        raise FileFormatError(path, "not a sweepedit recovery file")
    if data.get("version") != RECOVERY_VERSION:
        raise FileFormatError(path, f"recovery file version {data.get('version')!r} is not "
                              f"{RECOVERY_VERSION}")
    try:
        saved_at = float(data["saved_at"])
        doc_path = data.get("document_path")
        shape_path = data.get("shape_path")
        abstraction_data = data["abstraction"]
    except (KeyError, TypeError, ValueError) as exc:
        raise FileFormatError(path, f"recovery file lacks {exc}") from exc
    return Recovery(Path(path), saved_at, Path(doc_path) if doc_path else None,
                    Path(shape_path) if shape_path else None, bool(data.get("frame_known")),
                    abstraction_from_json(abstraction_data, path))


class Autosaver(QObject):
    """Writes `doc` to this session's recovery file after changes, at most every
    `interval_ms`. `remove()` after a save or at a clean exit; `written` counts writes.
    `report(message)` is told, once per kind of failure, when the file cannot be written."""

    def __init__(self, doc: Document, directory: Path | None = None,
                 interval_ms: int = AUTOSAVE_INTERVAL_MS, parent: QObject | None = None,
                 report: Callable[[str], None] | None = None) -> None:
        super().__init__(parent)
        self.doc = doc
        self.report = report
        self.directory = Path(directory) if directory is not None else default_recovery_dir()
        self.session = uuid.uuid4().hex[:12]
        self.path = self.directory / f"session-{self.session}.json"
        self._lock: QLockFile | None = None
        self._declined: list[Path] = []  # kept until this session first writes its own
        self.written = 0
        self.last_error: str | None = None
        self.enabled = True
        self._timer = QTimer(self)
        self._timer.setSingleShot(True)
        self._timer.setInterval(int(interval_ms))
        self._timer.timeout.connect(self.write_now)
        self._links = Connections()
        self._links.connect(doc.edited, self.schedule)
        self._links.connect(doc.path_changed, self.schedule)

    # -- writing ----------------------------------------------------------------------
    def schedule(self) -> None:
        """A change happened: write within interval_ms (a burst of changes: one write)."""
        if self.enabled and not self._timer.isActive():
            self._timer.start()

    @property
    def pending(self) -> bool:
        return self._timer.isActive()

    def write_now(self) -> bool:
        """Write the recovery file now when the document has unsaved changes (else remove
        it: nothing would be lost). False when it could not be written."""
        self._timer.stop()
        if not self.enabled:
            return False
        if not self.doc.dirty:
            self.remove()
            return True
        from sweepedit.io.params import atomic_write_text

        try:
            self.directory.mkdir(parents=True, exist_ok=True)
            self._hold_lock()
            atomic_write_text(self.path, recovery_json(self.doc))
        except (OSError, ValueError) as exc:  # a full disk must not stop the editing
            error = f"Autosave failed: cannot write {self.path} ({exc}); save your work."
            if self.report is not None and error != self.last_error:
                self.report(error)
            self.last_error = error
            return False
        self.last_error = None
        self.written += 1
        for old in self._declined:
            _unlink(old)
        self._declined.clear()
        return True

    def remove(self) -> None:
        """Delete this session's recovery file (after a save, at a clean exit)."""
        self._timer.stop()
        _unlink(self.path)

    def shutdown(self) -> None:
        """At a clean exit: no file left, the lock released."""
        self.enabled = False
        self._links.disconnect_all()
        self.remove()
        if self._lock is not None:
            self._lock.unlock()  # removes the lock file
            self._lock = None

    def _hold_lock(self) -> None:
        if self._lock is None:
            lock = QLockFile(str(self._lock_path(self.path)))
            lock.setStaleLockTime(0)  # stale only when its process is gone
            if lock.tryLock(0):
                self._lock = lock

    @staticmethod
    def _lock_path(path: Path) -> Path:
        return path.with_suffix(".lock")

    # -- recovering -------------------------------------------------------------------
    def orphans(self) -> list[Recovery]:
        """Recovery files of editors that are gone, newest first. Stale ones (older than
        their document) and unreadable ones are removed."""
        found: list[Recovery] = []
        if not self.directory.is_dir():
            return found
        for file in sorted(self.directory.glob("session-*.json")):
            if file == self.path:
                continue
            lock = QLockFile(str(self._lock_path(file)))
            lock.setStaleLockTime(0)
            if not lock.tryLock(0):
                continue  # its editor is still running
            try:
                recovery = read_recovery(file)
                if _stale(recovery):
                    _unlink(file)
                else:
                    found.append(recovery)
            except FileFormatError:  # a damaged file recovers nothing
                _unlink(file)
            finally:
                lock.unlock()  # removes the dead editor's lock file too
        return sorted(found, key=lambda r: r.saved_at, reverse=True)

    def taken(self, recovery: Recovery) -> None:
        """The user recovered it: its file goes, this session's own file takes over."""
        _unlink(recovery.file)
        self.write_now()

    def declined(self, recovery: Recovery) -> None:
        """The user declined: the file stays until this session's next autosave."""
        self._declined.append(recovery.file)


def _stale(recovery: Recovery) -> bool:
    """Older than its document: the document was saved after the last autosave."""
    path = recovery.document_path
    if path is None:
        return False
    try:
        return path.stat().st_mtime >= recovery.saved_at
    except OSError:  # the document is gone: the recovery file is all there is
        return False


def _unlink(path: Path) -> None:
    try:
        path.unlink()
    except FileNotFoundError:
        pass
    except OSError:
        pass  # a read-only data folder: nothing better to do than leave it
