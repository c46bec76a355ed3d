"""What a shape file's header claims, checked against what the file can hold.

Readers trust their headers: a PLY that claims 10^12 faces, an .npy whose shape is
(10^4, 10^4, 10^4) or an OFF with 10^12 vertices makes a reader allocate for them, fail
deep inside with a cryptic error or -- trimesh's ASCII PLY reader -- load whatever is
there as if nothing were amiss. These checks read only the header and count what the
rest of the file can hold (bytes for binary data, whitespace-separated values for text),
so such a file is a one-line FileFormatError before any reader allocates anything.

Each check is a lower bound on the size a file needs for its header to be true; a header
that passes may still be wrong in other ways, which the readers then report.
"""

from __future__ import annotations

import io
import math
import re
import struct
import zipfile
from pathlib import Path

import numpy as np

from sweepedit.errors import FileFormatError

# The largest voxel array read (cells): 1024^3 bool is 1 GiB, and pooling copies it once.
MAX_VOXEL_CELLS = 1024**3
# A header is this many bytes at most (PLY, binvox); a longer one is not a header.
MAX_HEADER_BYTES = 1 << 16

_PLY_SIZES = {"char": 1, "int8": 1, "uchar": 1, "uint8": 1, "short": 2, "int16": 2,
              "ushort": 2, "uint16": 2, "int": 4, "int32": 4, "uint": 4, "uint32": 4,
              "float": 4, "float32": 4, "double": 8, "float64": 8}


def check_claimed_sizes(path: Path, ext: str, data: bytes) -> None:
    """Raise FileFormatError if the header of `data` (the bytes of `path`, a file of
    extension `ext`) claims more elements than the file can hold; else return."""
    if ext == ".ply":
        _check_ply(path, data)
    elif ext == ".off":
        _check_off(path, data)
    elif ext == ".npy":
        _check_npy(path, io.BytesIO(data), len(data), "")
    elif ext == ".npz":
        _check_npz(path, data)
    elif ext == ".glb":
        _check_glb(path, data)
    elif ext == ".stl":
        _check_stl(path, data)


def _claims_too_much(path: Path, what: str, needed: int, holds: int, unit: str) -> None:
    if needed > holds:
        raise FileFormatError(path, f"the header claims {what}, which needs at least "
                                    f"{needed:,} {unit}, but the file holds {holds:,} "
                                    "(truncated or corrupt?)")


# --------------------------------------------------------------------------- PLY


def _check_ply(path: Path, data: bytes) -> None:
    end = data.find(b"end_header", 0, MAX_HEADER_BYTES)
    if data[:3].lower() != b"ply" or end < 0:
        return  # not a PLY header the reader could follow either: it says so itself
    body_start = data.find(b"\n", end)
    body = data[body_start + 1:] if body_start >= 0 else b""
    binary = False
    elements: list[tuple[str, int, int, int]] = []  # name, count, fixed bytes, values
    for raw in data[:end].split(b"\n")[1:]:
        words = raw.decode("ascii", errors="replace").split()
        if not words:
            continue
        if words[0] == "format" and len(words) > 1:
            binary = words[1].startswith("binary")
        elif words[0] == "element" and len(words) >= 3:
            count = _integer(path, words[2], f"element {words[1]}")
            elements.append((words[1], count, 0, 0))
        elif words[0] == "property" and elements and len(words) >= 3:
            name, count, size, values = elements[-1]
            type_name = words[2] if words[1] == "list" else words[1]
            # A list costs its count at least (it may be empty).
            elements[-1] = (name, count, size + _PLY_SIZES.get(type_name, 1), values + 1)
    claims = ", ".join(f"{name}: {count:,}" for name, count, _, _ in elements[:4])
    claims += ", ..." if len(elements) > 4 else ""
    if binary:
        needed = sum(count * size for _, count, size, _ in elements)
        _claims_too_much(path, claims, needed, len(body), "bytes of data")
    else:
        needed = sum(count * values for _, count, _, values in elements)
        _claims_too_much(path, claims, needed, count_tokens(body), "values")


_WHITESPACE = np.zeros(256, dtype=bool)
_WHITESPACE[list(b" \t\n\r\v\f")] = True
_TOKEN_CHUNK = 1 << 24


def count_tokens(data: bytes) -> int:
    """Whitespace-separated tokens in `data`, in chunks (no list of tokens, memory a few
    times the chunk)."""
    count = 0
    previous_space = True
    for start in range(0, len(data), _TOKEN_CHUNK):
        space = _WHITESPACE[np.frombuffer(data, np.uint8, min(_TOKEN_CHUNK, len(data) - start),
                                          start)]
        starts = ~space & np.concatenate([[previous_space], space[:-1]])
        count += int(np.count_nonzero(starts))
        previous_space = bool(space[-1])
    return count


def _integer(path: Path, word: str, what: str) -> int:
    try:
        value = int(word)
    except ValueError:
        raise FileFormatError(path, f"bad header: the count of {what} is {word[:20]!r}, "
                                    "not a whole number") from None
    if value < 0:
        raise FileFormatError(path, f"bad header: the count of {what} is negative ({value})")
    return value


# --------------------------------------------------------------------------- OFF

# Comments run from '#' to the end of the line; the counts follow the OFF keyword.
_OFF_COUNTS = re.compile(rb"\A\s*C?OFF\s+(-?\d+)\s+(-?\d+)")


def _check_off(path: Path, data: bytes) -> None:
    text = re.sub(rb"#[^\n]*", b"", data[:MAX_HEADER_BYTES])
    match = _OFF_COUNTS.match(text)
    if match is None:
        return  # the reader reports a missing or malformed count line
    vertices = _integer(path, match.group(1).decode(), "vertices")
    faces = _integer(path, match.group(2).decode(), "faces")
    # A vertex is 3 numbers, a face at least 4 ("3 i j k").
    needed = 3 * vertices + 4 * faces
    _claims_too_much(path, f"{vertices:,} vertices and {faces:,} faces", needed,
                     count_tokens(text[match.end():]) + count_tokens(data[MAX_HEADER_BYTES:]),
                     "numbers")


# --------------------------------------------------------------------------- NumPy


def _check_npy(path: Path, stream: io.IOBase, size: int, member: str) -> None:
    """`stream` at the start of an .npy of `size` bytes (a member of an .npz if named)."""
    where = f"array '{member}': " if member else ""
    try:
        version = np.lib.format.read_magic(stream)
        if version == (1, 0):
            shape, _, dtype = np.lib.format.read_array_header_1_0(stream)
        else:
            shape, _, dtype = np.lib.format.read_array_header_2_0(stream)
    except Exception as exc:  # numpy parses the header as Python literals: anything goes
        raise FileFormatError(path, f"{where}not a readable NumPy array header "
                                    f"({type(exc).__name__})") from None
    cells = math.prod(shape)
    if cells > MAX_VOXEL_CELLS:
        raise FileFormatError(path, f"{where}the array has shape {shape} ({cells:,} cells); "
                                    f"at most {MAX_VOXEL_CELLS:,} are read")
    if dtype.hasobject:  # np.load would refuse them too, in words about pickling
        raise FileFormatError(path, f"{where}the array holds Python objects (type {dtype}), "
                                    "which sweepedit never unpickles; save the voxels as "
                                    "booleans or numbers")
    _claims_too_much(path, f"{where}an array of shape {shape} and type {dtype}",
                     cells * dtype.itemsize, size - stream.tell(), "bytes")


def _check_npz(path: Path, data: bytes) -> None:
    try:
        with zipfile.ZipFile(io.BytesIO(data)) as archive:
            for info in archive.infolist():
                if not info.filename.endswith(".npy"):  # read as raw bytes, if at all
                    if info.file_size > MAX_VOXEL_CELLS:
                        raise FileFormatError(path, f"the archive member {info.filename!r} "
                                                    f"claims {info.file_size:,} bytes")
                    continue
                with archive.open(info) as member:
                    _check_npy(path, member, info.file_size, info.filename[:-4])
    except FileFormatError:
        raise
    except (zipfile.BadZipFile, zipfile.LargeZipFile, EOFError, OSError, ValueError,
            NotImplementedError) as exc:
        raise FileFormatError(path, f"not a readable .npz archive ({exc})") from None


# --------------------------------------------------------------------------- STL

STL_HEADER = 84  # 80 bytes of text, then the triangle count (uint32)
STL_TRIANGLE = 50  # normal, three corners (float32 each), 2 attribute bytes


def is_binary_stl(data: bytes) -> bool:
    """Whether `data` is a binary STL: an ASCII one starts with 'solid' and has facets
    (a binary header may start with 'solid' too, but holds no 'facet' text)."""
    head = data[:1024].lstrip().lower()
    return len(data) >= STL_HEADER and not (head.startswith(b"solid") and b"facet" in head)


def stl_triangles(data: bytes) -> tuple[int, int]:
    """(claimed, held): the triangles a binary STL's header claims and those its size holds."""
    claimed = struct.unpack_from("<I", data, 80)[0]
    return claimed, (len(data) - STL_HEADER) // STL_TRIANGLE


def _check_stl(path: Path, data: bytes) -> None:
    if not is_binary_stl(data):
        return
    claimed = stl_triangles(data)[0]
    _claims_too_much(path, f"{claimed:,} triangles", STL_HEADER + STL_TRIANGLE * claimed,
                     len(data), "bytes")


# --------------------------------------------------------------------------- GLB


def _check_glb(path: Path, data: bytes) -> None:
    """The binary glTF container: a 12-byte header (magic, version, total length), then
    chunks of (length, type, data); every length must lie within the file."""
    if len(data) < 12 or data[:4] != b"glTF":
        return  # the reader says what it is not
    offset = 12
    while offset + 8 <= len(data):
        length, kind = struct.unpack_from("<I4s", data, offset)
        name = kind.decode("ascii", errors="replace").strip("\x00 ")
        label = f"a {name} chunk" if name.isalnum() else "a chunk"
        _claims_too_much(path, f"{label} of {length:,} bytes at byte {offset:,}",
                         length, len(data) - offset - 8, "bytes")
        offset += 8 + length
