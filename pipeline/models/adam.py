"""Adam (Kingma & Ba 2015) whose every bit is the same on any x86-64 CPU.

PyTorch's default Adam takes the square root of its second-moment estimate with ``torch.sqrt``, which
on CPU calls Intel MKL's vector math (``vsSqrt``). Its SSE2 code — the branch ``MKL_CBWR=COMPATIBLE``
selects, ``pipeline/simd_level.py`` — starts from ``rsqrtps``, an approximate reciprocal square root
whose last bits differ between CPU makers (seen: ``bench/cross_vendor.py``, and the instruction in a
``qemu -d in_asm`` trace of ``torch.sqrt``). Those bits reach every weight after one step. The fused
CPU kernel (``fused=True``) takes the square root with the vector unit's IEEE ``sqrtps``: correctly
rounded everywhere.
"""
from __future__ import annotations

import torch


def adam(params, lr: float) -> torch.optim.Adam:
    """``torch.optim.Adam(params, lr)`` with the fused kernel (β = 0.9, 0.999; ε = 1e-8; the same update)."""
    return torch.optim.Adam(params, lr=lr, fused=True)
