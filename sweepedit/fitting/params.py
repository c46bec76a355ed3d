"""The primitive parameter layout of the fitting code: one flat torch vector per primitive.

A batch of primitives is a tensor (B, K, P) with P = 3n + 3 + k for n control points and
k scaling coefficients, laid out as

    [c1.x, c1.y, c1.z, ..., cn.x, cn.y, cn.z,  a, b, d,  s1, ..., sk]

i.e. the control points flattened point by point, then the profile (a, b, d), then the
scaling coefficients s1..sk of f(t) = 1 + s1 t + ... + sk t^k in ascending powers of t
(as in the parameter files of docs/parameter-format.md). With the defaults n = 3, k = 2,
P = 14.

`ParamLayout` splits and joins such tensors, maps an unconstrained network output (logits)
into the valid ranges of docs/primitive.md, and converts to and from
`sweepedit.geometry.model.SweepPrimitive`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import torch

from sweepedit.errors import primitive_label
from sweepedit.geometry.model import (
    A_RANGE,
    B_RANGE,
    DEGREE_RANGE,
    SCALING_RANGE,
    SweepPrimitive,
    palette_color,
)

CONTROL_POINT_RANGE = (-0.5, 0.5)
# f(t) is kept at or above this on [0, 1] by `constrain_scaling` (the model needs > 1e-3).
MIN_SCALING_VALUE = 0.05


@dataclass(frozen=True)
class ParamLayout:
    """Layout of one primitive's parameter vector: n control points, k scaling terms."""

    n_control_points: int = 3
    n_scaling: int = 2

    def __post_init__(self) -> None:
        if self.n_control_points < 3:
            raise ValueError("a primitive needs at least 3 control points")
        if self.n_scaling < 0:
            raise ValueError("the number of scaling coefficients must be >= 0")

    @property
    def size(self) -> int:
        """P = 3n + 3 + k."""
        return 3 * self.n_control_points + 3 + self.n_scaling

    @property
    def profile_slice(self) -> slice:
        """Where a, b, d sit in the vector."""
        start = 3 * self.n_control_points
        return slice(start, start + 3)

    @property
    def scaling_slice(self) -> slice:
        """Where s1..sk sit in the vector."""
        start = 3 * self.n_control_points + 3
        return slice(start, start + self.n_scaling)

    @classmethod
    def infer(cls, size: int, n_scaling: int = 2) -> ParamLayout:
        """The layout with k = n_scaling whose vector has `size` entries."""
        n, rest = divmod(size - 3 - n_scaling, 3)
        if rest or n < 3:
            raise ValueError(f"no layout with {n_scaling} scaling terms has {size} parameters")
        return cls(n, n_scaling)

    # -- split / join --------------------------------------------------------------------

    def split(self, params: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """params (..., P) -> control_points (..., n, 3), profile (..., 3), scaling (..., k)."""
        self._check(params)
        n = self.n_control_points
        cps = params[..., : 3 * n].reshape(*params.shape[:-1], n, 3)
        return cps, params[..., self.profile_slice], params[..., self.scaling_slice]

    def join(self, control_points: torch.Tensor, profile: torch.Tensor,
             scaling: torch.Tensor) -> torch.Tensor:
        """control_points (..., n, 3), profile (..., 3), scaling (..., k) -> params (..., P)."""
        lead = control_points.shape[:-2]
        return torch.cat([control_points.reshape(*lead, -1), profile, scaling], dim=-1)

    def _check(self, params: torch.Tensor) -> None:
        if params.shape[-1] != self.size:
            raise ValueError(f"expected {self.size} parameters per primitive "
                             f"(n={self.n_control_points}, k={self.n_scaling}), "
                             f"got {params.shape[-1]}")

    # -- ranges ------------------------------------------------------------------------

    def from_unconstrained(self, logits: torch.Tensor) -> torch.Tensor:
        """Map unconstrained values (..., P) into the valid ranges, (..., P).

        Every entry goes through a sigmoid and is stretched into its range: control
        points into [-0.5, 0.5], a and b into [0.01, 0.5], d into [0.3, 5], s_i into
        [-0.5, 0.5]; then `constrain_scaling` keeps f(t) >= MIN_SCALING_VALUE on [0, 1].
        """
        return self.from_unit(torch.sigmoid(logits))

    def from_unit(self, unit: torch.Tensor) -> torch.Tensor:
        """Map values in [0, 1] (..., P) (e.g. a network's sigmoid output) into the ranges."""
        self._check(unit)
        lo, hi = self.bounds(unit.dtype, unit.device)
        params = lo + (hi - lo) * unit
        cps, profile, scaling = self.split(params)
        return self.join(cps, profile, constrain_scaling(scaling))

    def to_unconstrained(self, params: torch.Tensor, eps: float = 1e-6) -> torch.Tensor:
        """Inverse of `from_unconstrained` for valid params (..., P) -> logits (..., P).

        Values are clamped a hair inside their range so that the logits stay finite.
        """
        self._check(params)
        lo, hi = self.bounds(params.dtype, params.device)
        unit = ((params - lo) / (hi - lo)).clamp(eps, 1.0 - eps)
        return torch.log(unit) - torch.log1p(-unit)

    def bounds(self, dtype: torch.dtype = torch.float32,
               device: torch.device | str | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        """Lower and upper bounds of every entry, each (P,)."""
        n, k = self.n_control_points, self.n_scaling
        lo = [CONTROL_POINT_RANGE[0]] * 3 * n + [A_RANGE[0], B_RANGE[0], DEGREE_RANGE[0]]
        hi = [CONTROL_POINT_RANGE[1]] * 3 * n + [A_RANGE[1], B_RANGE[1], DEGREE_RANGE[1]]
        lo += [SCALING_RANGE[0]] * k
        hi += [SCALING_RANGE[1]] * k
        return (torch.tensor(lo, dtype=dtype, device=device),
                torch.tensor(hi, dtype=dtype, device=device))

    def clamp(self, params: torch.Tensor) -> torch.Tensor:
        """Clamp params (..., P) into the ranges (f(t) > 0 enforced as in from_unit)."""
        lo, hi = self.bounds(params.dtype, params.device)
        cps, profile, scaling = self.split(torch.maximum(torch.minimum(params, hi), lo))
        return self.join(cps, profile, constrain_scaling(scaling))

    # -- primitives --------------------------------------------------------------------

    def to_primitives(self, params: torch.Tensor) -> list[SweepPrimitive]:
        """params (K, P) -> K SweepPrimitives (float64 copies, palette colours)."""
        if params.ndim != 2:
            raise ValueError(f"expected params of shape (K, P), got {tuple(params.shape)}")
        cps, profile, scaling = self.split(params.detach().to("cpu", torch.float64))
        out = []
        for i in range(params.shape[0]):
            a, b, d = (float(v) for v in profile[i])
            out.append(SweepPrimitive(cps[i].numpy(), a=a, b=b, degree=d,
                                      scaling=tuple(float(s) for s in scaling[i]),
                                      color=palette_color(i)))
        return out

    def from_primitives(self, primitives: Sequence[SweepPrimitive],
                        dtype: torch.dtype = torch.float32,
                        device: torch.device | str | None = None) -> torch.Tensor:
        """K SweepPrimitives (with this layout's n and k) -> params (K, P)."""
        rows = []
        for i, p in enumerate(primitives):
            if p.n_control_points != self.n_control_points or len(p.scaling) != self.n_scaling:
                raise ValueError(
                    f"{primitive_label(i)} has {p.n_control_points} control points and "
                    f"{len(p.scaling)} scaling terms; the layout expects "
                    f"{self.n_control_points} and {self.n_scaling}")
            rows.append(np.concatenate([p.control_points.reshape(-1), p.profile,
                                        np.asarray(p.scaling, dtype=np.float64)]))
        arr = np.stack(rows) if rows else np.zeros((0, self.size))
        return torch.as_tensor(arr, dtype=dtype, device=device)


DEFAULT_LAYOUT = ParamLayout()


def constrain_scaling(scaling: torch.Tensor, min_value: float = MIN_SCALING_VALUE) -> torch.Tensor:
    """Shrink the negative coefficients so that f(t) >= min_value on [0, 1].

    scaling (..., k) -> (..., k). Since t^i <= 1 on [0, 1], f(t) >= 1 + sum_i min(s_i, 0);
    when that bound drops below min_value, the negative coefficients are scaled by the
    factor that lifts it back to min_value (positive ones are unchanged). Parameters that
    already satisfy the bound pass through unchanged. Continuous and differentiable
    almost everywhere.
    """
    if scaling.shape[-1] == 0:
        return scaling
    negative = torch.clamp(scaling, max=0.0)
    neg_sum = -negative.sum(dim=-1, keepdim=True)
    budget = 1.0 - min_value
    factor = budget / torch.clamp(neg_sum, min=budget)
    return scaling - negative + negative * factor


def params_to_primitives(params: torch.Tensor,
                         layout: ParamLayout = DEFAULT_LAYOUT) -> list[SweepPrimitive]:
    """params (K, P) -> K SweepPrimitives (see ParamLayout.to_primitives)."""
    return layout.to_primitives(params)


def primitives_to_params(primitives: Sequence[SweepPrimitive],
                         layout: ParamLayout | None = None,
                         dtype: torch.dtype = torch.float32) -> torch.Tensor:
    """K SweepPrimitives -> params (K, P); the layout defaults to the first primitive's."""
    if layout is None:
        first = primitives[0] if primitives else None
        layout = (ParamLayout(first.n_control_points, len(first.scaling))
                  if first is not None else DEFAULT_LAYOUT)
    return layout.from_primitives(primitives, dtype=dtype)
