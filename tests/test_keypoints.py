"""Parameter layout and the differentiable key point sampler.

Truths from outside the code under test: the exact inside test (its own root finding)
decides on which side of the surface key points lie, torch.autograd.gradcheck checks
the gradients against finite differences, and the ranges come from docs/primitive.md.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch

from sweepedit.fitting.keypoints import (
    LOOP_POINTS,
    N_AXIS,
    N_KEYPOINTS,
    N_LOOPS,
    loop_parameters,
    sample_keypoints,
    split_keypoints,
)
from sweepedit.fitting.params import DEFAULT_LAYOUT, ParamLayout, constrain_scaling
from sweepedit.geometry.inside import inside_primitive
from sweepedit.geometry.model import SweepPrimitive, scaling_polynomial_min


def _prim_params(cps, a=0.1, b=0.06, d=2.0, s=(0.1, -0.2), dtype=torch.float64) -> torch.Tensor:
    return torch.tensor(np.concatenate([np.asarray(cps, float).reshape(-1), [a, b, d], s]),
                        dtype=dtype)


def _edge_cases(dtype=torch.float64) -> torch.Tensor:
    """(E, 14) primitives at the corners of the ranges and with awkward axes."""
    rows = [
        _prim_params([[-0.4, 0, 0], [0, 0.3, 0], [0.4, 0, 0]], 0.01, 0.01, 0.3, (0.5, -0.5)),
        _prim_params([[-0.4, 0, 0], [0, 0.3, 0], [0.4, 0, 0]], 0.5, 0.5, 5.0, (-0.5, 0.45)),
        _prim_params([[0, 0, -0.4], [0, 0, 0], [0, 0, 0.4]], 0.01, 0.5, 0.7),  # straight, along z
        _prim_params([[0, 0, -0.4], [0, 1e-7, 0], [0, 0, 0.4]], 0.2, 0.01, 1.0),  # nearly straight
        _prim_params([[-0.3, 0, 0], [0.4, 0.01, 0], [-0.3, 0.02, 0]], 0.05, 0.05, 2.0),  # folded
        _prim_params([[0.1, 0.1, 0.1], [0.1, 0.1, 0.1], [0.3, 0.2, 0.1]], 0.1, 0.1, 2.0),  # c1 = c2
        _prim_params([[-0.5, -0.5, -0.5], [0.5, 0.5, 0.5], [-0.5, 0.5, -0.5]], 0.3, 0.02, 4.0),
    ]
    return torch.stack(rows).to(dtype)


# -- layout -----------------------------------------------------------------------------


def test_layout_split_join_round_trip():
    layout = ParamLayout(4, 3)
    assert layout.size == 3 * 4 + 3 + 3
    p = torch.randn(2, 5, layout.size)
    cps, prof, scal = layout.split(p)
    assert cps.shape == (2, 5, 4, 3) and prof.shape == (2, 5, 3) and scal.shape == (2, 5, 3)
    assert torch.equal(cps[0, 0, 1], p[0, 0, 3:6])  # point by point
    assert torch.equal(prof[..., 2], p[..., 14])  # then a, b, d
    assert torch.equal(layout.join(cps, prof, scal), p)
    with pytest.raises(ValueError):
        layout.split(torch.zeros(3, 14))
    assert ParamLayout.infer(14) == DEFAULT_LAYOUT


def test_from_unconstrained_lands_in_the_ranges():
    z = torch.randn(4000, 14) * 6.0
    p = DEFAULT_LAYOUT.from_unconstrained(z)
    cps, prof, scal = DEFAULT_LAYOUT.split(p)
    assert cps.abs().max() <= 0.5
    assert prof[:, :2].min() >= 0.01 and prof[:, :2].max() <= 0.5
    assert prof[:, 2].min() >= 0.3 and prof[:, 2].max() <= 5.0
    assert scal.abs().max() <= 0.5
    for row in scal[:300].double().numpy():
        assert scaling_polynomial_min(row) >= 0.05 - 1e-6
    # Valid parameters survive the round trip through logits unchanged.
    valid = DEFAULT_LAYOUT.clamp(p)
    back = DEFAULT_LAYOUT.from_unconstrained(DEFAULT_LAYOUT.to_unconstrained(valid.double()))
    assert torch.allclose(back.float(), valid, atol=1e-4)


def test_constrain_scaling_keeps_f_positive_and_is_identity_when_valid():
    s = torch.tensor([[-0.5, -0.5], [0.3, -0.2], [-0.5, 0.5], [0.0, 0.0]])
    out = constrain_scaling(s)
    assert float(1 + out[0].sum()) >= 0.05 - 1e-6
    assert torch.equal(out[1:], s[1:])


def test_primitives_round_trip():
    p = DEFAULT_LAYOUT.from_unconstrained(torch.randn(5, 14)).double()
    prims = DEFAULT_LAYOUT.to_primitives(p)
    assert len(prims) == 5 and isinstance(prims[0], SweepPrimitive)
    for prim in prims:
        prim.validate()
    back = DEFAULT_LAYOUT.from_primitives(prims, dtype=torch.float64)
    assert torch.allclose(back, p)
    assert prims[2].scaling == tuple(float(v) for v in p[2, 12:])  # s1, s2 ascending
    with pytest.raises(ValueError):
        ParamLayout(4, 2).from_primitives(prims)


# -- key points ---------------------------------------------------------------------------


def test_shapes_and_layout():
    p = DEFAULT_LAYOUT.from_unconstrained(torch.randn(2, 3, 14))
    kp = sample_keypoints(p)
    assert kp.shape == (2, 3, N_KEYPOINTS, 3) == (2, 3, 875, 3)
    assert kp.dtype == torch.float32
    assert sample_keypoints(p[0]).shape == (3, 875, 3)
    axis, loops = split_keypoints(kp)
    assert axis.shape == (2, 3, N_AXIS, 3) and loops.shape == (2, 3, N_LOOPS, LOOP_POINTS, 3)
    cps = DEFAULT_LAYOUT.split(p)[0]
    # The axis starts at c1 and ends at c3 (clamped B-spline).
    assert torch.allclose(axis[..., 0, :], cps[..., 0, :], atol=1e-6)
    assert torch.allclose(axis[..., -1, :], cps[..., -1, :], atol=1e-6)
    # Each loop is centred on the axis point at its t (point-symmetric profile).
    assert torch.allclose(loops.mean(dim=-2)[..., 0, :], axis[..., 0, :], atol=1e-5)
    assert torch.allclose(loops.mean(dim=-2)[..., -1, :], axis[..., -1, :], atol=1e-5)


def test_gradcheck_float64():
    p = _prim_params([[-0.3, 0.1, 0.0], [0.0, 0.3, 0.2], [0.3, -0.1, 0.1]], 0.12, 0.07, 2.6,
                     (0.2, -0.3))[None, None].requires_grad_(True)
    # A subset of the outputs keeps the Jacobian small: every 7th key point.
    assert torch.autograd.gradcheck(lambda x: sample_keypoints(x)[..., ::7, :], (p,),
                                    eps=1e-6, atol=1e-5)


def test_gradients_finite_across_the_ranges():
    gen = torch.Generator().manual_seed(3)
    unit = torch.rand(64, 14, generator=gen, dtype=torch.float64)
    unit[:8, 9:12] = torch.tensor([0.0, 0.0, 0.0], dtype=torch.float64)  # a=b=0.01, d=0.3
    unit[8:16, 11] = 1.0  # d = 5
    rand = DEFAULT_LAYOUT.from_unit(unit)
    params = torch.cat([rand, _edge_cases()])[None].clone().requires_grad_(True)
    kp = sample_keypoints(params)
    assert torch.isfinite(kp).all()
    (kp * torch.randn_like(kp)).sum().backward()
    assert torch.isfinite(params.grad).all()
    assert (params.grad.abs().sum(dim=(0, 1)) > 0).all()  # every parameter matters


def test_keypoints_lie_on_the_exact_surface():
    """Loop points pulled 3% towards the axis are inside by the exact test, pushed 3%
    out are outside; interior axis points are inside."""
    prims = [
        _prim_params([[-0.35, -0.1, 0.0], [0.0, 0.25, 0.1], [0.35, -0.1, -0.1]], 0.08, 0.05,
                     2.0, (0.2, -0.3)),
        _prim_params([[0.0, -0.3, 0.0], [0.1, 0.0, 0.0], [0.0, 0.3, 0.1]], 0.15, 0.04, 4.0,
                     (-0.3, 0.1)),
        _prim_params([[-0.3, 0.0, 0.2], [0.0, 0.0, 0.0], [0.3, 0.1, -0.2]], 0.1, 0.1, 0.8,
                     (0.4, 0.0)),
    ]
    for p in prims:
        kp = sample_keypoints(p[None, None])[0, 0].numpy()
        axis, loops = kp[:N_AXIS], kp[N_AXIS:].reshape(N_LOOPS, LOOP_POINTS, 3)
        t_loops = loop_parameters(torch.float64).numpy()
        centre = loops.mean(axis=1, keepdims=True)
        inner = (centre + 0.97 * (loops - centre))[1:-1].reshape(-1, 3)
        outer = (centre + 1.03 * (loops - centre))[1:-1].reshape(-1, 3)
        arr = p.numpy()
        prim = SweepPrimitive(arr[:9].reshape(3, 3), a=arr[9], b=arr[10], degree=arr[11],
                              scaling=tuple(arr[12:]))
        assert inside_primitive(inner, prim).all()
        assert not inside_primitive(outer, prim).any()
        assert inside_primitive(axis[2:-2], prim).all()
        assert np.isclose(t_loops[0], 0.0) and np.isclose(t_loops[-1], 1.0)
