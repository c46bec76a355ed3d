"""The differentiable key point sampler: the neural sweeper's view of a primitive.

Each primitive becomes 875 key points (docs/fitting.md): 125 on the axis at evenly
spaced t in [0, 1], then 15 profile loops (at evenly spaced t in [0, 1], the first and last
on the end caps' rims) of 50 points each (evenly spaced angles θ = 2πj/50 of the
superellipse, starting at θ = 0 on the +U half-axis). Layout of the 875 points:

    [axis_0 .. axis_124,  loop_0[θ_0 .. θ_49],  ...,  loop_14[θ_0 .. θ_49]]

The points come from the shared sweep math (sweepedit.geometry.sweep: axis_points and
sweep_surface, i.e. axis_frames, superellipse and scaling_factor), so they lie exactly on
the surface that the exact mesher builds, and gradients reach every parameter.

Because θ is evenly spaced with an even count and the superellipse is point-symmetric,
the mean of a loop's points is exactly its axis point; the neural sweeper uses that.
"""

from __future__ import annotations

import math

import torch

from sweepedit.fitting.params import DEFAULT_LAYOUT, ParamLayout
from sweepedit.geometry.sweep import axis_points, sweep_surface

N_AXIS = 125
N_LOOPS = 15
LOOP_POINTS = 50
N_KEYPOINTS = N_AXIS + N_LOOPS * LOOP_POINTS  # 875


def axis_parameters(dtype: torch.dtype = torch.float32,
                    device: torch.device | str | None = None) -> torch.Tensor:
    """t of the axis key points, (N_AXIS,)."""
    return torch.linspace(0.0, 1.0, N_AXIS, dtype=dtype, device=device)


def loop_parameters(dtype: torch.dtype = torch.float32,
                    device: torch.device | str | None = None) -> torch.Tensor:
    """t of the profile loops, (N_LOOPS,)."""
    return torch.linspace(0.0, 1.0, N_LOOPS, dtype=dtype, device=device)


def loop_angles(dtype: torch.dtype = torch.float32,
                device: torch.device | str | None = None) -> torch.Tensor:
    """θ of the points of a loop, (LOOP_POINTS,)."""
    return torch.arange(LOOP_POINTS, dtype=dtype, device=device) * (2.0 * math.pi / LOOP_POINTS)


def sample_keypoints(params: torch.Tensor, layout: ParamLayout = DEFAULT_LAYOUT) -> torch.Tensor:
    """Key points of a batch of primitives: params (B, K, P) -> (B, K, 875, 3).

    Also accepts params (K, P) -> (K, 875, 3). Differentiable w.r.t. every parameter.
    """
    squeeze = params.ndim == 2
    if squeeze:
        params = params[None]
    B, K, _ = params.shape
    cps, profile, scaling = layout.split(params.reshape(B * K, -1))
    dt, dev = params.dtype, params.device
    axis = axis_points(cps, axis_parameters(dt, dev))  # (BK, 125, 3)
    loops = sweep_surface(cps, profile, scaling, loop_parameters(dt, dev),
                          loop_angles(dt, dev))  # (BK, 15, 50, 3)
    out = torch.cat([axis, loops.reshape(B * K, N_LOOPS * LOOP_POINTS, 3)], dim=1)
    out = out.reshape(B, K, N_KEYPOINTS, 3)
    return out[0] if squeeze else out


def split_keypoints(keypoints: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """(..., 875, 3) -> axis points (..., 125, 3), loops (..., 15, 50, 3)."""
    axis = keypoints[..., :N_AXIS, :]
    loops = keypoints[..., N_AXIS:, :].reshape(*keypoints.shape[:-2], N_LOOPS, LOOP_POINTS, 3)
    return axis, loops
