"""The time-delayed LSTM network of paper 000 §3.1.1 (Eq. 1–6) and how to run it on new audio.

One unidirectional LSTM layer (60 cells) and a linear read-out map normalised 28-D MFCC
features (100 Hz) to 20 mouth PCA coefficients; the output at step t is the mouth shape of step
t − d (target delay d), so the network hears d steps of the future before it commits to a shape.
Training is the ``train`` stage's (``stages/train/lstm.py``); this module is what a model folder
needs at synthesis time.
"""
from __future__ import annotations

import numpy as np
import torch
from torch import nn


def pick_device(name: str = "auto") -> torch.device:
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    return torch.device(name)


class DelayedLSTM(nn.Module):
    """LSTM(n_in → hidden) + Linear(hidden → n_out); ``delay`` is carried as metadata.

    ``skip``: a second, bias-free linear map from the input straight to the output, added to the
    read-out (a person's read-out of the encoder states themselves: ``stages/train/adapt.py``)."""

    def __init__(self, n_in: int = 28, hidden: int = 60, n_out: int = 20, layers: int = 1, skip: bool = False):
        super().__init__()
        self.lstm = nn.LSTM(n_in, hidden, num_layers=layers, batch_first=True)
        self.out = nn.Linear(hidden, n_out)
        self.skip = nn.Linear(n_in, n_out, bias=False) if skip else None

    def forward(self, x: torch.Tensor, state=None):
        """x (B, T, n_in) → (B, T, n_out), new state."""
        h, state = self.lstm(x, state)
        y = self.out(h)
        return (y if self.skip is None else y + self.skip(x)), state


@torch.no_grad()
def predict_sequence(model: DelayedLSTM, x: np.ndarray, delay: int, device, chunk: int | None = None) -> np.ndarray:
    """Mouth coefficients (m, n_out) for normalised features x (m, n_in), state carried over chunks.

    Runs the m + d delayed steps (zero-padded input) and drops the first d outputs, so output i
    is the shape at step i. ``chunk`` (steps) streams the input through the LSTM piecewise; the
    result equals one pass.
    """
    model.eval()
    xd = np.concatenate([x, np.zeros((delay, x.shape[1]), np.float32)]).astype(np.float32)
    chunk = chunk or len(xd)
    outs, state = [], None
    for a in range(0, len(xd), chunk):
        xb = torch.from_numpy(xd[None, a:a + chunk]).to(device)
        yb, state = model(xb, state)
        outs.append(yb[0].cpu().numpy())
    return np.concatenate(outs)[delay:delay + len(x)]
