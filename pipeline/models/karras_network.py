"""The network of Karras et al. 2017 (paper 001 §3.1, Table 1), exactly.

Input (B, 1, 64, 32): 64 audio frames (time) × 32 autocorrelation coefficients
(``pipeline.audio.speech_autocorrelation``); emotion (B, E).

    formant analysis   5 convolutions over the coefficient axis, ReLU:
                       1×3 stride 1×2 → 72, 108, 162, 243 channels (32 → 16 → 8 → 4 → 2 coefficients),
                       then 1×2 stride 1×2 → 256 (→ 1)
    articulation       5 convolutions over time, ReLU, the emotion vector concatenated to each output:
                       3×1 stride 2×1 (64 → 32 → 16 → 8 → 4), then 4×1 stride 4×1 (→ 1); 256 + E channels
    output             fully connected → 150 (linear) → the target dimension (linear), the last
                       initialised from the training targets' PCA (``init_output_from_pca``)

Training applies multiplicative noise 1.4^N(0,1) to the input of every convolution, one factor
per feature map, identical for the two samples of each temporal pair (§4.4: ``noise=True``,
batch rows 2i and 2i+1 paired). Weights: He initialisation.
"""
from __future__ import annotations

import numpy as np
import torch
from torch import nn

FORMANT_CHANNELS = (72, 108, 162, 243, 256)
NOISE_BASE = 1.4


class KarrasNetwork(nn.Module):
    def __init__(self, n_outputs: int, emotion_dim: int = 16):
        super().__init__()
        self.emotion_dim = emotion_dim
        chans = (1,) + FORMANT_CHANNELS
        self.formant = nn.ModuleList(
            [nn.Conv2d(chans[i], chans[i + 1], (1, 3), (1, 2), (0, 1)) for i in range(4)]
            + [nn.Conv2d(chans[4], chans[5], (1, 2), (1, 2))])
        width = 256 + emotion_dim
        self.articulation = nn.ModuleList(
            [nn.Conv2d(256 if i == 0 else width, 256, (3, 1), (2, 1), (1, 0)) for i in range(4)]
            + [nn.Conv2d(width, 256, (4, 1), (4, 1))])
        self.fc150 = nn.Linear(width, 150)
        self.out = nn.Linear(150, n_outputs)
        for m in self.modules():
            if isinstance(m, (nn.Conv2d, nn.Linear)):
                nn.init.kaiming_normal_(m.weight, nonlinearity="relu" if isinstance(m, nn.Conv2d) else "linear")
                nn.init.zeros_(m.bias)

    @staticmethod
    def _noise(x: torch.Tensor) -> torch.Tensor:
        """Per-feature-map factor 1.4^N(0,1), shared by rows 2i and 2i+1."""
        b, c = x.shape[:2]
        f = NOISE_BASE ** torch.randn((b + 1) // 2, c, 1, 1, device=x.device, dtype=x.dtype)
        return x * f.repeat_interleave(2, 0)[:b]

    def formant_features(self, x: torch.Tensor, noise: bool = False) -> torch.Tensor:
        """Formant analysis network: (B, 1, 64, 32) autocorrelations → (B, 256, 64, 1)."""
        for conv in self.formant:
            x = torch.relu(conv(self._noise(x) if noise else x))
        return x

    def articulate(self, x: torch.Tensor, emotion: torch.Tensor, noise: bool = False) -> torch.Tensor:
        """Articulation and output networks: (B, 256, 64, 1) formant features, (B, E) emotions → (B, n_outputs)."""
        e = emotion[:, :, None, None]
        for conv in self.articulation:
            x = torch.relu(conv(self._noise(x) if noise else x))
            x = torch.cat([x, e.expand(-1, -1, x.shape[2], 1)], 1)
        return self.out(self.fc150(x.flatten(1)))

    def forward(self, x: torch.Tensor, emotion: torch.Tensor, noise: bool = False) -> torch.Tensor:
        """(B, 1, 64, 32) autocorrelations and (B, E) emotions → (B, n_outputs)."""
        return self.articulate(self.formant_features(x, noise), emotion, noise)

    @torch.no_grad()
    def init_output_from_pca(self, mean: np.ndarray, components: np.ndarray) -> None:
        """Last layer = the targets' PCA: weight (n_outputs, 150) = componentsᵀ (zero-padded when
        fewer than 150 components are given), bias = the target mean."""
        k = min(len(components), 150)
        w = torch.zeros_like(self.out.weight)
        w[:, :k] = torch.as_tensor(np.asarray(components[:k]).T, dtype=w.dtype)
        self.out.weight.copy_(w)
        self.out.bias.copy_(torch.as_tensor(mean, dtype=w.dtype))


def multiply_adds(model: KarrasNetwork) -> int:
    """Multiply–adds of one forward pass (convolutions and fully connected layers)."""
    total, h, w = 0, 64, 32
    for conv in model.formant:
        w = (w + 2 * conv.padding[1] - conv.kernel_size[1]) // conv.stride[1] + 1
        total += conv.out_channels * h * w * conv.in_channels * conv.kernel_size[0] * conv.kernel_size[1]
    for conv in model.articulation:
        h = (h + 2 * conv.padding[0] - conv.kernel_size[0]) // conv.stride[0] + 1
        total += conv.out_channels * h * w * conv.in_channels * conv.kernel_size[0] * conv.kernel_size[1]
    return int(total + model.fc150.in_features * 150 + 150 * model.out.out_features)
