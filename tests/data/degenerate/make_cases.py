"""Writes the degenerate-shape corpus of this folder (run from anywhere; deterministic).

What each file must give is in cases.json beside it; tests/test_degenerate.py checks it.
The files are committed: this script documents how they were made and remakes them.
"""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
H = 1.0 / 64  # a cell of the default fitting grid, in the normalised frame

BOX_CORNERS = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], float)
# Outward triangles of the unit cube on BOX_CORNERS (index = 4x + 2y + z).
BOX_FACES = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                      [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]])
TETRA = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], float)
TETRA_FACES = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])


def box(lower, upper) -> tuple[np.ndarray, np.ndarray]:
    lower, upper = np.asarray(lower, float), np.asarray(upper, float)
    return lower + BOX_CORNERS * (upper - lower), BOX_FACES.copy()


def write_off(name: str, vertices: np.ndarray, faces: np.ndarray, fmt: str = "%.17g") -> None:
    lines = ["OFF", f"{len(vertices)} {len(faces)} 0"]
    lines += [" ".join(fmt % v for v in row) for row in vertices]
    lines += [" ".join(str(i) for i in [len(f), *f]) for f in faces]
    (HERE / name).write_text("\n".join(lines) + "\n")


def write_obj(name: str, vertices: np.ndarray, faces: np.ndarray) -> None:
    lines = [f"v {x:.9g} {y:.9g} {z:.9g}" for x, y, z in vertices]
    lines += ["f " + " ".join(str(i + 1) for i in f) for f in faces]
    (HERE / name).write_text("\n".join(lines) + "\n")


def write_stl(name: str, vertices: np.ndarray, faces: np.ndarray) -> None:
    """Binary STL (float32, as every STL)."""
    out = bytearray(b"sweepedit degenerate corpus".ljust(80, b" "))
    out += struct.pack("<I", len(faces))
    for f in faces:
        tri = vertices[f]
        normal = np.cross(tri[1] - tri[0], tri[2] - tri[0])
        normal /= max(np.linalg.norm(normal), 1e-30)
        out += struct.pack("<12fH", *normal, *tri.ravel(), 0)
    (HERE / name).write_bytes(bytes(out))


def write_xyz(name: str, points: np.ndarray) -> None:
    (HERE / name).write_text("\n".join(" ".join(f"{v:.17g}" for v in p) for p in points) + "\n")


def merge(*parts: tuple[np.ndarray, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    vertices, faces, offset = [], [], 0
    for v, f in parts:
        vertices.append(v)
        faces.append(f + offset)
        offset += len(v)
    return np.concatenate(vertices), np.concatenate(faces)


def main() -> None:
    rng = np.random.default_rng(18)
    write_off("single_triangle.off", np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], float),
              np.array([[0, 1, 2]]))

    # A 5 x 5 grid of vertices on a tilted plane, as quads.
    u, v = np.meshgrid(np.linspace(0, 1, 5), np.linspace(0, 1, 5), indexing="ij")
    e1, e2 = np.array([1.0, 0.2, 0.3]), np.array([-0.1, 1.0, 0.5])
    grid = u.reshape(-1, 1) * e1 + v.reshape(-1, 1) * e2 + np.array([2.0, -1.0, 0.5])
    quads = [[5 * i + j, 5 * (i + 1) + j, 5 * (i + 1) + j + 1, 5 * i + j + 1]
             for i in range(4) for j in range(4)]
    (HERE / "flat_mesh.obj").write_text(
        "\n".join(f"v {x:.17g} {y:.17g} {z:.17g}" for x, y, z in grid) + "\n"
        + "\n".join("f " + " ".join(str(i + 1) for i in q) for q in quads) + "\n")

    t = np.linspace(0, 1, 40)[:, None]
    write_xyz("line_of_points.xyz", np.array([0.5, -2.0, 3.0]) + t * np.array([1.0, 2.0, -0.5]))
    write_xyz("seven_points.xyz", rng.normal(size=(7, 3)))

    cloud = rng.normal(size=(40, 3))
    cloud /= np.linalg.norm(cloud, axis=1, keepdims=True)
    text = "\n".join(" ".join(f"{v:.9g}" for v in p) for p in cloud).splitlines()
    text[5] = "0.1 nan 0.3"
    text[17] = "inf 0.2 0.1"
    (HERE / "nan_points.xyz").write_text("\n".join(text) + "\n")

    # A closed needle 1 x 0.002 x 0.002 on an axis: no cell centre lies inside it.
    write_stl("needle.stl", *box([-0.5, -0.001, -0.001], [0.5, 0.001, 0.001]))

    # A cube 0.9 cells wide around the cell centre of the (+,+,+) corner, and a speck (a
    # tetrahedron 0.3 cells wide, holding no centre) at the opposite corner: normalising
    # leaves them in place and one cell lies inside.
    cube = box([0.5 - 0.9 * H] * 3, [0.5] * 3)
    speck = (TETRA * 0.3 * H - 0.5, TETRA_FACES.copy())
    write_off("one_voxel.off", *merge(cube, speck))

    # Boxes 1 x 0.6 x 0.4, far larger, far smaller and far from the origin.
    lower, upper = np.array([-0.5, -0.3, -0.2]), np.array([0.5, 0.3, 0.2])
    write_off("huge_box.off", *box(3e12 + 1e12 * lower, 3e12 + 1e12 * upper))
    write_off("tiny_box.off", *box(-2e-12 + 1e-12 * lower, -2e-12 + 1e-12 * upper))
    write_off("far_box.off", *box(1e12 + lower, 1e12 + upper))
    # 1e-6 across at 1e12 from the origin: float64 steps there are 1.2e-4.
    write_off("far_speck.off", *box(1e12 + 1e-6 * lower, 1e12 + 1e-6 * upper))

    # An open, gently waving sheet (a height field): it bounds no volume.
    n = 12
    x, y = np.meshgrid(np.linspace(-0.5, 0.5, n), np.linspace(-0.5, 0.5, n), indexing="ij")
    z = 0.08 * np.sin(2 * np.pi * x) * np.cos(np.pi * y)
    sheet = np.stack([x, y, z], axis=-1).reshape(-1, 3)
    tris = []
    for i in range(n - 1):
        for j in range(n - 1):
            a, b, c, d = n * i + j, n * (i + 1) + j, n * (i + 1) + j + 1, n * i + j + 1
            tris += [[a, b, c], [a, c, d]]
    write_obj("open_sheet.obj", sheet, np.array(tris))

    # Only faces of zero area: repeated vertices and collinear ones, some listed twice.
    v = np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0], [0, 1, 1], [0, 2, 2], [1, 1, 1]], float)
    write_off("zero_area_faces.off", v, np.array([[0, 1, 2], [0, 0, 1], [0, 3, 4], [0, 5, 5],
                                                  [0, 1, 2], [2, 1, 0]]))
    # One real triangle listed four times (both ways round) and zero-area faces.
    write_off("duplicate_faces.off", v, np.array([[0, 1, 3], [0, 1, 3], [3, 1, 0],
                                                  [0, 3, 1], [0, 1, 2], [3, 3, 3]]))

    # 150 tetrahedra 1/400 of the spread wide, scattered: specks, each far below a cell.
    specks = [(TETRA * 0.0025 + rng.uniform(-0.5, 0.5, 3), TETRA_FACES.copy())
              for _ in range(150)]
    write_stl("specks.stl", *merge(*specks))

    # A closed tetrahedron with every face twice: the winding number is 2 inside, the
    # solid is the tetrahedron.
    write_off("tetra_faces_twice.off", TETRA * 3.0 + 1.0,
              np.concatenate([TETRA_FACES, TETRA_FACES]))

    one = np.zeros((5, 6, 7), dtype=bool)
    one[2, 3, 4] = True
    np.save(HERE / "single_voxel.npy", one)


if __name__ == "__main__":
    main()
