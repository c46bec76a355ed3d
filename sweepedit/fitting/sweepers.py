"""Differentiable sweepers: primitive parameters + query points -> soft occupancy.

Common interface (`Sweeper`):

    forward(params (B, K, P), queries (B, Q, 3)) -> occupancy (B, K, Q) in [0, 1]

one occupancy per primitive and query (the fitting code forms the union). Parameters use
the layout of sweepedit.fitting.params (control points, a, b, d, s1..sk).

`AnalyticSweeper` is a smooth version of the exact inside test (sweepedit.geometry.inside)
that converges to it as its sharpness grows. `NeuralSweeper` is a compact POCO-like
network over the primitive's 875 key points (sweepedit.fitting.keypoints), trained on
random sweeps against the exact test (sweepedit.training.train); its weights ship
in sweepedit/resources/sweeper_neural.pt. `load_sweeper(kind)` builds the default of each kind.

Both reuse the shared sweep math of sweepedit.geometry.sweep; neither has a copy of it.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from sweepedit.fitting.keypoints import (
    LOOP_POINTS,
    N_AXIS,
    N_KEYPOINTS,
    N_LOOPS,
    sample_keypoints,
    split_keypoints,
)
from sweepedit.fitting.params import DEFAULT_LAYOUT, ParamLayout
from sweepedit.geometry.model import SweepPrimitive
from sweepedit.geometry.sweep import (
    axis_curvature_vectors,
    axis_frames,
    scaling_factor,
    superellipse_level,
)

RESOURCES = Path(__file__).resolve().parents[1] / "resources"  # package data
NEURAL_WEIGHTS = RESOURCES / "sweeper_neural.pt"

_EPS = 1e-9
# Queries farther than CULL / sharpness beyond a primitive's reach have occupancy below
# sigmoid(-CULL) = 6e-6 there: they are not evaluated (occupancy 0). The fits' cross-
# entropy clamps the union at 1e-5, so such values barely reach the loss or its gradient.
CULL = 12.0
# Columns of AnalyticSweeper's per-bracket table: an affine map (4 x 6), then 8 scalars.
_TABLE_WIDTH = 32


def _normalize(v: torch.Tensor, eps: float = 1e-12) -> torch.Tensor:
    return v / torch.sqrt((v * v).sum(-1, keepdim=True) + eps * eps)


class Sweeper(nn.Module):
    """Base class: forward(params (B, K, P), queries (B, Q, 3)) -> occupancy (B, K, Q).

    layout: the parameter layout; None infers it from P with `n_scaling` coefficients.
    """

    def __init__(self, layout: ParamLayout | None = None, n_scaling: int = 2) -> None:
        super().__init__()
        self.layout = layout
        self.n_scaling = n_scaling

    def layout_for(self, params: torch.Tensor) -> ParamLayout:
        """The layout of params (..., P)."""
        if self.layout is not None:
            return self.layout
        if params.shape[-1] == DEFAULT_LAYOUT.size:
            return DEFAULT_LAYOUT
        return ParamLayout.infer(params.shape[-1], self.n_scaling)

    @staticmethod
    def _check(params: torch.Tensor, queries: torch.Tensor) -> None:
        if params.ndim != 3 or queries.ndim != 3 or queries.shape[-1] != 3:
            raise ValueError(f"expected params (B, K, P) and queries (B, Q, 3), got "
                             f"{tuple(params.shape)} and {tuple(queries.shape)}")
        if params.shape[0] != queries.shape[0]:
            raise ValueError("params and queries must have the same batch size")

    def forward(self, params: torch.Tensor, queries: torch.Tensor) -> torch.Tensor:
        """params (B, K, P), queries (B, Q, 3) -> occupancy (B, K, Q) in [0, 1]."""
        raise NotImplementedError


# ----------------------------------------------------------------------------------------
# Analytic sweeper
# ----------------------------------------------------------------------------------------


class AnalyticSweeper(Sweeper):
    """A smooth approximation of the exact inside test.

    The axis is sampled at `stations` parameters t (frames from axis_frames) and extended
    by one extra station beyond each end (along the end tangents, `cap_margin` long). For
    each query q, h_i = (q - s_i).T_i is evaluated at every station (one matmul); a sign
    change of h between stations i and i+1 brackets a plane through q (as in the exact
    test); every bracket is kept -- a discrete choice, made without gradients. For each
    bracket, the root
    is interpolated linearly (λ = h_i / (h_i - h_{i+1})), and with it the point, frame,
    scale f and arc length. The in-plane coordinates x, y (divided by f) give the
    superellipse level L = |x/a|^d + |y/b|^d (sweep.superellipse_level); r = L^(1/d) is a
    homogeneous radius, and sd = ρ (1 - 1/r), with ρ the in-plane distance to the axis, is
    the signed distance to the profile's rim along the ray from the axis. The ends enter
    as the arc length e from each end (negative beyond the caps). The bracket's occupancy
    is sigmoid(min(-sd, e_start, e_end) / τ) (a CSG intersection, whose 0.5 level is the
    boundary itself), with the temperature τ = 1 / sharpness (a length), and the
    primitive's occupancy is the maximum over its brackets. As the sharpness grows
    (and with enough stations) this tends to the exact test.

    sharpness: 1/τ in 1/length units (default 200: τ = 0.005, a third of a 64^3 cell;
    lower it for wider gradient bands while fitting -- the 0.5 level barely moves).
    stations: number of axis samples S (default 48).
    Queries outside a box around the primitive, or farther than its largest radius from
    every 4th station, are not evaluated (occupancy 0, below sigmoid(-12) there anyway).
    fused: the bracket search and the per-bracket occupancy (and its gradient) run as
    the fused loops of bracket_kernels (a refinement step 11.5 -> 7.6 ms) rather than as
    torch ops; None (default): fused for CPU tensors, torch ops on other devices.
    """

    def __init__(self, sharpness: float = 200.0, stations: int = 48,
                 cap_margin: float | None = None, layout: ParamLayout | None = None,
                 n_scaling: int = 2, fused: bool | None = None) -> None:
        super().__init__(layout, n_scaling)
        if stations < 2:
            raise ValueError("stations must be at least 2")
        self.sharpness = float(sharpness)
        self.stations = int(stations)
        self.cap_margin = cap_margin
        self.fused = fused

    def _fused_for(self, tensor: torch.Tensor) -> bool:
        return self.fused if self.fused is not None else tensor.device.type == "cpu"

    def extra_repr(self) -> str:
        return f"sharpness={self.sharpness}, stations={self.stations}, fused={self.fused}"

    def _margin(self) -> float:
        return self.cap_margin if self.cap_margin is not None else 8.0 / self.sharpness

    def forward(self, params: torch.Tensor, queries: torch.Tensor) -> torch.Tensor:
        """params (B, K, P), queries (B, Q, 3) -> occupancy (B, K, Q) in [0, 1]."""
        return self.occupancy_and_bend(params, queries)[0]

    def occupancy_and_bend(self, params: torch.Tensor, queries: torch.Tensor
                           ) -> tuple[torch.Tensor, torch.Tensor]:
        """forward's occupancy (B, K, Q), and the axes' bend at the stations
        (B, K, S, 2): the curvature vector along the frame's U and V
        (sweep.axis_curvature_vectors), which with the profile and the scaling says
        where a sweep folds onto itself (losses.fold_loss); both from one station table."""
        self._check(params, queries)
        B, K, _ = params.shape
        Q = queries.shape[1]
        N = B * K
        st = self._stations(params)
        bend = st["bend"].reshape(B, K, -1, 2)
        q = queries[:, None].expand(B, K, Q, 3).reshape(N, Q, 3)
        rows, pair, bracket = self._brackets(q.detach(), st)  # (V,) each
        out = q.new_zeros(N * Q)
        if rows.numel() == 0:
            return out.reshape(B, K, Q) + 0.0 * params.sum(), bend
        S1 = st["table"].shape[1]
        occ = _bracket_occupancy(st["table"].reshape(N * S1, _TABLE_WIDTH), q.reshape(N * Q, 3),
                                rows * S1 + bracket, pair, self.sharpness, self._fused_for(q))
        # A query's occupancy is the largest over its brackets.
        out = out.scatter_reduce(0, pair, occ, reduce="amax", include_self=True)
        return out.reshape(B, K, Q), bend

    def _stations(self, params: torch.Tensor) -> dict[str, torch.Tensor]:
        """Tables of the sampled (and end-extended) axis, per bracket [i, i+1].

        table (N, S+1, 32): per bracket, an affine map (4, 6) flattened, which takes
        [q, 1] -> (h, x, y) at station i, then at i+1; then f_i, f_i+1, arc_i, arc_i+1,
        a, b, d and the total arc length (one table, so that a step gathers and scatters
        once: two narrower index_adds took 3x longer); bend (N, S, 2) (see
        occupancy_and_bend); points (N, S+2, 3), tangents
        (N, S+2, 3); box_lo, box_hi (N, 3): boxes that hold the soft solid.
        """
        B, K, _ = params.shape
        layout = self.layout_for(params)
        cps, profile, scaling = layout.split(params.reshape(B * K, -1))
        S = self.stations
        margin = self._margin()
        if self._fused_for(params):
            from sweepedit.fitting.station_kernels import FusedStations

            t_np = np.linspace(0.0, 1.0, S)
            table, bend, pts, tangents = FusedStations.apply(cps, profile, scaling, t_np,
                                                             margin)
            f = table[:, :, 24].detach()
        else:
            table, bend, pts, tangents, f = self._station_table(cps, profile, scaling, margin)
        with torch.no_grad():
            pts, f, profile = pts.detach(), f.detach(), profile.detach()
            seg = torch.sqrt(((pts[:, 2:-1] - pts[:, 1:-2]) ** 2).sum(-1) + _EPS ** 2)
            radius = f.abs().amax(dim=1) * torch.sqrt(profile[:, 0] ** 2 + profile[:, 1] ** 2)
            pad = radius + seg.amax(dim=1) + CULL / self.sharpness
            # Coarse stations (every 4th, both ends included) for a cheap distance cull: a
            # query farther than `reach` from all of them has occupancy < sigmoid(-12).
            coarse = torch.cat([pts[:, :-1:4], pts[:, -1:]], dim=1)
            coarse_gap = torch.sqrt(((coarse[:, 1:] - coarse[:, :-1]) ** 2).sum(-1)).amax(dim=1)
            # Per bracket: how near one of its two stations a query must be for its
            # occupancy there to reach sigmoid(-CULL) (bracket_reach2).
            ends = table[:, :, 24:26].detach().abs().amax(dim=-1)  # f at both stations
            legs = torch.sqrt(((pts[:, 1:] - pts[:, :-1]) ** 2).sum(-1))
            bracket_reach = (ends * torch.sqrt(profile[:, :1] ** 2 + profile[:, 1:2] ** 2)
                             + legs + CULL / self.sharpness)
        return {"table": table, "bend": bend, "points": pts, "tangents": tangents,
                "box_lo": pts.amin(dim=1) - pad[:, None], "box_hi": pts.amax(dim=1) + pad[:, None],
                "coarse": coarse, "reach": pad + coarse_gap,
                "bracket_reach2": bracket_reach * bracket_reach}

    def _station_table(self, cps: torch.Tensor, profile: torch.Tensor, scaling: torch.Tensor,
                       margin: float) -> tuple[torch.Tensor, ...]:
        """_stations' table (N, S + 1, 32) and bend (N, S, 2) as torch operations (any
        device), with the extended stations' points and tangents (N, S + 2, 3) and f at
        the stations (N, S)."""
        N, S = cps.shape[0], self.stations
        t = torch.linspace(0.0, 1.0, S, dtype=cps.dtype, device=cps.device)
        fr = axis_frames(cps, t)  # each (N, S, 3)
        f = scaling_factor(scaling, t)  # (N, S)
        seg = torch.sqrt(((fr.points[:, 1:] - fr.points[:, :-1]) ** 2).sum(-1) + _EPS ** 2)
        arc = torch.cat([torch.zeros_like(seg[:, :1]), torch.cumsum(seg, dim=1)], dim=1)
        total = arc[:, -1]
        pts = torch.cat([fr.points[:, :1] - margin * fr.T[:, :1], fr.points,
                         fr.points[:, -1:] + margin * fr.T[:, -1:]], dim=1)  # (N, S+2, 3)

        def ext(x: torch.Tensor) -> torch.Tensor:
            return torch.cat([x[:, :1], x, x[:, -1:]], dim=1)

        axes = torch.stack([ext(fr.T), ext(fr.U), ext(fr.V)], dim=-1)  # (N, S+2, 3, 3)
        bias = -(pts[..., None] * axes).sum(-2, keepdim=True)  # (N, S+2, 1, 3)
        affine = torch.cat([axes, bias], dim=-2)  # (N, S+2, 4, 3)
        affine = torch.cat([affine[:, :-1], affine[:, 1:]], dim=-1)  # (N, S+1, 4, 6)
        fe = ext(f)
        arc = torch.cat([arc[:, :1] - margin, arc, arc[:, -1:] + margin], dim=1)
        per_prim = torch.cat([profile, total[:, None]], dim=1)[:, None].expand(N, S + 1, 4)
        table = torch.cat([affine.flatten(2),
                           torch.stack([fe[:, :-1], fe[:, 1:], arc[:, :-1], arc[:, 1:]], -1),
                           per_prim], dim=-1)
        curvature = axis_curvature_vectors(cps, t)  # (N, S, 3)
        bend = torch.stack([(curvature * fr.U).sum(-1), (curvature * fr.V).sum(-1)], dim=-1)
        return table, bend, pts, ext(fr.T), f

    @torch.no_grad()
    def _brackets(self, q: torch.Tensor, st: dict[str, torch.Tensor]) -> tuple[torch.Tensor, ...]:
        """Every bracket of every in-reach query (no gradient), for all primitives in one
        batched call (a Python loop over primitives cost more than the arithmetic).

        q (N, Q, 3) -> rows, pairs, bracket (V,): for each bracket [i, i+1] where h changes
        sign, its primitive, its flat (primitive, query) index and i. Only queries in the
        primitive's box and within reach of its coarse stations are tested. Most queries
        cross one plane, so listing the crossings directly (no nearest-k selection) is
        both cheaper and closer to the exact test, which considers every plane.
        """
        if self._fused_for(q):
            return _find_brackets_fused(q, st)
        pts, tan = st["points"].detach(), st["tangents"].detach()  # (N, S+2, 3)
        coarse, reach = st["coarse"].detach(), st["reach"].detach()
        q2 = (q * q).sum(-1, keepdim=True)  # (N, Q, 1)
        keep = ((q >= st["box_lo"].detach()[:, None])
                & (q <= st["box_hi"].detach()[:, None])).all(-1)  # (N, Q)
        # |q - c|^2 to every coarse station: (N, Q, Sc), one batched matmul.
        d2c = torch.baddbmm((coarse * coarse).sum(-1)[:, None], q, coarse.transpose(1, 2),
                            alpha=-2.0) + q2
        keep &= d2c.amin(dim=2) <= (reach * reach)[:, None]
        rows, cols = torch.nonzero(keep, as_tuple=True)
        # h at every station for all pairs as one batched matmul (cheaper than gathering
        # each kept pair's stations), then the kept pairs' rows.
        offs = (pts * tan).sum(-1)  # (N, S+2)
        pairs = rows * q.shape[1] + cols
        h = torch.baddbmm(-offs[:, None], q, tan.transpose(1, 2)).flatten(0, 1).index_select(
            0, pairs)  # (R, S+2)
        hit, bracket = torch.nonzero((h[:, :-1] * h[:, 1:]) <= 0.0, as_tuple=True)
        rows, pairs = rows.index_select(0, hit), pairs.index_select(0, hit)
        # Only brackets within reach of a query (bracket_reach2).
        qs = q.reshape(-1, 3).index_select(0, pairs)
        d2 = torch.minimum(((qs - pts[rows, bracket]) ** 2).sum(-1),
                           ((qs - pts[rows, bracket + 1]) ** 2).sum(-1))
        near = d2 <= st["bracket_reach2"].detach()[rows, bracket]
        return rows[near], pairs[near], bracket[near]


def _find_brackets_fused(q: torch.Tensor, st: dict[str, torch.Tensor]
                         ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """AnalyticSweeper._brackets through bracket_kernels.find_brackets (CPU tensors)."""
    from sweepedit.fitting import bracket_kernels as kernels

    arrays = [st[k].detach().contiguous().numpy() for k in
              ("points", "tangents", "box_lo", "box_hi", "coarse", "reach", "bracket_reach2")]
    queries = q.detach().contiguous().numpy()
    # Most (primitive, query) pairs cross 0-2 planes; a run holds up to ceil(N / CHUNKS)
    # primitives.
    capacity = 4 * -(-q.shape[0] // kernels.CHUNKS) * q.shape[1]
    counts = np.zeros(kernels.CHUNKS, dtype=np.int64)
    while True:
        found = [np.empty((kernels.CHUNKS, capacity), dtype=np.int64) for _ in range(3)]
        kernels.find_brackets(queries, *arrays, *found, counts)
        if counts.max() <= capacity:
            return tuple(torch.from_numpy(np.concatenate(  # type: ignore[return-value]
                [a[c, :counts[c]] for c in range(kernels.CHUNKS)])) for a in found)
        capacity = int(counts.max())


def _bracket_occupancy(table: torch.Tensor, queries: torch.Tensor, flat: torch.Tensor,
                       pair: torch.Tensor, sharpness: float, fused: bool) -> torch.Tensor:
    """The soft occupancy of each bracket (AnalyticSweeper's formula): table (M, 32) of
    AnalyticSweeper._stations, flattened over (primitive, bracket); queries (NQ, 3);
    flat, pair (V,): each bracket's table row and query -> occupancy (V,).

    fused (CPU tensors only): bracket_kernels' loops compute it and its gradient (a
    refinement step's per-bracket work 4.2 -> ~1.2 ms); else torch ops."""
    if fused:
        return _FusedBracketOccupancy.apply(table, queries, flat, pair, sharpness)
    return _bracket_occupancy_ops(table, queries, flat, pair, sharpness)


def _bracket_occupancy_ops(table: torch.Tensor, queries: torch.Tensor, flat: torch.Tensor,
                           pair: torch.Tensor, sharpness: float) -> torch.Tensor:
    """_bracket_occupancy as torch ops (autograd's gradient)."""
    rows = table.index_select(0, flat)  # (V, 32)
    aff = rows[:, :24].reshape(-1, 4, 6)
    qr = queries.index_select(0, pair)  # (V, 3)
    # Local coordinates (h, x, y) of the query in both stations' frames.
    h0, x0, y0, h1, x1, y1 = torch.baddbmm(aff[:, 3:4], qr[:, None], aff[:, :3])[:, 0].unbind(1)
    f0, f1, e0, e1, a, b, d, total = rows[:, 24:].unbind(1)
    denom = h0 - h1
    denom = torch.where(denom.abs() < 1e-12, torch.full_like(denom, 1e-12), denom)
    lam = torch.clamp(h0 / denom, 0.0, 1.0)
    xw = x0 + lam * (x1 - x0)
    yw = y0 + lam * (y1 - y0)
    f = torch.clamp(f0 + lam * (f1 - f0), min=1e-4)
    e = e0 + lam * (e1 - e0)
    level = superellipse_level(xw / f, yw / f, torch.stack([a, b, d], dim=1))
    r = torch.clamp(level, min=1e-12) ** (1.0 / d)
    rho = torch.sqrt(xw * xw + yw * yw + 1e-12)
    sd = rho - rho / torch.clamp(r, min=1e-6)
    # Intersection of the profile and the two end caps as the minimum of their signed
    # distances, so that the 0.5 level is exactly the (linearised) boundary.
    return torch.sigmoid(sharpness * torch.minimum(-sd, torch.minimum(e, total - e)))


class _FusedBracketOccupancy(torch.autograd.Function):
    """_bracket_occupancy through bracket_kernels' loops (CPU tensors)."""

    @staticmethod
    def forward(ctx: Any, table: torch.Tensor, queries: torch.Tensor, flat: torch.Tensor,
                pair: torch.Tensor, sharpness: float) -> torch.Tensor:
        from sweepedit.fitting import bracket_kernels as kernels

        table_np = table.detach().contiguous().numpy()
        queries_np = queries.detach().contiguous().numpy()
        flat_np, pair_np = flat.contiguous().numpy(), pair.contiguous().numpy()
        occupancy = np.empty(len(flat_np), dtype=table_np.dtype)
        saved = np.empty((len(flat_np), kernels.N_SAVED), dtype=table_np.dtype)
        kernels.occupancy_forward(table_np, queries_np, flat_np, pair_np, float(sharpness),
                                  occupancy, saved)
        ctx.arrays = (table_np, queries_np, flat_np, pair_np, saved)
        ctx.sharpness = float(sharpness)
        result = torch.from_numpy(occupancy)
        # Saved as a tensor, so that autograd refuses a backward after an in-place change.
        ctx.save_for_backward(result)
        return result

    @staticmethod
    def backward(ctx: Any, grad: torch.Tensor) -> tuple[torch.Tensor | None, ...]:
        from sweepedit.fitting import bracket_kernels as kernels

        table_np, queries_np, flat_np, pair_np, saved = ctx.arrays
        occupancy = ctx.saved_tensors[0].numpy()
        want_queries = bool(ctx.needs_input_grad[1])
        grad_table = np.zeros_like(table_np)
        grad_queries = np.zeros_like(queries_np) if want_queries else queries_np[:0]
        kernels.occupancy_backward(table_np, queries_np, flat_np, pair_np, ctx.sharpness,
                                   occupancy, saved,
                                   grad.detach().contiguous().numpy().astype(table_np.dtype,
                                                                             copy=False),
                                   grad_table, grad_queries, want_queries)
        return (torch.from_numpy(grad_table) if ctx.needs_input_grad[0] else None,
                torch.from_numpy(grad_queries) if want_queries else None, None, None, None)


# ----------------------------------------------------------------------------------------
# Neural sweeper
# ----------------------------------------------------------------------------------------

# The axis point nearest to each loop (loops at t = l/14, axis points at t = i/124).
_LOOP_AXIS = [round(i * (N_AXIS - 1) / (N_LOOPS - 1)) for i in range(N_LOOPS)]
# Coarse axis points for the neighbour search, and the fine window searched around them.
_COARSE_STEP = 4
_AXIS_OFFSETS = (-1, 0, 1)
_LOOP_OFFSETS = (-2, -1, 0, 1)


def _mlp(*sizes: int) -> nn.Sequential:
    layers: list[nn.Module] = []
    for i in range(len(sizes) - 1):
        layers.append(nn.Linear(sizes[i], sizes[i + 1]))
        if i < len(sizes) - 2:
            layers.append(nn.ReLU())
    return nn.Sequential(*layers)


def _squash(o: torch.Tensor, scale: float = 4.0) -> tuple[torch.Tensor, torch.Tensor]:
    """Bounded offsets: o (..., 3) -> o / (1 + |o|/scale) (..., 3) and its norm (..., 1)."""
    norm = torch.sqrt((o * o).sum(-1, keepdim=True) + 1e-12)
    factor = 1.0 / (1.0 + norm / scale)
    return o * factor, norm * factor


class NeuralSweeper(Sweeper):
    """A compact POCO-like point-cloud-to-occupancy network over the 875 key points.

    Encoder (per primitive, on its key points only). Every key point gets a local frame
    and scale computed from the key points themselves: a loop point the in-plane outward
    normal (from its loop neighbours and the axis tangent), the loop's tangent direction
    and the axis tangent, scaled by the loop's RMS radius; an axis point the axis tangent
    and the direction to its nearest loop's θ = 0 point. A point convolution over the key
    point grid (the offsets to the neighbours along θ and along t, expressed in the local
    frame) and a PointNet max-pool per loop and over the primitive give each key point a
    latent vector (`latent` wide). Everything is invariant to rotation, translation and
    scale of the primitive.

    Decoder (per query). The query's neighbours among the key points are found through
    the key point structure (no gradient): the nearest axis point (coarse-to-fine), its
    two axis neighbours, and on each of the two loops that bracket it the 4 loop points
    around the query's polar angle -- k = 11 neighbours. For each neighbour j the offset
    o_j = R_j (q - p_j) / ℓ_j in its local frame (squashed) and its projected latent form
    a feature e_j; an attention weight softmax_j(score_j) (score from the latent and the
    offset) pools the e_j, and an MLP maps the pooled feature plus the e_j in the
    neighbours' fixed order to the occupancy logit. Queries outside the primitive's padded
    bounding box, or farther from its axis than its largest radius (plus the gap between
    the coarse axis points), cannot be inside: they get occupancy 0 (logit -30) and are
    not evaluated.

    latent: key point latent width; value: width of the projected latent ν_j per
    neighbour; hidden: width of the decoder MLP. About 58k parameters by default.
    """

    def __init__(self, latent: int = 48, value: int = 8, hidden: int = 96,
                 layout: ParamLayout | None = None, n_scaling: int = 2) -> None:
        super().__init__(layout, n_scaling)
        self.config = {"latent": latent, "value": value, "hidden": hidden}
        width = 64
        self.loop_in = _mlp(18, width, width)
        self.loop_pool = _mlp(width, width)
        self.loop_out = _mlp(3 * width, width, latent)
        self.axis_out = _mlp(14 + 2 * width, width, latent)
        self.value_head = nn.Linear(latent, value + 1)  # value ν_j and score bias β_j
        self.score = nn.Linear(4, 1, bias=False)
        self.k = len(_AXIS_OFFSETS) + 2 * len(_LOOP_OFFSETS)
        feat = 4 + value
        self.decoder = _mlp(feat * (self.k + 1), hidden, 64, 1)

    # -- encoder ---------------------------------------------------------------------

    def encode(self, keypoints: torch.Tensor) -> dict[str, torch.Tensor]:
        """keypoints (N, 875, 3) -> a table of the key points for the decoder.

        Returns dict with table (N, 875, 12 + value + 1) = [p (3), R/ℓ (9), ν, β], and the
        search helpers: axis (N, 125, 3), loop centres (N, 15, 3), loop frames u, v
        (N, 15, 3), loop polar angles (N, 15, 50), box_lo, box_hi (N, 3).
        """
        axis, loops = split_keypoints(keypoints)
        N = axis.shape[0]
        centre = loops.mean(dim=2)  # (N, 15, 3): exact for the point-symmetric profile
        rel = loops - centre[:, :, None]
        ell = torch.sqrt((rel * rel).sum(-1).mean(-1) + 1e-12).clamp(min=1e-4)  # (N, 15)
        d_axis = torch.cat([axis[:, 1:2] - axis[:, :1], axis[:, 2:] - axis[:, :-2],
                            axis[:, -1:] - axis[:, -2:-1]], dim=1)
        t_axis = _normalize(d_axis)  # (N, 125, 3)
        e_t = t_axis[:, _LOOP_AXIS]  # (N, 15, 3)
        r0 = rel[:, :, 0]
        u_l = _normalize(r0 - (r0 * e_t).sum(-1, keepdim=True) * e_t)
        v_l = torch.linalg.cross(e_t, u_l)
        d_theta = torch.roll(loops, -1, 2) - torch.roll(loops, 1, 2)
        et4 = e_t[:, :, None].expand_as(loops)
        n = _normalize(torch.linalg.cross(d_theta, et4))
        orient = torch.where((n * rel).sum((-1, -2), keepdim=True) < 0, -1.0, 1.0)
        n = n * orient
        e_th = torch.linalg.cross(et4, n)
        frame = torch.stack([n, e_th, et4], dim=-2) / ell[:, :, None, None, None]  # (N,15,50,3,3)

        def local(v: torch.Tensor) -> torch.Tensor:
            return (frame * v[..., None, :]).sum(-1)

        inv = 1.0 / ell[:, :, None, None]
        f_loop = torch.stack([(rel * u_l[:, :, None]).sum(-1), (rel * v_l[:, :, None]).sum(-1)],
                             dim=-1) * inv
        f_rad = local(rel)[..., :2]
        nb_th = torch.cat([local(torch.roll(loops, -1, 2) - loops)[..., :2],
                           local(torch.roll(loops, 1, 2) - loops)[..., :2]], dim=-1)
        mask_next = torch.ones(N_LOOPS, dtype=loops.dtype, device=loops.device)
        mask_next[-1] = 0.0
        mask_prev = torch.flip(mask_next, [0])
        nxt = torch.cat([loops[:, 1:], loops[:, -1:]], dim=1)
        prv = torch.cat([loops[:, :1], loops[:, :-1]], dim=1)
        nb_t = torch.cat([local(nxt - loops) * mask_next[:, None, None],
                          local(prv - loops) * mask_prev[:, None, None]], dim=-1)
        log_ell = torch.log(ell)
        lr = torch.stack([
            (torch.cat([log_ell[:, 1:], log_ell[:, -1:]], 1) - log_ell) * mask_next,
            (torch.cat([log_ell[:, :1], log_ell[:, :-1]], 1) - log_ell) * mask_prev], dim=-1)
        ends = torch.stack([1.0 - mask_prev, 1.0 - mask_next], dim=-1)  # (15, 2)
        per_loop = torch.cat([lr, ends.expand(N, -1, -1)], dim=-1)[:, :, None].expand(
            -1, -1, LOOP_POINTS, -1)
        feats = torch.cat([f_loop, f_rad, nb_th, nb_t, per_loop], dim=-1)  # (N,15,50,18)
        z1 = self.loop_in(feats)
        g_l = self.loop_pool(z1).amax(dim=2)  # (N, 15, W)
        g = g_l.amax(dim=1)  # (N, W)
        W = z1.shape[-1]
        z_loop = self.loop_out(torch.cat([z1, g_l[:, :, None].expand(-1, -1, LOOP_POINTS, -1),
                                          g[:, None, None].expand(-1, N_LOOPS, LOOP_POINTS, -1)],
                                         dim=-1))

        # Axis points: frame from the axis tangent and the nearest loop's θ = 0 direction.
        pos = torch.arange(N_AXIS, device=axis.device, dtype=axis.dtype) * (
            (N_LOOPS - 1) / (N_AXIS - 1))
        l0 = torch.clamp(torch.floor(pos).long(), max=N_LOOPS - 2)
        w = (pos - l0.to(pos.dtype))[None, :, None]
        near = torch.round(pos).long()
        ua = u_l[:, near]
        ua = _normalize(ua - (ua * t_axis).sum(-1, keepdim=True) * t_axis)
        va = torch.linalg.cross(t_axis, ua)
        ell_a = torch.exp(log_ell[:, l0] * (1 - w[..., 0]) + log_ell[:, l0 + 1] * w[..., 0])
        frame_a = torch.stack([ua, va, t_axis], dim=-2) / ell_a[..., None, None]  # (N,125,3,3)
        ar = torch.arange(N_AXIS, device=axis.device)
        nb = []
        for off in (1, -1, 6, -6):
            j = torch.clamp(ar + off, 0, N_AXIS - 1)
            ok = ((ar + off >= 0) & (ar + off < N_AXIS)).to(axis.dtype)[None, :, None]
            nb.append((frame_a * (axis[:, j] - axis)[..., None, :]).sum(-1) * ok)
        a_ends = torch.zeros(N_AXIS, 2, dtype=axis.dtype, device=axis.device)
        a_ends[0, 0] = 1.0
        a_ends[-1, 1] = 1.0
        g_a = g_l[:, l0] * (1 - w) + g_l[:, l0 + 1] * w
        z_axis = self.axis_out(torch.cat([*nb, a_ends.expand(N, -1, -1), g_a,
                                          g[:, None].expand(-1, N_AXIS, W)], dim=-1))

        latent = torch.cat([z_axis, z_loop.reshape(N, N_LOOPS * LOOP_POINTS, -1)], dim=1)
        frames = torch.cat([frame_a.reshape(N, N_AXIS, 9),
                            frame.reshape(N, N_LOOPS * LOOP_POINTS, 9)], dim=1)
        table = torch.cat([keypoints, frames, self.value_head(latent)], dim=-1)
        # Polar angle of every loop point in its loop's (u, v) frame, increasing in θ.
        phi = torch.remainder(torch.atan2((rel * v_l[:, :, None]).sum(-1),
                                          (rel * u_l[:, :, None]).sum(-1)), 2.0 * math.pi)
        radius = torch.sqrt((rel * rel).sum(-1)).amax(dim=(1, 2))  # (N,)
        gap = torch.sqrt(((axis[:, 1:] - axis[:, :-1]) ** 2).sum(-1)).amax(dim=1)
        pad = (1.1 * radius + 2.0 * gap + 0.01)[:, None]
        coarse = axis[:, ::_COARSE_STEP]
        coarse_gap = torch.sqrt(((coarse[:, 1:] - coarse[:, :-1]) ** 2).sum(-1)).amax(dim=1)
        return {"table": table, "axis": axis, "centre": centre, "u": u_l, "v": v_l,
                "phi": phi, "box_lo": keypoints.amin(dim=1) - pad,
                "reach": 1.1 * radius + coarse_gap + 0.01,
                "box_hi": keypoints.amax(dim=1) + pad}

    # -- neighbour search ---------------------------------------------------------------

    @torch.no_grad()
    def neighbours(self, q: torch.Tensor, enc: dict[str, torch.Tensor]) -> tuple[torch.Tensor, ...]:
        """Structured k-nearest key points of the in-box queries (no gradient).

        q (N, Q, 3) -> rows, cols (R,) (primitive, query) pairs inside the primitive's
        box, and nbr (R, 11) key point indices in [0, 875).
        """
        N = q.shape[0]
        axis, centre = enc["axis"].detach(), enc["centre"].detach()
        u, v = enc["u"].detach(), enc["v"].detach()
        phi = enc["phi"].detach().contiguous()
        reach = enc["reach"].detach()
        inside = ((q >= enc["box_lo"].detach()[:, None])
                  & (q <= enc["box_hi"].detach()[:, None])).all(-1)
        coarse_idx = torch.arange(0, N_AXIS, _COARSE_STEP, device=q.device)
        window = torch.arange(-_COARSE_STEP + 1, _COARSE_STEP, device=q.device)
        a_off = torch.tensor(_AXIS_OFFSETS, device=q.device)
        m_off = torch.tensor(_LOOP_OFFSETS, device=q.device)
        rows_l, cols_l, nbr_l = [], [], []
        for n in range(N):
            cols = torch.nonzero(inside[n]).squeeze(1)
            if cols.numel() == 0:
                continue
            qs = q[n].index_select(0, cols)
            ac = axis[n, coarse_idx]
            d2 = torch.addmm((ac * ac).sum(-1), qs, ac.T, alpha=-2.0)
            best, arg = d2.min(dim=1)
            # Only queries within reach of the axis can be inside (as in the exact test).
            near = (best + (qs * qs).sum(-1)) <= reach[n] ** 2
            if not bool(near.all()):
                cols, qs, arg = cols[near], qs[near], arg[near]
                if cols.numel() == 0:
                    continue
            ic = coarse_idx[arg]
            cand = torch.clamp(ic[:, None] + window, 0, N_AXIS - 1)  # (Qn, 7)
            df = ((qs[:, None] - axis[n, cand]) ** 2).sum(-1)
            i_star = cand.gather(1, df.argmin(dim=1, keepdim=True))[:, 0]
            l0 = torch.clamp((i_star * (N_LOOPS - 1)) // (N_AXIS - 1), max=N_LOOPS - 2)
            # Polar angle of the query in every loop's frame, then its slot in each loop.
            rel = qs[:, None] - centre[n][None]  # (Qn, 15, 3)
            ang = torch.remainder(torch.atan2((rel * v[n][None]).sum(-1),
                                              (rel * u[n][None]).sum(-1)), 2.0 * math.pi)
            slot = torch.searchsorted(phi[n], ang.T.contiguous()).T  # (Qn, 15)
            idx = [torch.clamp(i_star[:, None] + a_off, 0, N_AXIS - 1)]
            for loop in (l0, l0 + 1):
                m = slot.gather(1, loop[:, None])  # (Qn, 1)
                m = torch.remainder(m + m_off, LOOP_POINTS)
                idx.append(N_AXIS + loop[:, None] * LOOP_POINTS + m)
            rows_l.append(torch.full_like(cols, n))
            cols_l.append(cols)
            nbr_l.append(torch.cat(idx, dim=1))
        if not rows_l:
            empty = torch.zeros(0, dtype=torch.long, device=q.device)
            return empty, empty, torch.zeros(0, self.k, dtype=torch.long, device=q.device)
        return torch.cat(rows_l), torch.cat(cols_l), torch.cat(nbr_l)

    # -- decoder -------------------------------------------------------------------------

    def forward_logits(self, params: torch.Tensor, queries: torch.Tensor,
                       outside: float = -30.0) -> torch.Tensor:
        """params (B, K, P), queries (B, Q, 3) -> occupancy logits (B, K, Q).

        Queries outside a primitive's box get the logit `outside`.
        """
        self._check(params, queries)
        B, K, _ = params.shape
        Q = queries.shape[1]
        N = B * K
        keypoints = sample_keypoints(params, self.layout_for(params)).reshape(N, N_KEYPOINTS, 3)
        enc = self.encode(keypoints)
        q = queries[:, None].expand(B, K, Q, 3).reshape(N, Q, 3)
        rows, cols, nbr = self.neighbours(q.detach(), enc)
        out = torch.full((N * Q,), outside, dtype=params.dtype, device=params.device)
        if rows.numel() == 0:
            return out.reshape(B, K, Q) + 0.0 * params.sum()
        table = enc["table"]
        D = table.shape[-1]
        g = table.reshape(N * N_KEYPOINTS, D).index_select(
            0, (rows[:, None] * N_KEYPOINTS + nbr).reshape(-1)).reshape(-1, self.k, D)
        qr = q.reshape(N * Q, 3).index_select(0, rows * Q + cols)  # (R, 3)
        p_j, m_j, nu_j, beta_j = torch.split(g, [3, 9, D - 13, 1], dim=-1)
        diff = qr[:, None, :] - p_j  # (R, k, 3)
        o = (m_j.reshape(-1, self.k, 3, 3) * diff[..., None, :]).sum(-1)
        o_hat, rho = _squash(o)
        geo = torch.cat([o_hat, rho], dim=-1)  # (R, k, 4)
        e = torch.cat([geo, nu_j], dim=-1)  # (R, k, 4 + value)
        att = torch.softmax(beta_j + self.score(geo), dim=1)  # (R, k, 1)
        pooled = (att * e).sum(1)
        logit = self.decoder(torch.cat([e.reshape(e.shape[0], -1), pooled], dim=-1))[:, 0]
        out = out.index_put((rows * Q + cols,), logit)
        return out.reshape(B, K, Q)

    def forward(self, params: torch.Tensor, queries: torch.Tensor) -> torch.Tensor:
        """params (B, K, P), queries (B, Q, 3) -> occupancy (B, K, Q) in [0, 1]."""
        return torch.sigmoid(self.forward_logits(params, queries))


# ----------------------------------------------------------------------------------------
# Loading
# ----------------------------------------------------------------------------------------


def build_neural(config: dict[str, Any]) -> NeuralSweeper:
    """A NeuralSweeper with the architecture hyper-parameters of `config`."""
    keys = ("latent", "value", "hidden")
    return NeuralSweeper(**{k: int(config[k]) for k in keys if k in config})


def load_neural(path: str | Path = NEURAL_WEIGHTS) -> NeuralSweeper:
    """The NeuralSweeper saved at `path` (a dict with 'config' and 'state_dict'), frozen."""
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"no neural sweeper weights at {path}; train them with "
                                "sweepedit.training.train.train_sweeper")
    blob = torch.load(path, map_location="cpu", weights_only=True)
    net = build_neural(blob["config"])
    net.load_state_dict({k: v.float() for k, v in blob["state_dict"].items()})
    net.eval()
    for p in net.parameters():
        p.requires_grad_(False)
    return net


def load_sweeper(kind: str = "analytic", weights: str | Path | None = None,
                 **kwargs: Any) -> Sweeper:
    """The default-configured sweeper of a kind: 'analytic' or 'neural'.

    weights: for 'neural', the weights file (default sweepedit/resources/sweeper_neural.pt).
    kwargs: passed to AnalyticSweeper (e.g. sharpness, stations).
    """
    if kind == "analytic":
        return AnalyticSweeper(**kwargs)
    if kind == "neural":
        return load_neural(weights if weights is not None else NEURAL_WEIGHTS)
    raise ValueError(f"unknown sweeper kind {kind!r}; expected 'analytic' or 'neural'")


def soft_union_occupancy(primitives: Sequence[SweepPrimitive], points: np.ndarray,
                         kind: str = "analytic", chunk: int = 16384) -> np.ndarray:
    """Soft occupancy of the union of primitives at points (N, 3) -> float32 (N,) in [0, 1].

    Each primitive's occupancy comes from the chosen sweeper; the union is the Boltzmann
    soft-max that fitting uses. Primitives of different layouts (control points, scaling
    terms) are swept in separate groups.
    """
    from sweepedit.fitting.losses import boltzmann_union

    points = np.asarray(points, dtype=np.float32).reshape(-1, 3)
    if not primitives or not len(points):
        return np.zeros(len(points), dtype=np.float32)
    sweeper = load_sweeper(kind)
    groups: dict[tuple[int, int], list[SweepPrimitive]] = {}
    for p in primitives:
        groups.setdefault((p.n_control_points, len(p.scaling)), []).append(p)
    out = np.empty(len(points), dtype=np.float32)
    with torch.no_grad():
        batches = []
        for (n, k), prims in groups.items():
            layout = ParamLayout(n, k)
            batches.append((layout, layout.from_primitives(prims)[None]))
        for start in range(0, len(points), chunk):
            q = torch.as_tensor(points[start:start + chunk])[None]
            occupancy = []
            for layout, params in batches:
                sweeper.layout = layout
                occupancy.append(sweeper(params, q))
            occ = torch.cat(occupancy, dim=1)
            out[start:start + chunk] = boltzmann_union(occ, torch.ones(occ.shape[:2]))[0].numpy()
    return out
