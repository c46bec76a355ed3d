"""Loading shapes (meshes, voxel grids, point clouds) into one normalised `Shape`.

Formats (by extension):

- meshes: .obj .ply .stl .off .glb .gltf (trimesh readers). Vertices are merged by
  position, so OBJ files split at texture seams get their topology back; scenes are
  flattened with their transforms; a mesh that is inside-out as a whole is turned outward.
  An .obj/.stl/.off without faces is an error (a .ply or glTF without faces is a point
  cloud).
- voxel grids: .binvox, .npy, .npz (a 3D array of any resolution; bool, integer != 0 or
  float > 0.5 is occupied). Each occupied voxel is a cube; the surface is the marching-cubes
  surface of the grid (grids above MAX_VOXEL_RESOLUTION per side are first max-pooled).
- point clouds: .ply (or glTF) with vertices only, .xyz / .pts / .txt text ("x y z ..."
  per line, commas allowed, blank lines and '#' comments skipped, a lone count on the
  first line allowed); occupancy by the morphological method of
  `sweepedit.io.occupancy.PointCloudInside` (read its limits).

Every shape is normalised (bounding-box centre to the origin, longest side to 1) and
everything in a `Shape` lives in that frame. The grids and the fitting samples are
computed eagerly by `load_shape`, not lazily: one winding-number pass serves both, and
every consumer (fitting, metrics, skeleton, the app) needs them at once. That is 0.3-1 s
for the benchmark meshes and ~3-5 s for 1.3M faces on 2 cores; `surface_samples` is
computed on demand.

Every problem with the input file is raised as `FileFormatError(path, message)`; a
file that reads but gives a fit nothing to do (flat, a line, fewer than MIN_POINTS points,
an open sheet or specks that enclose fewer than MIN_INSIDE_CELLS cells of the grid) as
its subclass `DegenerateShapeError`. Headers are checked against the file's size before a
reader runs (sweepedit.io.headers), so a header claiming 10^12 faces allocates nothing.
"""

from __future__ import annotations

import hashlib
import io
import math
import re
import struct
import zipfile
import zlib
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np
import trimesh

from sweepedit.errors import DegenerateShapeError, FileFormatError
from sweepedit.geometry.model import Normalization
from sweepedit.io import occupancy as occ
from sweepedit.io.headers import (
    MAX_VOXEL_CELLS,
    STL_HEADER,
    STL_TRIANGLE,
    check_claimed_sizes,
    is_binary_stl,
    stl_triangles,
)

ShapeKind = Literal["mesh", "voxels", "points"]

MESH_EXTENSIONS = (".obj", ".ply", ".stl", ".off", ".glb", ".gltf")
VOXEL_EXTENSIONS = (".binvox", ".npy", ".npz")
POINT_EXTENSIONS = (".xyz", ".pts", ".txt")
SUPPORTED_EXTENSIONS = MESH_EXTENSIONS + VOXEL_EXTENSIONS + POINT_EXTENSIONS
MAX_VOXEL_RESOLUTION = 256
# Keys tried first, in order, when an .npz file holds several arrays.
NPZ_KEYS = ("occupancy", "voxels", "voxel", "grid", "data", "arr_0")
# A point cloud needs this many points to describe a solid at all.
MIN_POINTS = 10
# Cells of the grid (winding test at the centres) a shape must enclose to be fitted: the
# fit needs an inside whose boundary it can sample (a sheet, a line or specks have none).
MIN_INSIDE_CELLS = 2
# Points within this share of the shape's size of one plane (or line) are flat (a line).
FLAT_TOLERANCE = 1e-6
# Winding number that a cell centre must pass for an open mesh to enclose it firmly.
FIRM_WINDING = 0.75
# Exceptions that our own code raises on the unusual arrays a bad file produces; they are
# reported against the file. Anything else is a bug and propagates as it is.
_DATA_ERRORS = (ValueError, KeyError, IndexError, struct.error, UnicodeDecodeError, EOFError,
                zipfile.BadZipFile, zlib.error, OverflowError, np.linalg.LinAlgError)


@dataclass
class Shape:
    """A loaded shape in the normalised frame (docs/parameter-format.md).

    path: the file; kind: "mesh" | "voxels" | "points"; sha256: of the file's bytes.
    normalization: original = normalised * scale + center.
    surface: the normalised surface mesh (the input mesh; for voxels the marching-cubes
        surface; for point clouds a surface reconstructed from the grid, for display).
    cloud: (P, 3) normalised input points for point clouds, else None.
    occupancy: (R, R, R) bool fitting grid over [-0.5, 0.5]^3, indexed [ix, iy, iz], cell
        centres at (i + 0.5) / R - 0.5; includes thin parts (see sweepedit.io.occupancy).
    winding_occupancy: (R, R, R) bool, inside test at the cell centres only (IoU protocol).
    samples: occupancy-labelled fitting points (points (N, 3) float32, labels (N,) float32).
    """

    path: Path
    kind: ShapeKind
    normalization: Normalization
    surface: trimesh.Trimesh
    occupancy: np.ndarray
    winding_occupancy: np.ndarray
    samples: occ.OccupancySamples
    cloud: np.ndarray | None = None
    sha256: str = ""
    _inside: occ.InsideTest | None = field(default=None, repr=False)

    @property
    def resolution(self) -> int:
        return int(self.occupancy.shape[0])

    @property
    def name(self) -> str:
        return self.path.stem

    @property
    def n_components(self) -> int:
        """Connected components of the surface mesh (faces joined along shared edges)."""
        faces = np.arange(len(self.surface.faces))
        return len(trimesh.graph.connected_components(self.surface.face_adjacency,
                                                      nodes=faces, min_len=1))

    @property
    def mesh(self) -> trimesh.Trimesh:
        """The normalised surface mesh (an alias of `surface`)."""
        return self.surface

    def inside(self, points: np.ndarray) -> np.ndarray:
        """(N,) bool: exact inside test of (N, 3) normalised points (|winding| > 0.5 of
        the surface; the morphological test for point clouds)."""
        if self._inside is not None:
            return self._inside(points)
        return occ.mesh_inside(self.surface, points)

    def surface_samples(self, n: int = 100_000, seed: int = 0) -> np.ndarray:
        """(n, 3) float64 area-uniform samples of the surface (normalised frame).

        For point clouds, n of the input points (with replacement if there are fewer).
        """
        if self.cloud is not None:
            rng = np.random.default_rng(seed)
            idx = rng.choice(self.cloud.shape[0], n, replace=self.cloud.shape[0] < n)
            return self.cloud[idx].copy()
        points, _ = trimesh.sample.sample_surface(self.surface, n, seed=seed)
        return np.asarray(points, dtype=np.float64)

    def shell_samples(self, n: int, offset: float, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
        """Pairs of points `offset` (normalised units) to either side of n area-uniform
        surface samples along the surface's normal, labelled by the inside test:
        points (2n, 3) float64 and labels (2n,) bool. A boundary that passes between a
        pair lies within `offset` of the surface there. Point clouds have no normals to
        offset along: (0, 3) and (0,) for them."""
        if self.cloud is not None or n <= 0:
            return np.zeros((0, 3)), np.zeros(0, dtype=bool)
        points, faces = trimesh.sample.sample_surface(self.surface, n, seed=seed)
        normals = np.asarray(self.surface.face_normals[faces], dtype=np.float64)
        # Not clipped to the cube: a pair at a face of the box would collapse onto it.
        pairs = np.concatenate([points + offset * normals, points - offset * normals])
        return pairs, np.asarray(self.inside(pairs), dtype=bool)


def load_shape(path: str | Path, resolution: int = occ.DEFAULT_RESOLUTION,
               n_samples: int = occ.DEFAULT_SAMPLES, seed: int = 0) -> Shape:
    """Read, normalise and voxelise a shape file; see the module docstring for formats.

    resolution: R of the R^3 grids; n_samples: fitting samples; seed: for all sampling.
    Raises FileFormatError naming the file for any unreadable or unusable input.
    """
    path = Path(path)
    _check_options(resolution, n_samples)
    ext = path.suffix.lower()
    if ext not in SUPPORTED_EXTENSIONS:
        raise FileFormatError(path, f"unknown file type '{path.suffix or '(none)'}'; "
                                    f"supported: {' '.join(SUPPORTED_EXTENSIONS)}")
    if not path.exists():
        raise FileFormatError(path, "no such file")
    if not path.is_file():
        raise FileFormatError(path, "not a regular file")
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise FileFormatError(path, f"cannot read the file ({exc.strerror or exc})") from exc
    if len(data.strip()) == 0:
        raise FileFormatError(path, "the file is empty")
    digest = hashlib.sha256(data).hexdigest()
    check_claimed_sizes(path, ext, data)
    repaired = _repaired_mesh_bytes(path, ext, data)
    del data

    def read() -> Shape:
        if ext in VOXEL_EXTENSIONS:
            grid, lower, upper = _read_voxels(path, ext)
            return _shape_from_voxels(path, grid, lower, upper, resolution, n_samples, seed)
        if ext in POINT_EXTENSIONS:
            return _shape_from_points(path, _read_point_text(path), resolution, n_samples,
                                      seed)
        vertices, faces, points = _read_mesh(path, ext, repaired)
        if faces is not None:
            return _shape_from_mesh(path, vertices, faces, resolution, n_samples, seed)
        return _shape_from_points(path, points, resolution, n_samples, seed)

    return _finished(_built(path, read, f"cannot read the {ext} file"), digest)


def mesh_shape(vertices: np.ndarray, faces: np.ndarray, *, name: str = "mesh",
               resolution: int = occ.DEFAULT_RESOLUTION, n_samples: int = occ.DEFAULT_SAMPLES,
               seed: int = 0) -> Shape:
    """A shape from a triangle mesh in memory: vertices (V, 3), faces (F, 3) integer
    indices into them. Treated exactly as a mesh file (merged, normalised, voxelised);
    `name` stands for the file in messages and as `Shape.name`."""
    path = Path(name)
    vertices = _array(path, vertices, "vertices", np.float64)
    faces = _array(path, faces, "faces", np.int64)
    return _in_memory(path, (vertices, faces), lambda: _shape_from_mesh(
        path, vertices, faces, resolution, n_samples, seed), resolution, n_samples)


def points_shape(points: np.ndarray, *, name: str = "points",
                 resolution: int = occ.DEFAULT_RESOLUTION, n_samples: int = occ.DEFAULT_SAMPLES,
                 seed: int = 0) -> Shape:
    """A shape from (P, 3) points in memory, treated as a point-cloud file."""
    path = Path(name)
    points = _array(path, points, "points", np.float64)
    return _in_memory(path, (points,), lambda: _shape_from_points(
        path, points, resolution, n_samples, seed), resolution, n_samples)


def voxels_shape(grid: np.ndarray, *, name: str = "voxels",
                 resolution: int = occ.DEFAULT_RESOLUTION, n_samples: int = occ.DEFAULT_SAMPLES,
                 seed: int = 0) -> Shape:
    """A shape from an (X, Y, Z) voxel array in memory ([ix, iy, iz]; bool, integer != 0
    or float > 0.5 is occupied), treated as a .npy file: each voxel a unit cube."""
    path = Path(name)
    occupied = _voxel_grid(path, np.asarray(grid))
    return _in_memory(path, (occupied,), lambda: _shape_from_voxels(
        path, occupied, np.zeros(3), np.array(occupied.shape, dtype=np.float64), resolution,
        n_samples, seed), resolution, n_samples)


def _array(path: Path, value: object, what: str, dtype: type) -> np.ndarray:
    """value as an (N, 3) array of dtype, or FileFormatError naming `path`."""
    try:
        array = np.asarray(value)
        if array.ndim != 2 or array.shape[1] != 3:
            raise ValueError(f"{what} must be an (N, 3) array, got shape {array.shape}")
        if dtype is np.int64 and array.size and not np.issubdtype(array.dtype, np.integer):
            raise ValueError(f"{what} must be integer indices, got {array.dtype}")
        return array.astype(dtype, copy=False)
    except (TypeError, ValueError) as exc:
        raise FileFormatError(path, str(exc)) from None


def _in_memory(path: Path, arrays: tuple[np.ndarray, ...], build: Callable[[], Shape],
               resolution: int, n_samples: int) -> Shape:
    """Run build() as load_shape runs a reader: its data errors name `path`; the shape's
    sha256 is of the arrays' bytes."""
    _check_options(resolution, n_samples)
    shape = _built(path, build, "cannot use the data")
    digest = hashlib.sha256()
    for array in arrays:
        digest.update(np.ascontiguousarray(array).tobytes())
    return _finished(shape, digest.hexdigest())


def _check_options(resolution: int, n_samples: int) -> None:
    if resolution < 4:
        raise ValueError(f"resolution must be at least 4, got {resolution}")
    if n_samples < 1:
        raise ValueError(f"n_samples must be positive, got {n_samples}")


def _built(path: Path, build: Callable[[], Shape], failure: str) -> Shape:
    """build(), with the errors our own code raises on unusual data reported against
    `path` as `failure` and the exception; anything else is a bug and propagates."""
    try:
        return build()
    except FileFormatError:
        raise
    except MemoryError:
        raise FileFormatError(path, "not enough memory to load it") from None
    except _DATA_ERRORS as exc:
        raise FileFormatError(path, f"{failure} ({type(exc).__name__}: "
                                    f"{_short(exc)})") from exc


def _finished(shape: Shape, digest: str) -> Shape:
    """The shape with its digest, once it is known to have something to fit."""
    shape.sha256 = digest
    check_fittable(shape)
    return shape


def _short(exc: BaseException, limit: int = 200) -> str:
    text = " ".join(str(exc).split())
    return text if len(text) <= limit else text[: limit - 3] + "..."


def check_fittable(shape: Shape) -> None:
    """Raise DegenerateShapeError (naming the file) if the shape encloses fewer than
    MIN_INSIDE_CELLS cells of its grid: the fit would have nothing to do. `load_shape`
    calls it, and so does the fit for shapes made otherwise; it costs a count."""
    inside = int(np.count_nonzero(shape.winding_occupancy))
    if inside >= MIN_INSIDE_CELLS:
        return
    if shape.kind == "points":
        why = "the points enclose no volume: an open or sparsely sampled scan?"
    elif shape.kind == "voxels":
        why = "its voxels are thinner than a cell of the grid"
    elif not shape.surface.is_watertight and shape.n_components == 1:
        why = "it is an open surface, a sheet that encloses nothing"
    elif shape.n_components > 1:
        why = f"it is {shape.n_components} disjoint pieces, each thinner than a cell"
    else:
        why = "all of it is thinner than a cell of the grid"
    raise DegenerateShapeError(
        shape.path, f"degenerate shape: {inside} of the {shape.resolution}^3 grid cells lie "
                    f"inside it ({why}); there is nothing to fit")


# --------------------------------------------------------------------------- readers


def _repaired_mesh_bytes(path: Path, ext: str, data: bytes) -> bytes | None:
    """The bytes of a mesh file that trimesh would misread, repaired (an OBJ's relative
    face indices, a binary STL's short triangle count); None when it reads them right."""
    try:
        if ext == ".obj":
            return _absolute_obj_indices(data)
        if ext == ".stl":
            return _stl_full_count(data)
    except ValueError as exc:
        raise FileFormatError(path, f"cannot read the {ext} file ({type(exc).__name__}: "
                                    f"{_short(exc)})") from exc
    return None


def _read_mesh(path: Path, ext: str, repaired: bytes | None = None,
               ) -> tuple[np.ndarray, np.ndarray | None, np.ndarray]:
    """(V, 3) vertices and (F, 3) faces of all meshes in the file (scene transforms
    applied), or (P, 3) points and faces None for a PLY point cloud. repaired: the
    file's bytes to read instead (_repaired_mesh_bytes)."""
    try:
        if repaired is not None:
            scene = trimesh.load_scene(io.BytesIO(repaired), file_type=ext[1:], process=False)
        else:
            scene = trimesh.load_scene(str(path), file_type=ext[1:], process=False)
    except MemoryError:
        raise FileFormatError(path, "not enough memory to load it") from None
    except Exception as exc:  # trimesh's readers raise anything on a malformed file
        if ext == ".ply" and "unexpected length" in str(exc):
            # The header's sizes pass headers' lower bound but the lists need more.
            raise FileFormatError(path, "the file ends before the data its header "
                                        "announces (truncated?)") from exc
        raise FileFormatError(path, f"cannot read the {ext} file ({type(exc).__name__}: "
                                    f"{_short(exc)})") from exc
    vertex_blocks, face_blocks, point_blocks = [], [], []
    offset = 0
    for node in scene.graph.nodes_geometry:
        transform, geometry_name = scene.graph[node]
        geometry = scene.geometry.get(geometry_name)
        vertices = np.asarray(getattr(geometry, "vertices", np.zeros((0, 3))), dtype=np.float64)
        if vertices.size == 0:
            continue
        vertices = trimesh.transform_points(vertices.reshape(-1, 3), transform)
        faces = np.asarray(getattr(geometry, "faces", np.zeros((0, 3))), dtype=np.int64)
        if isinstance(geometry, trimesh.Trimesh) and faces.size > 0:
            vertex_blocks.append(vertices)
            face_blocks.append(faces.reshape(-1, 3) + offset)
            offset += vertices.shape[0]
        else:
            point_blocks.append(vertices)
    if face_blocks:
        return np.concatenate(vertex_blocks), np.concatenate(face_blocks), np.zeros((0, 3))
    if point_blocks and ext in (".ply", ".glb", ".gltf"):  # formats that hold point clouds
        return np.zeros((0, 3)), None, np.concatenate(point_blocks)
    if point_blocks:
        raise FileFormatError(path, "the mesh has vertices but no faces")
    raise FileFormatError(path, "no geometry found (empty or truncated file?)")


def _stl_full_count(data: bytes) -> bytes | None:
    """A binary STL whose header counts fewer triangles than it holds whole, with the
    count made right; else None. trimesh trusts the count, finds the size disagrees and
    reads nothing (a file of 12 good triangles was "no geometry"). A count larger than
    the file holds is refused before this (headers.check_claimed_sizes)."""
    if not is_binary_stl(data):
        return None
    claimed, held = stl_triangles(data)
    if claimed >= held or len(data) != STL_HEADER + STL_TRIANGLE * held:
        return None
    return data[:80] + struct.pack("<I", held) + data[STL_HEADER:]


_RELATIVE_FACE = re.compile(rb"^[ \t]*f[ \t][^\n]*?(?<=[\s/])-\d", re.MULTILINE)


def _absolute_obj_indices(data: bytes) -> bytes | None:
    """The OBJ text `data` with its relative (negative) face indices made absolute, or None
    when it has none. In OBJ, -1 is the last vertex (texture coordinate, normal) defined
    *before* the face; trimesh counts it from the end of the file instead, which loads a
    different shape without a word."""
    if not _RELATIVE_FACE.search(data):
        return None
    counts = {b"v": 0, b"vt": 0, b"vn": 0}
    kinds = (b"v", b"vt", b"vn")
    out = []
    for number, line in enumerate(data.splitlines(), start=1):
        head, _, rest = line.strip().partition(b" ")
        if head in counts:
            counts[head] += 1
        elif head == b"f" and b"-" in rest:
            corners = []
            for corner in rest.split():
                parts = corner.split(b"/")
                for i, part in enumerate(parts[:3]):
                    if part.startswith(b"-"):
                        index = counts[kinds[i]] + int(part) + 1
                        if index < 1:
                            raise ValueError(f"line {number}: face index {int(part)} reaches "
                                             f"before the {counts[kinds[i]]} "
                                             f"{kinds[i].decode()} lines above it")
                        parts[i] = str(index).encode()
                corners.append(b"/".join(parts))
            line = b"f " + b" ".join(corners)
        out.append(line)
    return b"\n".join(out) + b"\n"


def _read_point_text(path: Path) -> np.ndarray:
    """(P, 3) points of an XYZ/PTS text file (extra columns such as normals ignored)."""
    try:
        text = path.read_text(encoding="utf-8", errors="strict")
    except UnicodeDecodeError as exc:
        raise FileFormatError(path, "not a text point file (binary data)") from exc
    lines = [line.split("#", 1)[0].replace(",", " ").replace(";", " ") for line in
             text.splitlines()]
    data = [(n, line) for n, line in enumerate(lines, start=1) if line.strip()]
    if data and len(data[0][1].split()) == 1 and data[0][1].strip().isdigit():
        data = data[1:]  # the PTS point count
    if not data:
        raise FileFormatError(path, "no points in the file")
    try:  # fast path: C parser
        points = np.loadtxt([line for _, line in data], usecols=(0, 1, 2), ndmin=2,
                            dtype=np.float64)
    except ValueError:
        points = None
    if points is None or points.shape[0] != len(data):
        for number, line in data:  # slow path, only to say which line is wrong
            tokens = line.split()
            if len(tokens) < 3:
                raise FileFormatError(path, f"line {number}: expected 'x y z', got "
                                            f"{line.strip()[:60]!r}")
            try:
                [float(t) for t in tokens[:3]]
            except ValueError as exc:
                raise FileFormatError(path, f"line {number}: not a number in "
                                            f"{line.strip()[:60]!r}") from exc
        raise FileFormatError(path, "unreadable point rows")
    return points


def _read_voxels(path: Path, ext: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(X, Y, Z) bool grid [ix, iy, iz] and the (3,) lower / upper corners of the box
    that its cells tile, in the file's coordinates (voxel index units for .npy/.npz)."""
    if ext == ".binvox":
        return _read_binvox(path)
    try:
        loaded = np.load(path, allow_pickle=False)
    except Exception as exc:
        raise FileFormatError(path, f"not a readable NumPy {ext} file ({exc})") from exc
    if isinstance(loaded, np.lib.npyio.NpzFile):
        with loaded:
            keys = list(loaded.files)
            if not keys:
                raise FileFormatError(path, "the .npz archive holds no arrays")
            try:  # members are read (and decompressed) only now
                key = next((k for k in NPZ_KEYS if k in keys), None)
                if key is None:
                    key = next((k for k in keys if np.ndim(loaded[k]) >= 3), keys[0])
                array = loaded[key]
            except (*_DATA_ERRORS, OSError) as exc:
                raise FileFormatError(path, f"a damaged .npz archive ({type(exc).__name__}: "
                                            f"{_short(exc)})") from exc
    else:
        array = loaded
    grid = _voxel_grid(path, np.asarray(array))
    return grid, np.zeros(3), np.array(grid.shape, dtype=np.float64)


def _voxel_grid(path: Path, array: np.ndarray) -> np.ndarray:
    """An array read as voxels -> (X, Y, Z) bool occupancy (leading axes of size 1
    dropped), or FileFormatError naming `path`."""
    while array.ndim > 3 and array.shape[0] == 1:
        array = array[0]
    if array.ndim != 3:
        raise FileFormatError(path, f"expected a 3D voxel array, got shape {array.shape}")
    if array.dtype == bool:
        grid = array
    elif np.issubdtype(array.dtype, np.integer):
        grid = array != 0
    elif np.issubdtype(array.dtype, np.floating):
        if not np.all(np.isfinite(array)):
            raise FileFormatError(path, "the voxel array holds NaN or infinite values")
        grid = array > 0.5
    else:
        raise FileFormatError(path, f"unsupported voxel dtype {array.dtype}")
    return grid


def _read_binvox(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """binvox (https://www.patrickmin.com/binvox/binvox.html): run-length (value, count)
    bytes, y fastest, then z, then x. Cells tile translate + [0, scale]^3."""
    raw = path.read_bytes()
    header: dict[str, list[str]] = {}
    pos = 0
    lines = 0
    while True:
        end = raw.find(b"\n", pos)
        if end < 0 or lines > 16:
            raise FileFormatError(path, "truncated binvox header (no 'data' line)")
        line = raw[pos:end].decode("ascii", errors="replace").strip()
        pos = end + 1
        lines += 1
        if lines == 1:
            if not line.startswith("#binvox"):
                raise FileFormatError(path, "not a binvox file (no '#binvox' header)")
            continue
        if line == "data":
            break
        parts = line.split()
        if parts:
            header[parts[0]] = parts[1:]
    try:
        dims = tuple(int(v) for v in header["dim"])
        translate = np.array([float(v) for v in header.get("translate", ["0", "0", "0"])])
        scale = float(header.get("scale", ["1"])[0])
    except KeyError as exc:
        raise FileFormatError(path, f"bad binvox header (no {exc} line)") from exc
    except ValueError as exc:
        raise FileFormatError(path, f"bad binvox header ({exc})") from exc
    if (len(dims) != 3 or min(dims) < 1 or translate.shape != (3,)
            or not np.all(np.isfinite(translate)) or not 0 < scale < math.inf):
        raise FileFormatError(path, "bad binvox header (dim, translate or scale)")
    expected = math.prod(dims)
    if expected > MAX_VOXEL_CELLS:
        raise FileFormatError(path, f"the binvox grid {'x'.join(map(str, dims))} has "
                                    f"{expected:,} cells; at most {MAX_VOXEL_CELLS:,} are read")
    body = np.frombuffer(raw, dtype=np.uint8, offset=pos)
    if body.size % 2:
        body = body[:-1]
    values, counts = body[0::2], body[1::2].astype(np.int64)
    ends = np.cumsum(counts)
    total = int(ends[-1]) if ends.size else 0
    if total < expected:
        raise FileFormatError(path, f"truncated binvox data ({total} of {expected} voxels)")
    runs = int(np.searchsorted(ends, expected)) + 1  # runs past the grid are ignored
    flat = np.repeat(values[:runs] > 0, counts[:runs])[:expected]
    grid = flat.reshape(dims).transpose(0, 2, 1)  # stored [x, z, y] -> [x, y, z]
    lower = translate
    upper = translate + scale * np.array(grid.shape) / max(grid.shape)
    return np.ascontiguousarray(grid), lower, upper


# --------------------------------------------------------------------------- builders


def _check_finite(path: Path, array: np.ndarray, what: str) -> None:
    if array.size and not np.all(np.isfinite(array)):
        bad = int(np.count_nonzero(~np.all(np.isfinite(array.reshape(-1, 3)), axis=1)))
        noun = what if bad != 1 else what.removesuffix("s")
        raise FileFormatError(path, f"{bad} {noun} {'has' if bad == 1 else 'have'} NaN or "
                                    "infinite coordinates")


def _normalization(path: Path, points: np.ndarray) -> Normalization:
    """Box centre to the origin, longest side to 1; DegenerateShapeError for a single
    point, or a shape too small for its distance from the origin to keep its digits."""
    lower, upper = points.min(axis=0), points.max(axis=0)
    _check_size(path, points)
    _check_precision(path, points)
    return Normalization.from_bounds(lower, upper)


def _check_size(path: Path, points: np.ndarray) -> None:
    """FileFormatError if the (P, 3) finite points span more than float64 can hold."""
    with np.errstate(over="ignore"):
        extent = float(np.max(points.max(axis=0) - points.min(axis=0)))
    if not math.isfinite(extent):
        raise FileFormatError(path, "coordinates too large: the shape's size overflows "
                                    f"(they reach {float(np.max(np.abs(points))):.3g})")


def _check_precision(path: Path, points: np.ndarray) -> None:
    """DegenerateShapeError if the (P, 3) points span no more than ~1000 steps of float64
    at their distance from the origin (a point, or rounding noise far out)."""
    with np.errstate(over="ignore"):
        extent = float(np.max(points.max(axis=0) - points.min(axis=0)))
    if extent == 0.0:
        raise DegenerateShapeError(path, "degenerate shape: all of it lies at one point")
    far = float(np.max(np.abs(points)))
    if extent < 1e3 * np.spacing(far):
        raise DegenerateShapeError(path, f"degenerate shape: it is {extent:.3g} across but "
                                         f"lies {far:.3g} from the origin, where coordinates "
                                         "are too coarse to describe it")


def _check_not_flat(path: Path, points: np.ndarray, what: str) -> None:
    """DegenerateShapeError if the (P, 3) points lie on one line or in one plane, within
    FLAT_TOLERANCE of their extent (a flat mesh or scan encloses no volume)."""
    centred = points - points.mean(axis=0)
    # Principal directions; the extent along each is measured on the points themselves
    # (projections keep full precision where the squared covariance would not).
    _, axes = np.linalg.eigh(centred.T @ centred)
    extents = np.ptp(centred @ axes, axis=0)  # ascending variance: thinnest first
    size = float(extents.max())
    if extents[1] <= FLAT_TOLERANCE * size:
        raise DegenerateShapeError(path, f"degenerate shape: all {what} lie on one line; it "
                                         "encloses no volume")
    if extents[0] <= FLAT_TOLERANCE * size:
        raise DegenerateShapeError(path, f"degenerate shape: all {what} lie in one plane (a "
                                         "flat shape encloses no volume)")


def _conditioning(points: np.ndarray) -> tuple[np.ndarray, float] | None:
    """(3,) shift and factor (a power of two) that bring the (P, 3) points to about unit
    size at the origin, `(points - shift) * factor`, when they are far from that; None
    for shapes of ordinary size and place, which are left exactly as read (so their
    results do not change).

    trimesh merges vertices by rounding them to 1e-8 and drops faces lower than that
    (absolute tolerances, int64 keys): a shape 1e-12 across collapses to a point and one
    1e12 from the origin overflows the keys.
    """
    lower, upper = points.min(axis=0), points.max(axis=0)
    extent = float(np.max(upper - lower))
    far = float(np.max(np.abs(points)))
    if not 0.0 < extent < math.inf or (2.0**-10 <= extent <= 2.0**20 and far <= 2.0**30):
        return None
    return (lower + upper) / 2.0, math.ldexp(1.0, -math.floor(math.log2(extent)))


def _check_encloses_volume(path: Path, grids: occ.Voxelization) -> None:
    """DegenerateShapeError if an open mesh bounds nothing: its winding number passes
    0.5 near a curved sheet (it jumps by 1 across it), but stays below FIRM_WINDING;
    inside a closed mesh it is 1, near a small hole little less."""
    number = grids.winding_number
    if number is None or np.count_nonzero(grids.winding_occupancy) < MIN_INSIDE_CELLS:
        return  # too few cells inside at all: check_fittable says why
    if np.count_nonzero(number > FIRM_WINDING) < MIN_INSIDE_CELLS:
        raise DegenerateShapeError(path, "degenerate shape: it is an open surface, a sheet "
                                         "that encloses no volume (its winding number stays "
                                         f"below {FIRM_WINDING}); there is nothing to fit")


def _shape_from_mesh(path: Path, vertices: np.ndarray, faces: np.ndarray, resolution: int,
                     n_samples: int, seed: int) -> Shape:
    if faces.size == 0:
        raise FileFormatError(path, "the mesh has no faces")
    if faces.min() < 0 or faces.max() >= vertices.shape[0]:
        raise FileFormatError(path, "faces refer to vertices that do not exist")
    used = np.zeros(vertices.shape[0], dtype=bool)
    used[faces.ravel()] = True  # unreferenced vertices may hold anything
    _check_finite(path, vertices[used], "vertices")
    _check_size(path, vertices[used])
    _check_precision(path, vertices[used])
    conditioning = _conditioning(vertices[used])
    shift, factor = conditioning or (np.zeros(3), 1.0)
    if conditioning is not None:
        vertices = (vertices - shift) * factor
    # Merging by position restores the topology of meshes split at texture seams.
    mesh = trimesh.Trimesh(vertices, faces, process=True, validate=False)
    mesh.update_faces(mesh.nondegenerate_faces())
    mesh.remove_unreferenced_vertices()
    if len(mesh.faces) == 0 or mesh.area <= 0:
        raise DegenerateShapeError(path, "degenerate shape: the mesh has no faces of "
                                         "non-zero area")
    # Scans and exports often mix face orientations, and the winding number then cancels
    # inside (spot with half its faces flipped kept 40 % of its volume): the faces are
    # turned to agree across each connected surface first, when they do not (~0.7 s for
    # 23k faces; the check alone is a few ms).
    if not mesh.is_winding_consistent:
        trimesh.repair.fix_winding(mesh)
    _check_not_flat(path, mesh.vertices, "its vertices")
    conditioned = _normalization(path, mesh.vertices)
    mesh.vertices = conditioned.to_normalized(mesh.vertices)
    normalization = Normalization(center=conditioned.center / factor + shift,
                                  scale=conditioned.scale / factor)
    # An inside-out mesh is turned outward (renderers and normals want that); the inside
    # test uses |winding number| anyway, which also covers single inside-out components.
    if occ.signed_volume(mesh) < 0:
        mesh.invert()
    grids, samples = occ.voxelize_mesh(mesh, resolution, n_samples, seed)
    _check_occupancy(path, grids.occupancy)
    _check_encloses_volume(path, grids)
    return Shape(path=path, kind="mesh", normalization=normalization, surface=mesh,
                 occupancy=grids.occupancy, winding_occupancy=grids.winding_occupancy,
                 samples=samples)


def _shape_from_voxels(path: Path, grid: np.ndarray, lower: np.ndarray, upper: np.ndarray,
                       resolution: int, n_samples: int, seed: int) -> Shape:
    if not grid.any():
        raise FileFormatError(path, "the voxel grid is empty (no occupied voxel)")
    grid, lower, upper = _pool_voxels(grid, lower, upper)
    # Crop to the occupied cells: their cubes' box is the shape's bounding box.
    nz = np.argwhere(grid)
    lo_i, hi_i = nz.min(axis=0), nz.max(axis=0) + 1
    step = (upper - lower) / np.array(grid.shape)
    grid = grid[lo_i[0]:hi_i[0], lo_i[1]:hi_i[1], lo_i[2]:hi_i[2]]
    box_lo, box_hi = lower + lo_i * step, lower + hi_i * step
    normalization = Normalization.from_bounds(box_lo, box_hi)
    surface = occ.grid_surface(grid, normalization.to_normalized(box_lo),
                               normalization.to_normalized(box_hi))
    grids, samples = occ.voxelize_mesh(surface, resolution, n_samples, seed)
    _check_occupancy(path, grids.occupancy)
    return Shape(path=path, kind="voxels", normalization=normalization, surface=surface,
                 occupancy=grids.occupancy, winding_occupancy=grids.winding_occupancy,
                 samples=samples)


def _pool_voxels(grid: np.ndarray, lower: np.ndarray,
                 upper: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Max-pool grids finer than MAX_VOXEL_RESOLUTION (keeps thin parts; the growth is at
    most one pooled cell, a quarter of a fitting cell)."""
    factor = int(np.ceil(max(grid.shape) / MAX_VOXEL_RESOLUTION))
    if factor <= 1:
        return grid, lower, upper
    shape = np.array(grid.shape)
    padded_shape = -(-shape // factor) * factor
    padded = np.zeros(padded_shape, dtype=bool)
    padded[: shape[0], : shape[1], : shape[2]] = grid
    pooled = padded.reshape(padded_shape[0] // factor, factor, padded_shape[1] // factor,
                            factor, padded_shape[2] // factor, factor).any(axis=(1, 3, 5))
    step = (upper - lower) / shape
    return pooled, lower, lower + padded_shape * step


def _shape_from_points(path: Path, points: np.ndarray, resolution: int, n_samples: int,
                       seed: int) -> Shape:
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if points.shape[0] == 0:
        raise FileFormatError(path, "the point cloud has no points")
    _check_finite(path, points, "points")
    if points.shape[0] < MIN_POINTS:
        raise DegenerateShapeError(path, f"degenerate shape: {points.shape[0]} points are "
                                         f"too few for a solid (at least {MIN_POINTS})")
    normalization = _normalization(path, points)
    cloud = normalization.to_normalized(points)
    _check_not_flat(path, cloud, "its points")
    grids, samples, inside = occ.voxelize_points(cloud, resolution, n_samples, seed)
    _check_occupancy(path, grids.occupancy)
    surface = occ.grid_surface(grids.winding_occupancy if grids.winding_occupancy.any()
                               else grids.occupancy,
                               np.full(3, -0.5), np.full(3, 0.5), smooth=0.7)
    return Shape(path=path, kind="points", normalization=normalization, surface=surface,
                 occupancy=grids.occupancy, winding_occupancy=grids.winding_occupancy,
                 samples=samples, cloud=cloud, _inside=inside)


def _check_occupancy(path: Path, grid: np.ndarray) -> None:
    if not grid.any():
        raise FileFormatError(path, "the shape encloses no volume on the grid")
