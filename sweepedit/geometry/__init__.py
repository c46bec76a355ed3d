"""Sweep primitives: the data model, the sweep math, the mesher and the exact inside test.

No Qt and no torch-only code here: sweep.py is written against the array API so that
the fitting code can run the same math in torch.
"""

from sweepedit.geometry.inside import grid_points, inside_primitive, inside_primitives, inside_union
from sweepedit.geometry.mesher import TriangleMesh, sweep_mesh, sweep_meshes, union_mesh
from sweepedit.geometry.model import Abstraction, Normalization, SweepPrimitive, palette_color
from sweepedit.geometry.solid import abstraction_union, solid_mesh, solid_union

__all__ = [
    "Abstraction", "Normalization", "SweepPrimitive", "TriangleMesh", "abstraction_union",
    "grid_points", "inside_primitive", "inside_primitives", "inside_union", "palette_color",
    "solid_mesh", "solid_union", "sweep_mesh", "sweep_meshes", "union_mesh",
]
