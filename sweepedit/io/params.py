"""Parameter files: sweepedit's JSON abstraction file and the official SweepNet text file.

JSON (docs/parameter-format.md)::

    {"format": "sweepedit.abstraction", "version": 1,
     "normalization": {"center": [x, y, z], "scale": s},
     "source": {...} | null,
     "primitives": [{"control_points": [[x, y, z], ...], "profile": {"a", "b", "degree"},
                     "scaling": [s1, ..., sk], "name", "color", "visible", "locked"}, ...],
     "fit": {...} | null}

Unknown keys survive a load/save cycle: top-level ones in `Abstraction.extras`, per-primitive
ones in `SweepPrimitive.extras`, and unknown keys *inside* "profile" / "normalization" in
`extras["profile"]` / `Abstraction.extras["normalization"]` (those names are known keys, so
they can never collide with a real unknown key of the same level).

Official SweepNet text: one row per primitive, c1..cn (3n numbers), a, b, d, s_quad, s_lin;
3n + 5 columns (14 for the usual n = 3). It holds geometry only: names, colours, flags,
normalisation (the identity), source and fit record are not stored.

Every file is written atomically (`atomic_write_text`, `atomic_write_bytes`, `atomic_open`):
an error mid-write leaves the previous file untouched and no temporary file behind; a
crash (SIGKILL, a power cut) leaves the previous or the new file whole, and a hidden
`.NAME.PID.HEX.tmp` that the next write of that file removes.
"""

from __future__ import annotations

import contextlib
import copy
import io
import json
import math
import os
import re
import secrets
import stat
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import IO, Any, Literal

import numpy as np

from sweepedit.errors import (
    FileFormatError,
    InvalidPrimitiveError,
    SweepeditError,
    primitive_label,
)
from sweepedit.geometry.model import (
    MIN_CONTROL_POINTS,
    Abstraction,
    Normalization,
    SweepPrimitive,
    palette_color,
)

__all__ = [
    "FORMAT_NAME",
    "FORMAT_VERSION",
    "abstraction_from_json",
    "abstraction_to_json",
    "atomic_open",
    "atomic_write_bytes",
    "atomic_write_text",
    "read_abstraction",
    "read_official_txt",
    "write_abstraction",
    "write_official_txt",
]

PathLike = str | os.PathLike[str]

FORMAT_NAME = "sweepedit.abstraction"
FORMAT_VERSION = 1

TOP_KEYS = ("format", "version", "normalization", "source", "primitives", "fit")
# What one file may ask for, checked before any work: the exact inside test and the
# meshers hold every primitive at once (100,000 primitives asked eval for 13.7 GiB and
# crashed manifold3d's union). Fits use at most 32 primitives of 8 control points and 3
# scaling terms; these leave a hand-made file a wide margin.
MAX_PRIMITIVES = 1024
MAX_CONTROL_POINTS = 256
MAX_SCALING_TERMS = 32
PRIMITIVE_KEYS = ("control_points", "profile", "scaling", "name", "color", "visible", "locked")
PROFILE_KEYS = ("a", "b", "degree")
NORMALIZATION_KEYS = ("center", "scale")

_COLOR_RE = re.compile(r"#[0-9a-fA-F]{6}")
# The official format stores the two scaling coefficients after the profile.
_OFFICIAL_SCALING_COLUMNS = 2
_OFFICIAL_FMT = "%.18e"  # numpy's savetxt default; 19 significant digits round-trip a double


def default_name(index: int) -> str:
    """Name given to the index-th (0-based) primitive when a file has none: the same
    1-based label as in error messages."""
    return primitive_label(index)


# --------------------------------------------------------------------------- atomic writes


@contextlib.contextmanager
def atomic_open(path: PathLike, mode: Literal["wb", "w"] = "wb", *, encoding: str = "utf-8",
                newline: str | None = "") -> Iterator[IO[Any]]:
    """Open a file for writing that only replaces `path` when the block ends without error.

    Writes go to a temporary file in the same directory (so the final rename stays on one
    file system); on success it is flushed, fsynced and moved over `path` with os.replace
    (atomic on POSIX and Windows). On any exception the temporary file is removed, `path`
    is left as it was and the exception propagates. mode is "wb" (bytes) or "w" (text;
    `newline=""` by default so "\\n" is written as is on every platform).

    Example: ``with atomic_open("mesh.ply") as f: mesh.export(f, file_type="ply")``.
    """
    if mode not in ("wb", "w"):
        raise ValueError(f"atomic_open mode must be 'wb' or 'w', got {mode!r}")
    path = Path(path)
    directory = path.parent
    try:
        # Keep the permissions of a file we replace; a new file gets the umask's default.
        keep_mode: int | None = stat.S_IMODE(os.stat(path).st_mode)
    except FileNotFoundError:
        keep_mode = None
    _remove_stale_temps(directory, path.name)
    try:
        tmp, fd = _create_temp(directory, path.name)
    except OSError as exc:
        raise _about(exc, path) from None
    try:
        kwargs: dict[str, Any] = {} if mode == "wb" else {"encoding": encoding,
                                                          "newline": newline}
        with os.fdopen(fd, mode, **kwargs) as handle:
            yield handle
            handle.flush()
            os.fsync(handle.fileno())
        if keep_mode is not None:
            os.chmod(tmp, keep_mode)
        try:
            os.replace(tmp, path)
        except OSError as exc:
            raise _about(exc, path) from None
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise
    _fsync_directory(directory)


def require_folder(path: PathLike) -> Path:
    """`path` as a Path, or SweepeditError where the folder it would be written in does
    not exist: for the checks before long work, so that none is done for a file that
    cannot be written."""
    path = Path(path)
    if not path.parent.is_dir():
        raise SweepeditError(f"{path}: {_missing_folder(path)}")
    return path


def _missing_folder(path: Path) -> str:
    """Why `path` cannot be written when its folder is missing, in a user's words."""
    return f"the folder {path.parent} does not exist"


def _about(exc: OSError, path: Path) -> OSError:
    """The same OS error, naming the file the caller asked for instead of the hidden
    temporary file (a missing folder or a folder in the way would otherwise be reported
    against '.name.1234abcd.tmp'), and a missing folder by name rather than as "No such
    file or directory"."""
    if exc.errno is None:
        return exc
    reason = exc.strerror
    if isinstance(exc, FileNotFoundError) and not path.parent.is_dir():
        reason = _missing_folder(path)
    return type(exc)(exc.errno, reason, str(path))


def _create_temp(directory: Path, name: str) -> tuple[Path, int]:
    # Not tempfile.mkstemp: it creates mode 0600, and the saved file would keep it. The
    # writer's process id in the name tells a later writer whether it is still alive.
    flags = os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_BINARY", 0)
    for _ in range(100):
        tmp = directory / f".{name}.{os.getpid()}.{secrets.token_hex(6)}.tmp"
        try:
            return tmp, os.open(tmp, flags, 0o666)
        except FileExistsError:
            continue
    raise FileExistsError(f"could not create a temporary file next to {directory / name}")


def _remove_stale_temps(directory: Path, name: str) -> None:
    """Remove the temporary files of `name` left by writers that were killed mid-write
    (SIGKILL, a power cut: no `except` ran), recognised by our naming and a process id
    that no longer exists. Best effort, POSIX only (Windows has no harmless liveness
    probe); another live writer's file is never touched."""
    if os.name != "posix":
        return
    pattern = re.compile(rf"\.{re.escape(name)}\.(\d+)\.[0-9a-f]{{12}}\.tmp")
    with contextlib.suppress(OSError), os.scandir(directory) as entries:
        for entry in entries:
            match = pattern.fullmatch(entry.name)
            if match and not _process_exists(int(match.group(1))):
                with contextlib.suppress(OSError):
                    os.unlink(entry.path)


def _process_exists(pid: int) -> bool:
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)  # signal 0: only asks whether the process exists
    except ProcessLookupError:
        return False
    except OSError:  # it exists but is not ours, or we cannot tell: keep its file
        return True
    return True


def _fsync_directory(directory: Path) -> None:
    # Makes the rename itself durable; not possible on every platform (Windows), so best effort.
    with contextlib.suppress(OSError):
        fd = os.open(directory, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


def atomic_write_bytes(path: PathLike, data: bytes) -> None:
    """Replace `path` with `data` atomically: the old content or the new, never a mixture."""
    with atomic_open(path, "wb") as handle:
        handle.write(data)


def atomic_write_text(path: PathLike, text: str, encoding: str = "utf-8") -> None:
    """Replace `path` with `text` atomically. The text is encoded before the file is touched."""
    atomic_write_bytes(path, text.encode(encoding))


# --------------------------------------------------------------------------- dispatch


def read_abstraction(path: PathLike) -> Abstraction:
    """Read a .json (sweepedit) or .txt (official SweepNet) parameter file, validated.

    Raises FileFormatError for anything wrong with the file's content (naming the file and,
    where it applies, the primitive, the field and the line); OSError if it cannot be read.
    """
    kind = _kind(path)
    try:
        if kind == "json":
            return _read_json(path)
        return read_official_txt(path, n_control_points=None)
    except FileFormatError:
        raise
    except InvalidPrimitiveError as e:
        raise e.in_file(path) from e
    except (ValueError, KeyError, IndexError, OverflowError, RecursionError) as e:
        # Content the checks above did not foresee (e.g. an integer of 5,000 digits, which
        # Python's int parser refuses): still a problem of this file, reported as one.
        raise FileFormatError(path, f"cannot read the parameter file ({type(e).__name__}: "
                              f"{' '.join(str(e).split())[:200]})") from e


def write_abstraction(abstraction: Abstraction, path: PathLike) -> None:
    """Write `abstraction` to a .json or .txt file (by extension), atomically.

    Primitives are validated first (InvalidPrimitiveError), so no file is ever written that
    could not be read back. FileFormatError if the extension is unknown or the official
    format cannot hold the abstraction.
    """
    kind = _kind(path)
    if kind == "txt":
        write_official_txt(abstraction, path)
        return
    abstraction.validate()
    atomic_write_text(path, dumps_abstraction(abstraction))


def is_parameter_file(path: PathLike) -> bool:
    """Parameters (.json, official .txt) rather than a shape. A .txt may also be a point
    cloud: official rows hold 14+ numbers, point rows 3 (or 6 with normals)."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix == ".txt":
        try:
            with path.open("r", encoding="utf-8", errors="replace") as f:
                for line in f:
                    tokens = line.replace(",", " ").split()
                    if tokens and not line.lstrip().startswith("#"):
                        return len(tokens) > 6
        except OSError:
            return True  # let the parameter reader report it
        return True
    return suffix == ".json"


def _kind(path: PathLike) -> Literal["json", "txt"]:
    suffix = Path(path).suffix.lower()
    if suffix == ".json":
        return "json"
    if suffix == ".txt":
        return "txt"
    raise FileFormatError(path, f"unknown parameter file extension {suffix or '(none)'!r}: "
                          "use .json (sweepedit) or .txt (official SweepNet)")


# --------------------------------------------------------------------------- JSON


def dumps_abstraction(abstraction: Abstraction) -> str:
    """The JSON text of `abstraction` (UTF-8 ready, ends with a newline); no validation."""
    text = json.dumps(_plain_json(abstraction_to_json(abstraction)), indent=2,
                      ensure_ascii=False, allow_nan=False, default=_json_default)
    return _compact_number_lists(text) + "\n"


def _plain_json(value: Any) -> Any:
    """value with numpy scalars and arrays as plain numbers and lists, and non-finite
    numbers (a fit record's NaN score, say) as null: json would write bare NaN, which
    is not JSON and which other readers and schema tools refuse."""
    if isinstance(value, dict):
        return {k: _plain_json(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_plain_json(v) for v in value]
    if isinstance(value, np.ndarray):
        return _plain_json(value.tolist())
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def _json_default(value: Any) -> Any:
    # What _plain_json leaves: paths (fit records and extras carry them) as strings.
    if isinstance(value, os.PathLike):
        return os.fspath(value)
    raise TypeError(f"cannot store a {type(value).__name__} in a parameter file: {value!r}")


# An indented list of plain numbers; a raw newline never occurs inside a JSON string, so this
# only ever matches structure. "[\n  1.0,\n  2.0\n]" -> "[1.0, 2.0]" (a point per line).
_NUMBER_LIST_RE = re.compile(r"\[\n[ ]*(-?[0-9][0-9.eE+-]*(?:,\n[ ]*-?[0-9][0-9.eE+-]*)*)\n[ ]*\]")


def _compact_number_lists(text: str) -> str:
    return _NUMBER_LIST_RE.sub(
        lambda m: "[" + ", ".join(part.strip() for part in m.group(1).split(",")) + "]", text)


def abstraction_to_json(abstraction: Abstraction) -> dict[str, Any]:
    """The JSON document of `abstraction` as plain Python data (a fresh, deep copy).

    Key order: format, version, normalization, source, primitives, fit, then unknown keys.
    Floats are stored unrounded (Python writes the shortest repr that reads back exactly).
    """
    extras = dict(abstraction.extras)
    norm_extras = _nested_extras(extras.pop("normalization", None), "normalization")
    norm = abstraction.normalization
    normalization: dict[str, Any] = {"center": [float(v) for v in norm.center],
                                     "scale": float(norm.scale)}
    normalization.update(_unknown_only(norm_extras, NORMALIZATION_KEYS))
    doc: dict[str, Any] = {
        "format": FORMAT_NAME,
        "version": FORMAT_VERSION,
        "normalization": normalization,
        "source": copy.deepcopy(abstraction.source),
        "primitives": [_primitive_to_json(p) for p in abstraction.primitives],
        "fit": copy.deepcopy(abstraction.fit),
    }
    doc.update(_unknown_only(extras, TOP_KEYS))
    return doc


def _primitive_to_json(p: SweepPrimitive) -> dict[str, Any]:
    extras = dict(p.extras)
    profile_extras = _nested_extras(extras.pop("profile", None), "profile")
    profile: dict[str, Any] = {"a": float(p.a), "b": float(p.b), "degree": float(p.degree)}
    profile.update(_unknown_only(profile_extras, PROFILE_KEYS))
    out: dict[str, Any] = {
        "control_points": np.asarray(p.control_points, dtype=np.float64).tolist(),
        "profile": profile,
        "scaling": [float(s) for s in p.scaling],
        "name": p.name,
        "color": p.color,
        "visible": bool(p.visible),
        "locked": bool(p.locked),
    }
    out.update(_unknown_only(extras, PRIMITIVE_KEYS))
    return out


def _nested_extras(value: Any, key: str) -> dict[str, Any]:
    if value is None:
        return {}
    if not isinstance(value, Mapping):
        raise TypeError(f"extras[{key!r}] holds the unknown keys inside {key!r} and must be a "
                        f"dict, got {type(value).__name__}")
    return dict(value)


def _unknown_only(extras: Mapping[str, Any], known: tuple[str, ...]) -> dict[str, Any]:
    # An extra that shadows a known key must never override the model's own value.
    return {k: copy.deepcopy(v) for k, v in extras.items() if k not in known}


def _read_json(path: PathLike) -> Abstraction:
    raw = Path(path).read_bytes()
    try:
        text = raw.decode("utf-8-sig")  # tolerate a BOM some editors add
    except UnicodeDecodeError as e:
        raise FileFormatError(path, f"not UTF-8 text (byte {e.start}): not a JSON "
                              "parameter file") from e
    if not text.strip():
        raise FileFormatError(path, "the file is empty")
    try:
        data = json.loads(text)
    except json.JSONDecodeError as e:
        if not text[e.pos:].strip():
            raise FileFormatError(path, f"the JSON ends unexpectedly at line {e.lineno}, "
                                  f"column {e.colno} (truncated file?): {e.msg}") from e
        raise FileFormatError(path, f"malformed JSON at line {e.lineno}, column {e.colno}: "
                              f"{e.msg}") from e
    except RecursionError as e:
        raise FileFormatError(path, "malformed JSON: nested too deeply") from e
    return abstraction_from_json(data, path)


def abstraction_from_json(data: dict[str, Any], path_for_errors: PathLike = "<json>"
                          ) -> Abstraction:
    """Build and validate an Abstraction from a parsed JSON document.

    path_for_errors: the file name that FileFormatError messages report.
    """
    return _JsonReader(path_for_errors).abstraction(data)


class _JsonReader:
    """Checks a parsed document piece by piece; every error names file, primitive and field."""

    def __init__(self, path: PathLike) -> None:
        self.path = path

    def error(self, detail: str, primitive: int | None = None,
              field: str | None = None) -> FileFormatError:
        # InvalidPrimitiveError composes "primitive i, field 'f': detail" the same way for all.
        return InvalidPrimitiveError(detail, primitive=primitive, field=field).in_file(self.path)

    def abstraction(self, data: Any) -> Abstraction:
        if not isinstance(data, dict):
            raise self.error(f"the top level must be a JSON object, got {_describe(data)}")
        self._check_header(data)
        normalization, norm_extras = self._normalization(data.get("normalization"))
        source = self._optional_object(data, "source")
        fit = self._optional_object(data, "fit")
        if "primitives" not in data:
            raise self.error("missing key 'primitives'", field="primitives")
        items = data["primitives"]
        if not isinstance(items, list):
            raise self.error(f"expected a list, got {_describe(items)}", field="primitives")
        if len(items) > MAX_PRIMITIVES:
            raise self.error(f"{len(items):,} primitives; sweepedit reads at most "
                             f"{MAX_PRIMITIVES:,} from one file", field="primitives")
        primitives = [self.primitive(item, i) for i, item in enumerate(items)]
        extras = {k: v for k, v in data.items() if k not in TOP_KEYS}
        if norm_extras:
            extras["normalization"] = norm_extras
        return Abstraction(primitives=primitives, normalization=normalization, source=source,
                           fit=fit, extras=extras)

    def _check_header(self, data: dict[str, Any]) -> None:
        fmt = data.get("format")
        if fmt != FORMAT_NAME:
            found = "no 'format' key" if "format" not in data else f"'format' is {fmt!r}"
            raise self.error(f"not a sweepedit abstraction file: {found}, expected "
                             f"{FORMAT_NAME!r}", field="format")
        if "version" not in data:
            raise self.error("missing key 'version'", field="version")
        version = data["version"]
        if not isinstance(version, int) or isinstance(version, bool) or version < 1:
            raise self.error(f"expected a positive integer version, got {_describe(version)}",
                             field="version")
        if version > FORMAT_VERSION:
            raise self.error(f"the file has format version {version}, written by a newer "
                             f"sweepedit; this sweepedit reads version {FORMAT_VERSION} only "
                             "(update sweepedit to open it)", field="version")

    def _optional_object(self, data: dict[str, Any], key: str) -> dict[str, Any] | None:
        value = data.get(key)
        if value is not None and not isinstance(value, dict):
            raise self.error(f"expected an object or null, got {_describe(value)}", field=key)
        return value

    def _normalization(self, value: Any) -> tuple[Normalization, dict[str, Any]]:
        if value is None:
            return Normalization(), {}
        if not isinstance(value, dict):
            raise self.error(f"expected an object, got {_describe(value)}",
                             field="normalization")
        center = self.vector(value.get("center", [0.0, 0.0, 0.0]), 3, None,
                             "normalization.center")
        scale = self.number(value.get("scale", 1.0), None, "normalization.scale")
        try:
            normalization = Normalization(center=center, scale=scale)
        except InvalidPrimitiveError as e:
            raise e.in_file(self.path) from e
        return normalization, {k: v for k, v in value.items() if k not in NORMALIZATION_KEYS}

    def primitive(self, item: Any, index: int) -> SweepPrimitive:
        if not isinstance(item, dict):
            raise self.error(f"expected an object, got {_describe(item)}", index)
        points = self.required(item, "control_points", index, "control_points")
        if not isinstance(points, list):
            raise self.error(f"expected a list of [x, y, z] points, got {_describe(points)}",
                             index, "control_points")
        if len(points) > MAX_CONTROL_POINTS:
            raise self.error(f"{len(points):,} control points; a primitive may have at most "
                             f"{MAX_CONTROL_POINTS}", index, "control_points")
        control_points = [self.vector(p, 3, index, f"control_points[{j}]")
                          for j, p in enumerate(points)]
        profile = self.required(item, "profile", index, "profile")
        if not isinstance(profile, dict):
            raise self.error(f"expected an object {{a, b, degree}}, got {_describe(profile)}",
                             index, "profile")
        a, b, degree = (self.number(self.required(profile, k, index, f"profile.{k}"), index,
                                    f"profile.{k}") for k in PROFILE_KEYS)
        scaling = item.get("scaling", [])  # [] is f(t) = 1
        if not isinstance(scaling, list):
            raise self.error(f"expected a list [s1, ..., sk], got {_describe(scaling)}",
                             index, "scaling")
        if len(scaling) > MAX_SCALING_TERMS:
            raise self.error(f"{len(scaling):,} scaling terms; a primitive may have at most "
                             f"{MAX_SCALING_TERMS}", index, "scaling")
        coefficients = [self.number(s, index, f"scaling[{i}]") for i, s in enumerate(scaling)]
        name = item.get("name", default_name(index))
        if not isinstance(name, str):
            raise self.error(f"expected a string, got {_describe(name)}", index, "name")
        color = item.get("color", palette_color(index))
        if not isinstance(color, str) or not _COLOR_RE.fullmatch(color):
            raise self.error(f"expected a colour '#rrggbb', got {_describe(color)}",
                             index, "color")
        visible = self.boolean(item.get("visible", True), index, "visible")
        locked = self.boolean(item.get("locked", False), index, "locked")
        extras = {k: v for k, v in item.items() if k not in PRIMITIVE_KEYS}
        profile_extras = {k: v for k, v in profile.items() if k not in PROFILE_KEYS}
        if profile_extras:
            extras["profile"] = profile_extras
        primitive = SweepPrimitive(
            control_points=np.array(control_points, dtype=np.float64).reshape(-1, 3),
            a=a, b=b, degree=degree, scaling=tuple(coefficients), name=name, color=color,
            visible=visible, locked=locked, extras=extras)
        try:
            primitive.validate(index)
        except InvalidPrimitiveError as e:
            raise e.in_file(self.path) from e
        return primitive

    def required(self, obj: dict[str, Any], key: str, index: int | None, field: str) -> Any:
        if key not in obj:
            raise self.error(f"missing key {key!r}", index, field)
        return obj[key]

    def number(self, value: Any, index: int | None, field: str) -> float:
        # bool is an int in Python but never a number in a parameter file.
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise self.error(f"expected a number, got {_describe(value)}", index, field)
        try:
            return float(value)
        except OverflowError as e:
            raise self.error("number too large", index, field) from e

    def vector(self, value: Any, size: int, index: int | None, field: str) -> list[float]:
        if not isinstance(value, list) or len(value) != size:
            raise self.error(f"expected a list of {size} numbers, got {_describe(value)}",
                             index, field)
        return [self.number(v, index, f"{field}[{i}]") for i, v in enumerate(value)]

    def boolean(self, value: Any, index: int, field: str) -> bool:
        if not isinstance(value, bool):
            raise self.error(f"expected true or false, got {_describe(value)}", index, field)
        return value


def _describe(value: Any) -> str:
    """'a string "abc"', 'null', 'a list of 2 items' ... for error messages."""
    if value is None:
        return "null"
    if isinstance(value, bool):
        return f"the boolean {'true' if value else 'false'}"
    if isinstance(value, str):
        shown = value if len(value) <= 40 else value[:37] + "..."
        return f"a string {json.dumps(shown, ensure_ascii=False)}"
    if isinstance(value, int | float):
        return f"the number {value!r}"
    if isinstance(value, list):
        return f"a list of {len(value)} item{'s' * (len(value) != 1)}"
    if isinstance(value, dict):
        return "an object"
    return type(value).__name__


# --------------------------------------------------------------------------- official text


def official_columns(n_control_points: int) -> int:
    """Numbers per row of the official format: 3n control-point coordinates, a, b, d, 2 scaling."""
    return 3 * n_control_points + 3 + _OFFICIAL_SCALING_COLUMNS


def read_official_txt(path: PathLike, n_control_points: int | None = None) -> Abstraction:
    """Read an official SweepNet primitive_parameters.txt file, validated.

    Row layout: c1..cn (3n), a, b, d, s_quad, s_lin; note s_quad (the t^2 coefficient) comes
    first, so `scaling = (s_lin, s_quad)`. n_control_points=None infers n from the column
    count of the first row (3n + 5: 14 columns -> 3); an int requires exactly 3n + 5.
    Blank lines and '#' comments are skipped. Normalisation is the identity; names and
    colours are the defaults ("primitive i", palette_color(i)).
    """
    if n_control_points is not None and n_control_points < MIN_CONTROL_POINTS:
        raise ValueError(f"n_control_points must be >= {MIN_CONTROL_POINTS}, "
                         f"got {n_control_points}")
    try:
        text = Path(path).read_bytes().decode("utf-8")
    except UnicodeDecodeError as e:
        raise FileFormatError(path, f"not a text file (byte {e.start} is not UTF-8)") from e

    rows: list[tuple[int, np.ndarray]] = []
    expected = None if n_control_points is None else official_columns(n_control_points)
    first_line = 0
    for lineno, line in enumerate(text.splitlines(), start=1):
        content = line.split("#", 1)[0].strip()
        if not content:
            continue
        if len(rows) == MAX_PRIMITIVES:
            raise FileFormatError(path, f"line {lineno}: more than {MAX_PRIMITIVES:,} primitive "
                                  "rows; sweepedit reads at most that many from one file")
        values = _parse_row(path, lineno, content.split(), len(rows))
        if values.size > official_columns(MAX_CONTROL_POINTS):
            raise FileFormatError(path, f"line {lineno}: {values.size:,} numbers, more than "
                                  f"{MAX_CONTROL_POINTS} control points' worth")
        if expected is None:
            if values.size < official_columns(MIN_CONTROL_POINTS) or (values.size - 5) % 3:
                raise FileFormatError(path, f"line {lineno}: {values.size} numbers; a row "
                                      "holds 3n + 5 numbers for n >= 3 control points (14 "
                                      "for n = 3)")
            expected, first_line = values.size, lineno
        elif values.size != expected:
            why = (f"line {first_line} has {expected}" if n_control_points is None else
                   f"{n_control_points} control points need {expected}")
            raise FileFormatError(path, f"line {lineno}: {values.size} numbers, expected "
                                  f"{expected} ({why})")
        rows.append((lineno, values))
    if not rows:
        raise FileFormatError(path, "the file is empty: no primitive rows")

    assert expected is not None
    n = (expected - 5) // 3
    primitives = []
    for index, (lineno, row) in enumerate(rows):
        primitive = SweepPrimitive(
            control_points=row[:3 * n].reshape(n, 3),
            a=row[3 * n], b=row[3 * n + 1], degree=row[3 * n + 2],
            scaling=(row[3 * n + 4], row[3 * n + 3]),  # (s_lin, s_quad) -> (s1, s2)
            name=default_name(index), color=palette_color(index))
        try:
            primitive.validate(index)
        except InvalidPrimitiveError as e:
            raise FileFormatError(path, f"line {lineno}, {e}", primitive=e.primitive,
                                  field=e.field) from e
        primitives.append(primitive)
    return Abstraction(primitives=primitives)


def _official_field(column: int, n_columns: int) -> str | None:
    """The field that 0-based `column` of an official row of `n_columns` numbers holds
    (names as in the JSON format and in validation errors), or None if the row has a
    column count no n gives."""
    if n_columns < official_columns(MIN_CONTROL_POINTS) or (n_columns - 5) % 3:
        return None
    n = (n_columns - 5) // 3
    if column < 3 * n:
        return f"control_points[{column // 3}]"
    return ("profile.a", "profile.b", "profile.degree", "scaling[1]",
            "scaling[0]")[column - 3 * n]


def _parse_row(path: PathLike, lineno: int, tokens: list[str], index: int) -> np.ndarray:
    """The numbers of one row (the index-th primitive); errors name line, column, and the
    primitive and field where the row's length tells them."""
    values = np.empty(len(tokens))
    for column, token in enumerate(tokens, start=1):
        try:
            value = float(token)
            problem = None if math.isfinite(value) else "is not a finite number"
        except ValueError:
            problem = "is not a number"
        if problem:
            field = _official_field(column - 1, len(tokens))
            where = f", {primitive_label(index)}, field '{field}'" if field else ""
            raise FileFormatError(path, f"line {lineno}, column {column}{where}: {token!r} "
                                  f"{problem}", primitive=index if field else None,
                                  field=field)
        values[column - 1] = value
    return values


def write_official_txt(abstraction: Abstraction, path: PathLike) -> None:
    """Write the official SweepNet text format (full precision, '%.18e'), atomically.

    Only geometry is stored. FileFormatError (before anything is written) when the format
    cannot hold the abstraction: no primitives, control-point counts that differ between
    primitives, or a scaling polynomial of degree > 2 (trailing zero coefficients are fine;
    fewer than 2 coefficients are padded with zeros). InvalidPrimitiveError if a primitive
    is invalid.
    """
    abstraction.validate()
    primitives = abstraction.primitives
    if not primitives:
        raise FileFormatError(path, "the official format cannot hold an abstraction without "
                              "primitives (an empty file is not readable)")
    n = primitives[0].n_control_points
    rows = []
    for index, p in enumerate(primitives):
        if p.n_control_points != n:
            raise FileFormatError(
                path, f"the official format needs the same number of control points in every "
                f"row: {primitive_label(0)} has {n}, {primitive_label(index)} has "
                f"{p.n_control_points}",
                primitive=index, field="control_points")
        scaling = list(p.scaling)
        while len(scaling) > _OFFICIAL_SCALING_COLUMNS and scaling[-1] == 0.0:
            scaling.pop()  # a zero top coefficient loses nothing
        if len(scaling) > _OFFICIAL_SCALING_COLUMNS:
            raise FileFormatError(
                path, f"{primitive_label(index)}, field 'scaling': the official format holds a "
                f"scaling polynomial of degree <= 2 (s_lin, s_quad), this one has degree "
                f"{len(scaling)}; "
                "save as .json instead", primitive=index, field="scaling")
        s1, s2 = [*scaling, 0.0, 0.0][:2]
        rows.append(np.concatenate([p.control_points.reshape(-1), [p.a, p.b, p.degree, s2, s1]]))
    buffer = io.StringIO()
    np.savetxt(buffer, np.array(rows), fmt=_OFFICIAL_FMT, delimiter=" ")
    atomic_write_text(path, buffer.getvalue())
