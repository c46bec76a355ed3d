"""The fitting grid: voxelisation, inside/outside tests and occupancy-labelled samples.

Everything here works in the normalised frame (docs/parameter-format.md): the shape fits the cube
[-0.5, 0.5]^3, which is cut into R^3 cells (R = 64 by default) of side h = 1/R. Cell (i, j, k)
has its centre at ((i, j, k) + 0.5) * h - 0.5 and grids are indexed [ix, iy, iz].

Two grids are made for every shape:

- the *winding* grid: a cell is inside when the generalised winding number of the surface at
  its centre is above 0.5 (|w| > 0.5, so inside-out meshes work as well). This is exactly the
  inside test of the IoU protocol (docs/quality.md).
- the *fitting* grid (`occupancy`): the winding grid plus thin-part voxels. A part thinner
  than a cell can hold no cell centre, so it would vanish from the winding grid (or survive
  as a dotted line) and neither the skeleton nor the fit would know it exists. The fitting
  grid therefore also marks (a) the cells that the surface passes through and that lie more
  than one cell away from every winding-inside cell (the vanished parts), and (b) the fewest
  surface cells that reconnect pieces of the winding grid which the surface itself connects
  (shortest paths through surface cells). Thick parts get no extra voxels: on the 30
  benchmark shapes the fitting grid adds nothing to 23 of them and at most 1.9% of the
  volume (octopus, ant). A thin part comes out one cell thick, about the thinnest sweep the
  parameter ranges allow (a >= 0.01 is a diameter of 1.3 cells at R = 64).

Sample labels always come from the exact inside test (the winding number), never from the
grid: the fitting loss then sees the true surface of thin parts.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import igl
import numpy as np
import scipy.ndimage as ndi
import trimesh
from scipy import sparse
from scipy.sparse import csgraph
from scipy.spatial import cKDTree

from sweepedit.geometry.arrays import as_array

DEFAULT_RESOLUTION = 64
DEFAULT_SAMPLES = 32_768
# Share of the fitting samples drawn near the surface, and how near (in cells).
NEAR_SURFACE_FRACTION = 0.8
NEAR_SURFACE_CELLS = 2.0
# Triangles with longer edges (normalised units, 2 cells at R = 64) are split before the
# fast winding number.
LONG_EDGE = 1.0 / 32.0
# Faces that splitting may make, at most (or twice the mesh's own): a few thousand faces
# that all span the shape would otherwise become millions, slower than not splitting.
SPLIT_FACE_BUDGET = 400_000
# A surface this large (normalised units; a unit cube has 6, the benchmark shapes at most
# 3.2) is a tangle of overlapping triangles, as a damaged file gives: the Barnes-Hut far
# field fails near all of it (a 1,236-face tangle took 30 s at 64^3) and summing every
# triangle exactly is far cheaper, up to EXACT_WINDING_BUDGET triangle-query pairs (~2 s).
TANGLE_AREA = 12.0
EXACT_WINDING_BUDGET = 400_000_000
# Surface samples per cell-face area used to find the cells that the surface passes through.
SURFACE_SAMPLES_PER_CELL_AREA = 8.0
MAX_SURFACE_SAMPLES = 2_000_000

# 26-connectivity, used for every component and adjacency test on the grid.
STRUCTURE_26 = np.ones((3, 3, 3), dtype=bool)
# One of each opposite pair of the 26 neighbour offsets (for undirected voxel graphs).
_HALF_OFFSETS = np.array(
    [(i, j, k) for i in (-1, 0, 1) for j in (-1, 0, 1) for k in (-1, 0, 1) if (i, j, k) > (0, 0, 0)]
)

InsideTest = Callable[[np.ndarray], np.ndarray]


@dataclass
class OccupancySamples:
    """Occupancy-labelled points for the fitting loss.

    points: (N, 3) float32 in the normalised frame; labels: (N,) float32, 1 inside, 0 outside.
    The first `n_near` points lie within NEAR_SURFACE_CELLS cells of the surface, the rest
    are uniform in the cube.
    """

    points: np.ndarray
    labels: np.ndarray
    n_near: int

    def __len__(self) -> int:
        return int(self.points.shape[0])


@dataclass
class Voxelization:
    """The grids of one shape, (R, R, R) arrays indexed [ix, iy, iz]: three bool grids,
    and for meshes |winding number| at the cell centres (float; None otherwise)."""

    occupancy: np.ndarray
    winding_occupancy: np.ndarray
    surface_cells: np.ndarray
    winding_number: np.ndarray | None = None


# --------------------------------------------------------------------------- grid helpers


def cell_size(resolution: int) -> float:
    """Side h of a cell of the R^3 grid over [-0.5, 0.5]^3."""
    return 1.0 / resolution


def cell_coordinates(resolution: int = DEFAULT_RESOLUTION) -> np.ndarray:
    """(R,) centre coordinates along one axis: (i + 0.5) / R - 0.5."""
    return (np.arange(resolution) + 0.5) / resolution - 0.5


def cell_centers(resolution: int = DEFAULT_RESOLUTION) -> np.ndarray:
    """(R^3, 3) cell centres in C order, so `values.reshape(R, R, R)` is indexed [ix, iy, iz]."""
    c = cell_coordinates(resolution)
    return np.stack(np.meshgrid(c, c, c, indexing="ij"), axis=-1).reshape(-1, 3)


def point_cells(points: np.ndarray, resolution: int = DEFAULT_RESOLUTION) -> np.ndarray:
    """(N, 3) int64 index of the cell that holds each point, clipped to the grid."""
    ijk = np.floor((as_array(points, "N, 3", "points") + 0.5) * resolution).astype(np.int64)
    return np.clip(ijk, 0, resolution - 1)


def splat(points: np.ndarray, resolution: int = DEFAULT_RESOLUTION) -> np.ndarray:
    """(R, R, R) bool: the cells that hold at least one of the (N, 3) points."""
    grid = np.zeros((resolution,) * 3, dtype=bool)
    ijk = point_cells(points, resolution)
    grid[ijk[:, 0], ijk[:, 1], ijk[:, 2]] = True
    return grid


# --------------------------------------------------------------------------- inside tests


# Queries per libigl call (see winding_numbers): about 70 ms of work for a 5k-face mesh.
WINDING_CHUNK_QUERIES = 65_536


def winding_numbers(vertices: np.ndarray, faces: np.ndarray, queries: np.ndarray,
                    max_edge: float = LONG_EDGE) -> np.ndarray:
    """(Q,) generalised winding numbers of the (Q, 3) queries w.r.t. a triangle soup.

    libigl's `fast_winding_number` (Barill et al. 2018, Barnes-Hut; error well below 0.01
    here). Long triangles defeat its far-field approximation (every query is "near" them;
    a 400-face glyph took 3x longer than the same glyph split finely), so edges longer
    than `max_edge` (normalised units) are split first, which leaves the surface unchanged.
    """
    V = as_array(vertices, "V, 3", "vertices", contiguous=True)
    F = as_array(faces, "F, 3", "faces", dtype=np.int64, contiguous=True)
    Q = as_array(queries, "Q, 3", "queries", contiguous=True)
    if Q.shape[0] == 0:
        return np.zeros(0)
    area = 0.5 * float(np.linalg.norm(np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]]),
                                      axis=1).sum())
    if area > TANGLE_AREA and len(F) * len(Q) <= EXACT_WINDING_BUDGET:
        return np.concatenate([np.asarray(igl.winding_number(V, F, Q[i:i + WINDING_CHUNK_QUERIES]))
                               for i in range(0, len(Q), WINDING_CHUNK_QUERIES)])
    longest = np.linalg.norm(V[F[:, [1, 2, 0]]] - V[F], axis=-1).max(axis=1)
    max_edge = _split_edge(longest, max_edge)
    if float(longest.max()) > max_edge:
        V, F = trimesh.remesh.subdivide_to_size(V, F, max_edge=max_edge, max_iter=12)
        F = np.ascontiguousarray(F, dtype=np.int64)
        V = np.ascontiguousarray(V, dtype=np.float64)
    # libigl holds the GIL for the whole call; in chunks, a GUI thread gets to paint between
    # them. Each call rebuilds the tree, so chunks grow with the mesh (one chunk when big).
    chunk = max(WINDING_CHUNK_QUERIES, 4 * len(F))
    return np.concatenate([np.asarray(igl.fast_winding_number(V, F, Q[i:i + chunk]))
                           for i in range(0, len(Q), chunk)])


def _split_edge(longest: np.ndarray, max_edge: float) -> float:
    """The edge length to split to: `max_edge`, doubled while splitting the faces whose
    longest edges are (F,) `longest` would make more than SPLIT_FACE_BUDGET faces (or
    twice F). Each split quarters a face and halves its edges."""
    budget = max(SPLIT_FACE_BUDGET, 2 * longest.size)
    while True:
        with np.errstate(divide="ignore"):
            splits = np.ceil(np.log2(np.maximum(longest / max_edge, 1.0)))
        if float(np.sum(4.0 ** np.minimum(splits, 12))) <= budget or not np.any(splits):
            return max_edge
        max_edge *= 2.0


def signed_volume(mesh: trimesh.Trimesh) -> float:
    """Signed enclosed volume (negative for an inside-out mesh); cheaper than trimesh's
    `volume`, whose mass_properties also computes inertia."""
    tri = np.asarray(mesh.vertices)[np.asarray(mesh.faces)]
    return float(np.einsum("ij,ij->", tri[:, 0], np.cross(tri[:, 1], tri[:, 2])) / 6.0)


def mesh_inside(mesh: trimesh.Trimesh, queries: np.ndarray) -> np.ndarray:
    """(Q,) bool: |generalised winding number| > 0.5 at the (Q, 3) queries.

    The absolute value makes inside-out meshes and inside-out components work; only
    overlapping components of opposite orientation would cancel (none seen in practice).
    """
    return np.abs(winding_numbers(mesh.vertices, mesh.faces, queries)) > 0.5


# --------------------------------------------------------------------------- samples


def surface_cells(mesh: trimesh.Trimesh, resolution: int = DEFAULT_RESOLUTION,
                  seed: int = 0) -> np.ndarray:
    """(R, R, R) bool: the cells that the surface passes through.

    Found by dense area-uniform sampling (SURFACE_SAMPLES_PER_CELL_AREA samples per h^2 of
    area, plus every vertex): a cell that the surface only grazes may be missed, which at
    worst drops a thin-part voxel.
    """
    h = cell_size(resolution)
    count = int(np.clip(mesh.area / h**2 * SURFACE_SAMPLES_PER_CELL_AREA, 10_000,
                        MAX_SURFACE_SAMPLES))
    points, _ = trimesh.sample.sample_surface(mesh, count, seed=seed)
    grid = splat(points, resolution)
    grid |= splat(mesh.vertices, resolution)
    return grid


def near_surface_points(surface_points: np.ndarray, rng: np.random.Generator,
                        resolution: int = DEFAULT_RESOLUTION) -> np.ndarray:
    """(N, 3): each of the (N, 3) surface points moved uniformly within a ball of radius
    NEAR_SURFACE_CELLS cells, then clipped to the cube."""
    n = surface_points.shape[0]
    direction = rng.normal(size=(n, 3))
    direction /= np.maximum(np.linalg.norm(direction, axis=1, keepdims=True), 1e-12)
    radius = NEAR_SURFACE_CELLS * cell_size(resolution) * rng.random(n) ** (1.0 / 3.0)
    return np.clip(surface_points + direction * radius[:, None], -0.5, 0.5)


def sample_query_points(surface_points: np.ndarray, n_samples: int, rng: np.random.Generator,
                        resolution: int = DEFAULT_RESOLUTION) -> tuple[np.ndarray, int]:
    """(N, 3) fitting sample positions (labels still to compute) and the near-surface count.

    `surface_points` (M, 3) are area-uniform surface samples, M >= the near-surface count.
    """
    n_near = round(n_samples * NEAR_SURFACE_FRACTION)
    near = near_surface_points(surface_points[:n_near], rng, resolution)
    uniform = rng.uniform(-0.5, 0.5, size=(n_samples - n_near, 3))
    return np.concatenate([near, uniform], axis=0), n_near


def make_samples(points: np.ndarray, inside: np.ndarray, n_near: int) -> OccupancySamples:
    """Pack (N, 3) positions and their (N,) inside flags as float32 arrays."""
    return OccupancySamples(points=np.asarray(points, dtype=np.float32),
                            labels=np.asarray(inside, dtype=np.float32), n_near=n_near)


# --------------------------------------------------------------------------- thin parts


def add_thin_parts(inside: np.ndarray, surface: np.ndarray) -> np.ndarray:
    """(R, R, R) bool fitting grid: the `inside` grid plus the thin parts seen in `surface`.

    inside: winding grid; surface: cells the surface passes through (both (R, R, R) bool).
    Adds the surface cells more than one cell away from any inside cell (parts that
    vanished), then the fewest surface cells that join pieces which the surface connects.
    """
    grown = ndi.binary_dilation(inside, STRUCTURE_26)
    base = inside | (surface & ~grown)
    return connect_pieces(base, surface)


def connect_pieces(base: np.ndarray, allowed: np.ndarray) -> np.ndarray:
    """(R, R, R) bool: `base` plus cells of `allowed` on shortest paths that join its pieces.

    Within each 26-connected component of base | allowed, every 26-connected piece of
    `base` is joined to the largest one by a path that costs 1 per added cell and almost
    nothing through cells of `base`, found by one multi-source Dijkstra.
    """
    full = base | allowed
    base_labels, n_base = ndi.label(base, STRUCTURE_26)
    if n_base <= 1:
        return base.copy()
    full_labels, _ = ndi.label(full, STRUCTURE_26)
    piece_index = np.arange(1, n_base + 1)
    # Which component of `full` each piece lies in, and how big the piece is.
    piece_full = ndi.maximum(full_labels, base_labels, piece_index).astype(np.int64)
    piece_size = ndi.sum_labels(np.ones_like(base_labels), base_labels, piece_index)
    pieces_per_full = np.bincount(piece_full)
    split = np.flatnonzero(pieces_per_full > 1)
    if split.size == 0:
        return base.copy()

    region = np.isin(full_labels, split)
    coords = np.argwhere(region)
    index = np.full(base.shape, -1, dtype=np.int64)
    index[tuple(coords.T)] = np.arange(coords.shape[0])
    cost = np.where(base[tuple(coords.T)], 1e-3, 1.0)
    rows, cols, weights = [], [], []
    for offset in _HALF_OFFSETS:
        nb = coords + offset
        ok = np.all((nb >= 0) & (nb < np.array(base.shape)), axis=1)
        j = np.full(coords.shape[0], -1, dtype=np.int64)
        j[ok] = index[tuple(nb[ok].T)]
        ok &= j >= 0
        i = np.flatnonzero(ok)
        rows.append(i)
        cols.append(j[ok])
        weights.append(0.5 * (cost[i] + cost[j[ok]]) * float(np.linalg.norm(offset)))
    graph = sparse.coo_matrix(
        (np.concatenate(weights), (np.concatenate(rows), np.concatenate(cols))),
        shape=(coords.shape[0],) * 2).tocsr()

    voxel_piece = base_labels[tuple(coords.T)]
    main_piece = {}
    for f in split:
        members = np.flatnonzero(piece_full == f) + 1
        main_piece[int(f)] = int(members[np.argmax(piece_size[members - 1])])
    sources = np.flatnonzero(np.isin(voxel_piece, list(main_piece.values())))
    dist, pred = csgraph.dijkstra(graph, directed=False, indices=sources,
                                  return_predecessors=True, min_only=True)[:2]
    out = base.copy()
    for f in split:
        for piece in np.flatnonzero(piece_full == f) + 1:
            if piece == main_piece[int(f)]:
                continue
            members = np.flatnonzero(voxel_piece == piece)
            node = int(members[np.argmin(dist[members])])
            if not np.isfinite(dist[node]):
                continue
            while node >= 0:
                out[tuple(coords[node])] = True
                node = int(pred[node])
    return out


# --------------------------------------------------------------------------- meshes


def voxelize_mesh(mesh: trimesh.Trimesh, resolution: int = DEFAULT_RESOLUTION,
                  n_samples: int = DEFAULT_SAMPLES,
                  seed: int = 0) -> tuple[Voxelization, OccupancySamples]:
    """Grids and fitting samples of a mesh already in the normalised frame.

    One winding-number evaluation serves the R^3 cell centres and the N samples (the
    Barnes-Hut tree is built once). Returns the grids and the samples.
    """
    rng = np.random.default_rng(seed)
    surface = surface_cells(mesh, resolution, seed=seed)
    n_near = round(n_samples * NEAR_SURFACE_FRACTION)
    on_surface, _ = trimesh.sample.sample_surface(mesh, max(n_near, 1), seed=rng)
    queries, n_near = sample_query_points(on_surface, n_samples, rng, resolution)
    centers = cell_centers(resolution)
    number = np.abs(winding_numbers(mesh.vertices, mesh.faces,
                                    np.concatenate([centers, queries], axis=0)))
    inside = number > 0.5
    winding = inside[: centers.shape[0]].reshape((resolution,) * 3)
    samples = make_samples(queries, inside[centers.shape[0]:], n_near)
    grids = Voxelization(occupancy=add_thin_parts(winding, surface),
                         winding_occupancy=winding, surface_cells=surface,
                         winding_number=number[: centers.shape[0]].reshape((resolution,) * 3))
    return grids, samples


# --------------------------------------------------------------------------- point clouds


class PointCloudInside:
    """Inside test of a point cloud without normals, on the R^3 grid (normalised frame).

    Method (morphological, scipy.ndimage only): mark the cells that hold points, dilate
    them by a ball of radius r (about the distance to the 8th nearest sample, so the balls
    cover the surface without gaps), fill the enclosed cavity (`binary_fill_holes`) and
    erode by the same ball: the solid comes back to the sampled surface. If nothing gets
    enclosed, r grows up to MAX_CLOSING_CELLS. Far from the points a query takes this grid's
    value; within 1.5 cells of the points it is inside when the nearest point lies further
    out than the query, "out" being the direction in which the smoothed solid falls off.
    That keeps the boundary cells unbiased (counting every point cell as inside would add
    half a cell all round).

    Limits: the surface must be closed and sampled without holes wider than about
    2 * MAX_CLOSING_CELLS cells; an open scan (a missing side) encloses nothing, and
    `load_shape` refuses it (DegenerateShapeError). Parts closer together than about 2r
    merge and concave details smaller than r fill in. Input normals are not used.
    """

    MAX_CLOSING_CELLS = 4

    def __init__(self, points: np.ndarray, resolution: int = DEFAULT_RESOLUTION):
        self.points = np.asarray(points, dtype=np.float64)
        self.resolution = resolution
        self.tree = cKDTree(self.points)
        self.shell = splat(self.points, resolution)
        self.filled = self._fill()
        self.band = ndi.binary_dilation(self.shell, STRUCTURE_26, iterations=2)
        soft = ndi.gaussian_filter(self.filled.astype(np.float64), sigma=1.0, mode="constant")
        # Outward direction = minus the gradient of the smoothed grid (index units).
        self.gradient = np.stack(np.gradient(soft), axis=0)

    def _cover_radius(self) -> float:
        """Median distance from a sample to its 8th nearest neighbour."""
        sub = self.points
        if sub.shape[0] > 20_000:
            sub = sub[np.random.default_rng(0).choice(sub.shape[0], 20_000, replace=False)]
        k = min(8, self.points.shape[0] - 1)
        d, _ = self.tree.query(sub, k=k + 1)
        return float(np.median(d[:, k]))

    def _fill(self) -> np.ndarray:
        from skimage.morphology import ball

        h = cell_size(self.resolution)
        r0 = int(np.clip(np.ceil(self._cover_radius() / h), 1, self.MAX_CLOSING_CELLS))
        solid = np.zeros_like(self.shell)
        for r in range(r0, self.MAX_CLOSING_CELLS + 1):
            pad = r + 1
            grown = ndi.binary_dilation(np.pad(self.shell, pad), ball(r))
            filled = ndi.binary_fill_holes(grown)
            if filled.sum() > 1.05 * grown.sum():  # a cavity was enclosed
                solid = ndi.binary_erosion(filled, ball(r))[pad:-pad, pad:-pad, pad:-pad]
                break
        return solid

    def __call__(self, queries: np.ndarray) -> np.ndarray:
        """(Q,) bool inside flags of the (Q, 3) queries."""
        q = as_array(queries, "Q, 3", "queries")
        h = cell_size(self.resolution)
        ijk = point_cells(q, self.resolution)
        result = self.filled[ijk[:, 0], ijk[:, 1], ijk[:, 2]].copy()
        # Only queries within two cells of a point cell can be within 1.5 h of a point.
        near = self.band[ijk[:, 0], ijk[:, 1], ijk[:, 2]]
        dist, nearest = self.tree.query(q[near], distance_upper_bound=1.5 * h)
        near[near] = np.isfinite(dist)
        nearest = nearest[np.isfinite(dist)]
        if np.any(near):
            idx = (q[near] + 0.5) / h - 0.5
            grad = np.stack([ndi.map_coordinates(g, idx.T, order=1, mode="nearest")
                             for g in self.gradient], axis=1)
            outward = -grad
            to_surface = self.points[nearest] - q[near]
            has_dir = np.linalg.norm(outward, axis=1) > 1e-6
            # Where the grid gives no direction (deep inside or far out), keep the grid's value.
            verdict = np.einsum("ij,ij->i", to_surface, outward) > 0.0
            result[np.flatnonzero(near)[has_dir]] = verdict[has_dir]
        return result


def voxelize_points(points: np.ndarray, resolution: int = DEFAULT_RESOLUTION,
                    n_samples: int = DEFAULT_SAMPLES,
                    seed: int = 0) -> tuple[Voxelization, OccupancySamples, PointCloudInside]:
    """Grids, fitting samples and the inside test of a point cloud in the normalised frame.

    points: (P, 3). Near-surface samples start from the input points (drawn with
    replacement when there are fewer than needed).
    """
    rng = np.random.default_rng(seed)
    inside_test = PointCloudInside(points, resolution)
    n_near = round(n_samples * NEAR_SURFACE_FRACTION)
    chosen = rng.choice(points.shape[0], n_near, replace=points.shape[0] < n_near)
    queries, n_near = sample_query_points(points[chosen], n_samples, rng, resolution)
    centers = cell_centers(resolution)
    inside = inside_test(np.concatenate([centers, queries], axis=0))
    winding = inside[: centers.shape[0]].reshape((resolution,) * 3)
    samples = make_samples(queries, inside[centers.shape[0]:], n_near)
    grids = Voxelization(occupancy=add_thin_parts(winding, inside_test.shell),
                         winding_occupancy=winding, surface_cells=inside_test.shell)
    return grids, samples, inside_test


# --------------------------------------------------------------------------- surfaces


def grid_surface(grid: np.ndarray, lower: np.ndarray, upper: np.ndarray,
                 smooth: float = 0.0) -> trimesh.Trimesh:
    """Marching-cubes surface (level 0.5) of an (X, Y, Z) bool grid whose cells tile the box
    [lower, upper] (each (3,)), outward-facing, in that box's coordinates.

    smooth > 0 blurs the grid (Gaussian sigma in cells) first for a rounder surface; where
    that would blur every cell below the level (a sparse shell of single cells, as a few
    points or a flat scan give), the grid is used as it is.
    """
    from skimage.measure import marching_cubes

    field = np.pad(grid.astype(np.float32), 1)
    if smooth > 0:
        blurred = ndi.gaussian_filter(field, sigma=smooth)
        if blurred.max() > 0.5:
            field = blurred
    verts, faces, _, _ = marching_cubes(field, level=0.5)
    # Padded index v corresponds to cell coordinate v - 1, whose centre is at v - 0.5.
    lower = np.asarray(lower, dtype=np.float64)
    step = (np.asarray(upper, dtype=np.float64) - lower) / np.array(grid.shape)
    mesh = trimesh.Trimesh(lower + (verts - 0.5) * step, faces, process=True)
    if signed_volume(mesh) < 0:
        mesh.invert()
    return mesh
