"""Differentiable fitting in torch: parameter layout, key point sampler, sweepers.
(The neural sweeper's training is its own package, sweepedit.training.)

params.py            the (B, K, P) parameter layout (P = 3n + 3 + k: control points, then
                     a, b, d, then s1..sk in ascending powers), ranges, SweepPrimitive I/O
keypoints.py         875 key points per primitive (the neural sweeper's input)
sweepers.py          Sweeper interface: AnalyticSweeper, NeuralSweeper, load_sweeper
network.py           SweepNet: voxel / point encoder, MLP, primitive and selection heads
losses.py            reconstruction (Boltzmann union), overlap, parsimony, axis losses
warmstart.py         primitives from the skeleton's branches
fit.py               the per-shape fit: warm start, then refinement (the default "direct"
                     method) or SweepNet's network stage first ("network"); stages,
                     progress, time limit, device, restarts
refine.py            direct refinement of the fitted parameters, pruning, residual rounds
bench.py             `sweepedit bench`: fit a folder of shapes, table and contact sheet
"""

from sweepedit.fitting.keypoints import N_KEYPOINTS, sample_keypoints
from sweepedit.fitting.params import DEFAULT_LAYOUT, ParamLayout
from sweepedit.fitting.sweepers import AnalyticSweeper, NeuralSweeper, Sweeper, load_sweeper

__all__ = [
    "DEFAULT_LAYOUT", "N_KEYPOINTS", "AnalyticSweeper", "NeuralSweeper", "ParamLayout",
    "Sweeper", "load_sweeper", "sample_keypoints",
]
