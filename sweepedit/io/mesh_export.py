"""Writing swept meshes to disk (OBJ, PLY, STL, GLB), atomically."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from sweepedit.errors import SweepeditError
from sweepedit.geometry.mesher import DISPLAY_PROFILE_POINTS, DISPLAY_STATIONS, TriangleMesh
from sweepedit.geometry.model import Abstraction, Normalization
from sweepedit.geometry.solid import solid_mesh, solid_union
from sweepedit.io.params import atomic_write_bytes, require_folder

if TYPE_CHECKING:
    import trimesh

MESH_FORMATS = (".obj", ".ply", ".stl", ".glb")


def mesh_format(path: str | Path) -> str:
    """The export format of a path by its extension, or a clear error."""
    suffix = Path(path).suffix.lower()
    if suffix not in MESH_FORMATS:
        raise SweepeditError(f"{path}: cannot write meshes as '{suffix or 'no extension'}'; "
                             f"use one of {', '.join(MESH_FORMATS)}")
    return suffix[1:]


def trimesh_of(mesh: TriangleMesh, color: str | None = None) -> trimesh.Trimesh:
    """The mesh as a trimesh.Trimesh, unprocessed, with its normals and, given a colour
    "#rrggbb", that colour on every face."""
    import trimesh

    out = trimesh.Trimesh(mesh.vertices, mesh.faces, vertex_normals=mesh.normals,
                          process=False)
    if color:
        rgb = [int(color[i:i + 2], 16) for i in (1, 3, 5)]
        out.visual.face_colors = np.tile([*rgb, 255], (len(mesh.faces), 1))
    return out


def write_mesh(mesh: TriangleMesh, path: str | Path, color: str | None = None) -> None:
    """Write one mesh atomically in the format its extension names."""
    fmt = mesh_format(path)
    data = trimesh_of(mesh, color).export(file_type=fmt)
    atomic_write_bytes(path, data.encode("utf-8") if isinstance(data, str) else data)


def in_frame(mesh: TriangleMesh, normalization: Normalization,
             original_frame: bool) -> TriangleMesh:
    """The mesh (normalised frame) mapped to the shape's original frame when asked."""
    if not original_frame:
        return mesh
    return TriangleMesh(normalization.to_original(mesh.vertices), mesh.faces, mesh.normals)


def export_abstraction(abstraction: Abstraction, path: str | Path, *, per_primitive: bool = False,
                       original_frame: bool = False, stations: int = DISPLAY_STATIONS,
                       profile_points: int = DISPLAY_PROFILE_POINTS) -> list[Path]:
    """Write the union of the primitives (or one file per primitive) and return the paths.

    Each file is the watertight mesh of the true solid (solid.py), also where a sweep
    folds onto itself; stations and profile_points are the least resolution (tight bends
    and sharp stars get more). Per-primitive files are named STEM_NN.EXT beside `path`,
    one per primitive in order.
    """
    path = require_folder(path)  # before the meshing, not after it
    mesh_format(path)
    if not abstraction.primitives:
        raise SweepeditError(f"{path}: the abstraction has no primitives to export")

    def framed(mesh: TriangleMesh) -> TriangleMesh:
        return in_frame(mesh, abstraction.normalization, original_frame)

    if not per_primitive:
        write_mesh(framed(solid_union(abstraction.primitives, stations, profile_points)), path)
        return [path]
    # Every mesh first, then the files: a primitive that fails to mesh leaves none behind.
    meshes = [framed(solid_mesh(p, stations, profile_points)) for p in abstraction.primitives]
    written = [path.with_name(f"{path.stem}_{i:02d}{path.suffix}") for i in range(len(meshes))]
    for mesh, out, prim in zip(meshes, written, abstraction.primitives, strict=True):
        write_mesh(mesh, out, color=prim.color)
    return written
