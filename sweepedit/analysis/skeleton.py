"""The medial axis of an occupancy grid as a graph of branches (the fitting prior).

`compute_skeleton(occupancy)` thins the R^3 grid to a curve skeleton (Lee et al. 1994,
`skimage.morphology.skeletonize`), turns the skeleton voxels into a graph (26-adjacency),
and cleans it up:

- nodes are tips (one neighbour), junctions (clusters of touching voxels with three or more
  neighbours, merged into one node at their centroid) and loop anchors (see below);
- spurs are pruned: a branch from a junction to a tip no longer than the local radius at the
  junction plus SPUR_MARGIN_CELLS is surface noise (a real limb reaches further out than the
  body it grows from); one spur per junction goes per pass, shortest first, so that the fork
  that thinning leaves at a blunt end keeps one arm as the continuation;
- cycles too short to go round a real hole (a self-loop at a junction, or two parallel
  branches, shorter than 2 pi times the local radius plus two margins) are broken;
- junctions left with two branches are dissolved (the two branches joined);
- per connected component of the grid: a tiny bit (under MIN_COMPONENT_FRACTION of the
  volume and with almost no skeleton) is dropped; a blob whose skeleton is empty or much
  shorter than its radius (a ball, a cube) gets the fallback branch: its principal axis (PCA
  of its voxels) spanning the component;
- branch points are lightly smoothed (the voxel staircase) and each gets a radius from the
  Euclidean distance transform.

Loops: a closed curve with no junction on it (a torus, a knot) is one branch whose two
ends are the same node, of kind "loop"; its first and last points coincide. A junction
whose only branch ends on both sides at it also becomes a "loop" node.

All points and radii are in the normalised frame ([-0.5, 0.5]^3, cell centre of index i at
(i + 0.5) / R - 0.5). A radius is the largest Euclidean distance transform value (distance
to the nearest empty cell centre) within one cell of the point: the voxel skeleton runs up
to 0.7 cell off the true axis, and this undoes most of that. On tubes of radius 1 to 10
cells at random offsets and angles it came within 0.25 cell of the true radius (EDT - 0.5
at the point itself: 0.5 to 1 cell too small).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import numpy as np
import scipy.ndimage as ndi
from skimage.morphology import skeletonize

from sweepedit.geometry.arrays import as_array

NodeKind = Literal["tip", "junction", "loop"]

SPUR_FACTOR = 1.0
SPUR_MARGIN_CELLS = 2.0
MIN_COMPONENT_FRACTION = 0.01
MIN_BRANCH_CELLS = 2.0
SMOOTHING_ITERATIONS = 6
MIN_RADIUS_CELLS = 0.5

_STRUCTURE_26 = np.ones((3, 3, 3), dtype=bool)
_OFFSETS_26 = np.array([(i, j, k) for i in (-1, 0, 1) for j in (-1, 0, 1) for k in (-1, 0, 1)
                        if (i, j, k) != (0, 0, 0)])


@dataclass
class Branch:
    """One branch of the skeleton.

    points: (M, 3) ordered points in the normalised frame, M >= 2, from the start node's
        position to the end node's; radii: (M,) local radius at each point.
    start, end: node ids in the owning Skeleton; start_kind / end_kind: "tip" | "junction"
        | "loop". A loop (closed branch) has start == end and points[0] == points[-1].
    fallback: True when the branch is a principal axis, not a medial-axis curve.
    """

    points: np.ndarray
    radii: np.ndarray
    start: int
    end: int
    start_kind: NodeKind
    end_kind: NodeKind
    fallback: bool = False

    @property
    def is_loop(self) -> bool:
        return self.start == self.end

    @property
    def length(self) -> float:
        return float(np.sum(np.linalg.norm(np.diff(self.points, axis=0), axis=1)))

    @property
    def mean_radius(self) -> float:
        return float(np.mean(self.radii))

    def resample(self, n: int) -> tuple[np.ndarray, np.ndarray]:
        """(n, 3) points evenly spaced by arc length from start to end, and (n,) radii."""
        seg = np.linalg.norm(np.diff(self.points, axis=0), axis=1)
        s = np.concatenate([[0.0], np.cumsum(seg)])
        if s[-1] <= 0:
            return np.repeat(self.points[:1], n, axis=0), np.repeat(self.radii[:1], n)
        t = np.linspace(0.0, s[-1], n)
        pts = np.stack([np.interp(t, s, self.points[:, d]) for d in range(3)], axis=1)
        return pts, np.interp(t, s, self.radii)


@dataclass
class Skeleton:
    """Branches of the medial axis and their nodes.

    nodes: (K, 3) node positions (normalised frame); node_kinds: K kinds ("tip" |
    "junction" | "loop"); resolution: R of the grid it came from.
    """

    branches: list[Branch]
    nodes: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    node_kinds: list[NodeKind] = field(default_factory=list)
    resolution: int = 64

    def __len__(self) -> int:
        return len(self.branches)

    @property
    def junction_ids(self) -> np.ndarray:
        """(J,) ids of the junction nodes."""
        return np.array([i for i, k in enumerate(self.node_kinds) if k == "junction"],
                        dtype=np.int64)

    @property
    def junctions(self) -> np.ndarray:
        """(J, 3) junction positions."""
        return self.nodes[self.junction_ids].reshape(-1, 3)

    @property
    def tips(self) -> np.ndarray:
        """(T, 3) tip positions."""
        ids = [i for i, k in enumerate(self.node_kinds) if k == "tip"]
        return self.nodes[ids].reshape(-1, 3)

    @property
    def n_loops(self) -> int:
        return sum(b.is_loop for b in self.branches)

    @property
    def is_fallback(self) -> bool:
        """True when every branch is a principal-axis fallback."""
        return bool(self.branches) and all(b.fallback for b in self.branches)

    @property
    def total_length(self) -> float:
        return float(sum(b.length for b in self.branches))

    def all_points(self) -> np.ndarray:
        """(P, 3) the points of all branches (shared node points repeat)."""
        if not self.branches:
            return np.zeros((0, 3))
        return np.concatenate([b.points for b in self.branches], axis=0)

    def all_radii(self) -> np.ndarray:
        """(P,) radii matching `all_points()`."""
        if not self.branches:
            return np.zeros(0)
        return np.concatenate([b.radii for b in self.branches])


# --------------------------------------------------------------------------- internals


@dataclass
class _Node:
    pos: np.ndarray  # (3,) index space
    kind: str
    component: int


@dataclass
class _Edge:
    a: int
    b: int
    pts: np.ndarray  # (M, 3) index space, from node a's position to node b's
    component: int
    fallback: bool = False

    @property
    def length(self) -> float:
        return float(np.sum(np.linalg.norm(np.diff(self.pts, axis=0), axis=1)))


class _Graph:
    def __init__(self) -> None:
        self.nodes: list[_Node] = []
        self.edges: list[_Edge] = []

    def add_node(self, pos: np.ndarray, kind: str, component: int) -> int:
        self.nodes.append(_Node(np.asarray(pos, dtype=np.float64), kind, component))
        return len(self.nodes) - 1

    def degrees(self) -> np.ndarray:
        deg = np.zeros(len(self.nodes), dtype=np.int64)
        for e in self.edges:
            deg[e.a] += 1
            deg[e.b] += 1
        return deg


def _voxel_graph(skel: np.ndarray, labels: np.ndarray) -> _Graph:
    """Nodes and branches (index space) of a skeleton voxel set."""
    coords = np.argwhere(skel)
    k = coords.shape[0]
    graph = _Graph()
    if k == 0:
        return graph
    index = np.full(skel.shape, -1, dtype=np.int64)
    index[tuple(coords.T)] = np.arange(k)
    padded = np.pad(index, 1, constant_values=-1)
    nb = np.stack([padded[tuple((coords + 1 + o).T)] for o in _OFFSETS_26], axis=1)
    neighbours = [row[row >= 0] for row in nb]
    deg = np.array([n.size for n in neighbours])
    comp = labels[tuple(coords.T)]

    node_of = np.full(k, -1, dtype=np.int64)
    # Junction voxels that touch form one node (thinning leaves small clusters).
    junction = deg >= 3
    jgrid = np.zeros(skel.shape, dtype=bool)
    jgrid[tuple(coords[junction].T)] = True
    jlab, nj = ndi.label(jgrid, _STRUCTURE_26)
    if nj:
        jl = jlab[tuple(coords.T)]
        for c in range(1, nj + 1):
            members = np.flatnonzero(jl == c)
            node_of[members] = graph.add_node(coords[members].mean(axis=0), "junction",
                                              int(comp[members[0]]))
    for v in np.flatnonzero(deg <= 1):
        node_of[v] = graph.add_node(coords[v], "tip", int(comp[v]))

    visited = np.zeros(k, dtype=bool)
    started: set[tuple[int, int]] = set()
    direct: set[tuple[int, int]] = set()

    def walk(n: int, v: int, u: int) -> None:
        if (n, u) in started:
            return
        started.add((n, u))
        m = int(node_of[u])
        if m >= 0:
            pair = (min(n, m), max(n, m))
            if m == n or pair in direct:
                return
            direct.add(pair)
            started.add((m, v))
            graph.edges.append(_Edge(n, m, np.stack([graph.nodes[n].pos, graph.nodes[m].pos]),
                                     int(comp[u])))
            return
        interior = []
        prev, cur = v, u
        for _ in range(k + 1):
            if node_of[cur] >= 0:
                break
            interior.append(cur)
            visited[cur] = True
            a, b = neighbours[cur]
            prev, cur = cur, (b if a == prev else a)
        m = int(node_of[cur])
        started.add((m, interior[-1]))
        if m == n and len(interior) < 3:
            return  # a tiny ring around a junction cluster: thinning noise
        pts = np.concatenate([graph.nodes[n].pos[None], coords[interior],
                              graph.nodes[m].pos[None]]).astype(np.float64)
        graph.edges.append(_Edge(n, m, pts, int(comp[interior[0]])))

    for v in np.flatnonzero(node_of >= 0):
        for u in neighbours[v]:
            if node_of[u] != node_of[v]:
                walk(int(node_of[v]), int(v), int(u))

    # Closed curves without any node: anchor a loop node on each.
    for s in np.flatnonzero((deg == 2) & (node_of < 0) & ~visited):
        if visited[s]:
            continue
        node_of[s] = graph.add_node(coords[s], "loop", int(comp[s]))
        visited[s] = True
        walk(int(node_of[s]), int(s), int(neighbours[s][0]))
    return graph


def _dissolve(graph: _Graph) -> None:
    """Join the two branches of every junction of degree 2; a junction whose only branch
    returns to it becomes a loop node; a junction left with one branch becomes a tip."""
    changed = True
    while changed:
        changed = False
        ends: dict[int, list[tuple[int, int]]] = {}
        for i, e in enumerate(graph.edges):
            ends.setdefault(e.a, []).append((i, 0))
            ends.setdefault(e.b, []).append((i, 1))
        for n, node in enumerate(graph.nodes):
            if node.kind != "junction":
                continue
            at = ends.get(n, [])
            if len(at) == 1:
                node.kind = "tip"
            elif len(at) == 2:
                (i, si), (j, sj) = at
                if i == j:
                    node.kind = "loop"
                    continue
                e1, e2 = graph.edges[i], graph.edges[j]
                p1 = e1.pts if si == 1 else e1.pts[::-1]  # ends at n
                p2 = e2.pts if sj == 0 else e2.pts[::-1]  # starts at n
                a = e1.a if si == 1 else e1.b
                b = e2.b if sj == 0 else e2.a
                merged = _Edge(a, b, np.concatenate([p1[:-1], p2]), e1.component)
                graph.edges = [e for t, e in enumerate(graph.edges) if t not in (i, j)]
                graph.edges.append(merged)
                node.kind = "dead"
                changed = True
                break


def _remove_small_cycles(graph: _Graph, edt: np.ndarray, margin_cells: float) -> bool:
    """Break cycles of one branch (at a junction) or two parallel branches that are too
    short to go around a real hole: shorter than 2 pi times the larger node radius plus
    twice the margin (a tunnel's centre line is longer than the circumference of its
    tube).
    Removes the longer branch of each such cycle; True if any went."""
    deg = graph.degrees()
    pairs: dict[tuple[int, int], list[int]] = {}
    for i, e in enumerate(graph.edges):
        pairs.setdefault((min(e.a, e.b), max(e.a, e.b)), []).append(i)
    drop: set[int] = set()
    for (a, b), idx in pairs.items():
        radius = float(np.max(_radius_cells(edt, np.stack([graph.nodes[a].pos,
                                                           graph.nodes[b].pos]))))
        limit = 2.0 * np.pi * radius + 2.0 * margin_cells
        if a == b:
            # A self-loop on a node with other branches; a lone ring (knot, torus) stays.
            if deg[a] > 2:
                drop.update(i for i in idx if graph.edges[i].length < limit)
            continue
        if len(idx) >= 2:
            idx = sorted(idx, key=lambda i: graph.edges[i].length)
            for i in idx[1:]:
                if graph.edges[idx[0]].length + graph.edges[i].length < limit:
                    drop.add(i)
    if drop:
        graph.edges = [e for i, e in enumerate(graph.edges) if i not in drop]
    return bool(drop)


def _prune_spurs(graph: _Graph, edt: np.ndarray, spur_factor: float,
                 margin_cells: float) -> None:
    """Remove junction-to-tip branches no longer than the junction's radius + margin
    (and small cycles, see _remove_small_cycles)."""
    while True:
        if _remove_small_cycles(graph, edt, margin_cells):
            _dissolve(graph)
        deg = graph.degrees()
        best: dict[int, tuple[float, int]] = {}
        for i, e in enumerate(graph.edges):
            if e.a == e.b:
                continue
            for tip, junction in ((e.a, e.b), (e.b, e.a)):
                if deg[tip] == 1 and graph.nodes[tip].kind == "tip" and deg[junction] >= 3:
                    radius = _radius_cells(edt, graph.nodes[junction].pos[None])[0]
                    length = e.length
                    if length <= spur_factor * radius + margin_cells and (
                            junction not in best or length < best[junction][0]):
                        best[junction] = (length, i)
        if not best:
            return
        drop = {i for _, i in best.values()}
        for i in drop:
            e = graph.edges[i]
            for n in (e.a, e.b):
                if graph.nodes[n].kind == "tip":
                    graph.nodes[n].kind = "dead"
        graph.edges = [e for i, e in enumerate(graph.edges) if i not in drop]
        _dissolve(graph)


def _radius_cells(edt: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """(M,) distance to the surface, in cells, at (M, 3) index-space points; `edt` is the
    neighbourhood-maximum distance transform."""
    d = ndi.map_coordinates(edt, np.asarray(pts, dtype=np.float64).T, order=1, mode="nearest")
    return np.maximum(d, MIN_RADIUS_CELLS)


def _principal_axis(voxels: np.ndarray) -> np.ndarray:
    """(M, 3) index-space points along the principal axis of (V, 3) voxel indices, spanning
    the outermost voxel centres, about one point per cell."""
    centre = voxels.mean(axis=0)
    if voxels.shape[0] > 1:
        _, _, vt = np.linalg.svd(voxels - centre, full_matrices=False)
        axis = vt[0]
    else:
        axis = np.array([1.0, 0.0, 0.0])
    t = (voxels - centre) @ axis
    lo, hi = float(t.min()), float(t.max())
    if hi - lo < 1.0:  # a single voxel: a one-cell segment through it
        lo, hi = -0.5, 0.5
    m = max(2, int(np.ceil(hi - lo)) + 1)
    return centre + np.linspace(lo, hi, m)[:, None] * axis


def _smooth(pts: np.ndarray, iterations: int) -> np.ndarray:
    """Laplacian smoothing of the interior points, the ends fixed."""
    p = pts.copy()
    for _ in range(iterations):
        if p.shape[0] < 3:
            break
        p[1:-1] = 0.25 * p[:-2] + 0.5 * p[1:-1] + 0.25 * p[2:]
    return p


def compute_skeleton(occupancy: np.ndarray, *, spur_factor: float = SPUR_FACTOR,
                     spur_margin_cells: float = SPUR_MARGIN_CELLS,
                     min_component_fraction: float = MIN_COMPONENT_FRACTION) -> Skeleton:
    """Skeleton branches of an (R, R, R) bool occupancy grid over [-0.5, 0.5]^3.

    spur_factor, spur_margin_cells: a junction-to-tip branch is pruned when its length is
    at most spur_factor * (radius at the junction) + spur_margin_cells cells.
    min_component_fraction: grid components below this share of the occupied volume are
    dropped unless their skeleton has some length.
    Returns a Skeleton with at least one branch whenever the grid holds a voxel.
    """
    occ = as_array(occupancy, "R, R, R", "occupancy", dtype=bool)
    res = occ.shape[0]
    h = 1.0 / res
    if not occ.any():
        return Skeleton(branches=[], resolution=res)

    edt = ndi.distance_transform_edt(np.pad(occ, 1))[1:-1, 1:-1, 1:-1]
    labels, n_comp = ndi.label(occ, _STRUCTURE_26)
    volumes = np.bincount(labels.ravel(), minlength=n_comp + 1)
    total = int(volumes[1:].sum())

    # Radii: the largest distance within one cell (see the module docstring).
    edt_near = ndi.maximum_filter(edt, size=3)
    graph = _voxel_graph(skeletonize(occ) > 0, labels)
    _prune_spurs(graph, edt_near, spur_factor, spur_margin_cells)
    _dissolve(graph)

    # Per component: keep its branches, replace them by the principal axis, or drop it.
    length = np.zeros(n_comp + 1)
    for e in graph.edges:
        length[e.component] += e.length
    r_max = ndi.maximum(edt, labels, np.arange(n_comp + 1))
    largest = int(np.argmax(volumes[1:])) + 1
    keep = []
    for e in graph.edges:
        c = e.component
        if length[c] >= max(MIN_BRANCH_CELLS, 0.5 * r_max[c]):
            keep.append(e)
    graph.edges = keep
    for c in range(1, n_comp + 1):
        if length[c] >= max(MIN_BRANCH_CELLS, 0.5 * r_max[c]):
            continue
        if c != largest and volumes[c] < min_component_fraction * total:
            continue
        pts = _principal_axis(np.argwhere(labels == c).astype(np.float64))
        a = graph.add_node(pts[0], "tip", c)
        b = graph.add_node(pts[-1], "tip", c)
        graph.edges.append(_Edge(a, b, pts, c, fallback=True))

    # Renumber the nodes that branches use, then convert to the normalised frame.
    used = sorted({n for e in graph.edges for n in (e.a, e.b)})
    new_id = {n: i for i, n in enumerate(used)}
    nodes = np.array([graph.nodes[n].pos for n in used]).reshape(-1, 3) * h + (h / 2 - 0.5)
    kinds: list[NodeKind] = [graph.nodes[n].kind for n in used]  # type: ignore[misc]
    branches = []
    # Longest first: the fitting warm start gives primitives to branches in this order.
    for e in sorted(graph.edges, key=lambda e: -e.length):
        pts = e.pts if e.fallback else _smooth(e.pts, SMOOTHING_ITERATIONS)
        radii = _radius_cells(edt_near, pts) * h
        a, b = new_id[e.a], new_id[e.b]
        branches.append(Branch(points=pts * h + (h / 2 - 0.5), radii=radii, start=a, end=b,
                               start_kind=kinds[a], end_kind=kinds[b], fallback=e.fallback))
    return Skeleton(branches=branches, nodes=nodes, node_kinds=kinds, resolution=res)
