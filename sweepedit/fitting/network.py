"""SweepNet's network: an encoder of the input shape, an MLP and two heads.

The voxel encoder (1->32->64->128->256 channels, kernel 4, stride 2, then 256 with
kernel 4 to a 256-d code) and the MLP 256->512->1024->2048 follow the paper; for point
clouds a small DGCNN-style encoder (EdgeConv over kNN graphs) replaces the voxels.
The primitive head outputs K parameter vectors in [0, 1] (sigmoid) that
sweepedit.fitting.params maps into the parameter ranges; the selection head outputs K
logits (soft sigmoid weights while fitting; logit > 0 keeps a primitive at the end).

Per-shape fitting starts from a warm start: the last layer of each head is zero-
initialised and its bias set to the warm start's logits, so the network's first output
is exactly the warm start and fitting learns the residual.
"""

from __future__ import annotations

import itertools

import torch
from torch import nn

CODE_DIM = 256
FEATURE_DIM = 2048


class VoxelEncoder(nn.Module):
    """(B, 1, 64, 64, 64) occupancy -> (B, 256) code."""

    def __init__(self) -> None:
        super().__init__()
        layers: list[nn.Module] = []
        channels = [1, 32, 64, 128, 256]
        for c_in, c_out in itertools.pairwise(channels):
            layers += [nn.Conv3d(c_in, c_out, 4, stride=2, padding=1), nn.LeakyReLU(0.02)]
        layers += [nn.Conv3d(256, CODE_DIM, 4, stride=1, padding=0), nn.LeakyReLU(0.02)]
        self.net = nn.Sequential(*layers)

    def forward(self, voxels: torch.Tensor) -> torch.Tensor:
        return self.net(voxels).flatten(1)


def _knn_features(x: torch.Tensor, k: int) -> torch.Tensor:
    """EdgeConv input: x (B, C, N) -> (B, 2C, N, k) of [x_j - x_i, x_i] over k neighbours."""
    B, C, N = x.shape
    pts = x.transpose(1, 2)  # (B, N, C)
    idx = torch.cdist(pts, pts).topk(k, dim=-1, largest=False).indices  # (B, N, k)
    neighbours = torch.gather(pts.unsqueeze(1).expand(B, N, N, C), 2,
                              idx.unsqueeze(-1).expand(B, N, k, C))  # (B, N, k, C)
    centre = pts.unsqueeze(2).expand(B, N, k, C)
    return torch.cat([neighbours - centre, centre], dim=-1).permute(0, 3, 1, 2)


class PointEncoder(nn.Module):
    """DGCNN-style: (B, N, 3) points -> (B, 256) code (N ~ 1-2k points)."""

    def __init__(self, k: int = 16) -> None:
        super().__init__()
        self.k = k
        self.edge1 = nn.Sequential(nn.Conv2d(6, 64, 1), nn.LeakyReLU(0.2))
        self.edge2 = nn.Sequential(nn.Conv2d(128, 128, 1), nn.LeakyReLU(0.2))
        self.out = nn.Sequential(nn.Conv1d(64 + 128, CODE_DIM, 1), nn.LeakyReLU(0.2))

    def forward(self, points: torch.Tensor) -> torch.Tensor:
        x = points.transpose(1, 2)
        x1 = self.edge1(_knn_features(x, self.k)).max(dim=-1).values
        x2 = self.edge2(_knn_features(x1, self.k)).max(dim=-1).values
        return self.out(torch.cat([x1, x2], dim=1)).max(dim=-1).values


class SweepNet(nn.Module):
    """Encoder + MLP + primitive head + selection head.

    forward(shape_input) -> (params in [0, 1] (B, K, P), selection logits (B, K)).
    """

    def __init__(self, n_primitives: int, n_params: int, point_input: bool = False) -> None:
        super().__init__()
        self.n_primitives = n_primitives
        self.n_params = n_params
        self.encoder: nn.Module = PointEncoder() if point_input else VoxelEncoder()
        self.mlp = nn.Sequential(
            nn.Linear(CODE_DIM, 512), nn.LeakyReLU(0.02),
            nn.Linear(512, 1024), nn.LeakyReLU(0.02),
            nn.Linear(1024, FEATURE_DIM), nn.LeakyReLU(0.02),
        )
        self.primitive_head = nn.Linear(FEATURE_DIM, n_primitives * n_params)
        self.selection_head = nn.Linear(FEATURE_DIM, n_primitives)

    def warm_start(self, param_logits: torch.Tensor, selection_logits: torch.Tensor) -> None:
        """Make the heads output exactly these logits: (K, P) and (K,)."""
        with torch.no_grad():
            for head, bias in ((self.primitive_head, param_logits),
                               (self.selection_head, selection_logits)):
                head.weight.zero_()
                head.bias.copy_(bias.reshape(-1))

    def heads(self, code: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """A (B, 256) code -> params (B, K, P) in [0, 1] and selection logits (B, K)."""
        feature = self.mlp(code)
        params = torch.sigmoid(self.primitive_head(feature))
        return params.view(-1, self.n_primitives, self.n_params), self.selection_head(feature)

    def forward(self, shape_input: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        return self.heads(self.encoder(shape_input))
