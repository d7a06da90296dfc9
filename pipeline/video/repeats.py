"""Repeated output frames of a re-timed video (paper 000 §3.3, last paragraph).

Re-timing (``stages/synthesize/retime.py``) may show one target frame at two consecutive output
frames; the second of them is replaced by the frame half-way to the next target frame, by
optical flow. ``synthesize`` decides the mapping; ``composite`` draws the frames: one rule,
``repeat_partners``, says which frames are interpolated and towards which target frame.
"""
from __future__ import annotations

import functools

from typing import Callable, Iterator, Sequence, Union

import cv2
import numpy as np

from pipeline.errors import ParameterError

FrameSource = Union[Sequence[np.ndarray], Callable[[int], np.ndarray]]


def repeat_partners(mapping: np.ndarray) -> np.ndarray:
    """(N,) int: for an output frame that repeats its predecessor's target frame and is followed
    by a different one, that following target frame (the half-way partner, §3.3 end); −1 for
    every other frame (shown as its target frame unchanged, a trailing repeat included)."""
    idx = np.asarray(mapping, np.int64).ravel()
    out = np.full(idx.size, -1, np.int64)
    if idx.size > 2:
        rep = (idx[1:-1] == idx[:-2]) & (idx[2:] != idx[1:-1])
        out[1:-1][rep] = idx[2:][rep]
    return out


def interpolate_repeats(source: FrameSource, mapping: np.ndarray) -> Iterator[np.ndarray]:
    """Yield the N output frames, a repeated frame replaced by the half-way frame (§3.3 end).

    Output frame i with mapping[i] == mapping[i−1] (and a different mapping[i+1]) becomes
    ``halfway_frame(target[mapping[i]], target[mapping[i+1]])``; a repeat at the last output
    frame stays a copy. Every other frame is a copy of its target frame, unchanged. Frames are
    fetched lazily, each target index once (the mapping is monotonic), and at most two are held,
    so 720p targets never need to fit in memory. ``list(interpolate_repeats(frames, mapping))``
    gives all frames at once.

    Parameters
    ----------
    source : sequence or callable
        Indexed by target frame j, or a callable get(j), giving (H, W, 3) uint8.
    mapping : ndarray
        (N,) int, target frame per output frame (``retime``).

    Yields
    ------
    ndarray
        (H, W, 3) uint8, N images (new arrays; the source frames are not modified).
    """
    get = source if callable(source) else source.__getitem__
    idx = np.asarray(mapping, np.int64).ravel()
    flow = cv2.DISOpticalFlow_create(cv2.DISOPTICAL_FLOW_PRESET_FAST)
    cache: dict[int, np.ndarray] = {}

    def fetch(j: int) -> np.ndarray:
        if j not in cache:
            cache[j] = _check_image(get(j), j)
        return cache[j]

    partner = repeat_partners(idx)
    for i, j in enumerate(idx.tolist()):
        for done in [k for k in cache if k < j]:
            del cache[done]
        if partner[i] >= 0:
            yield halfway_frame(fetch(j), fetch(int(partner[i])), flow)
        else:
            yield fetch(j).copy()


def halfway_frame(prev: np.ndarray, next_: np.ndarray, flow=None, max_side: int = 640) -> np.ndarray:
    """The frame half-way between two frames, by optical flow (paper §3.3, last paragraph).

    Average of ``prev`` warped by ½·F(prev→next) and ``next_`` warped by ½·F(next→prev).
    Flow convention (OpenCV): F_{a→b}(x) is where pixel x of a moves to in b,
    a(x) ≈ b(x + F_{a→b}(x)). A point at p in a sits at p + ½F in the middle frame, so the
    middle frame is sampled backwards, mid_a(x) = a(x − ½·F_{a→b}(x)) with cv2.remap — the flow
    is read at the destination pixel rather than the source one, exact where it is smooth.

    Parameters
    ----------
    prev, next_ : ndarray
        (H, W, 3) uint8 (any channel order).
    flow : cv2.DISOpticalFlow, optional
        Or any object with ``calc(grey0, grey1, None)``; default DIS fast preset.
    max_side : int
        The flow is estimated on the frames shrunk by an integer factor so their longer
        side is at most this (px), then scaled back up.

    Returns
    -------
    ndarray
        (H, W, 3) uint8.
    """
    if flow is None:
        flow = cv2.DISOpticalFlow_create(cv2.DISOPTICAL_FLOW_PRESET_FAST)
    g0 = cv2.cvtColor(prev, cv2.COLOR_RGB2GRAY)
    g1 = cv2.cvtColor(next_, cv2.COLOR_RGB2GRAY)
    h, w = g0.shape
    k = max(1, int(np.ceil(max(h, w) / max_side)))     # flow is smooth: estimate it on a smaller image
    if k > 1:
        small = (w // k, h // k)
        g0, g1 = cv2.resize(g0, small, interpolation=cv2.INTER_AREA), cv2.resize(g1, small, interpolation=cv2.INTER_AREA)
    a = _warp_half(prev, flow.calc(g0, g1, None), k)
    b = _warp_half(next_, flow.calc(g1, g0, None), k)
    return cv2.addWeighted(a, 0.5, b, 0.5, 0.0)


@functools.lru_cache(maxsize=4)
def _pixel_grid(h: int, w: int) -> np.ndarray:
    """(h, w, 2) float32 pixel coordinates (x, y), read-only (one per frame size, reused)."""
    grid = np.dstack(np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32)))
    grid.setflags(write=False)
    return grid


def _warp_half(image: np.ndarray, flow: np.ndarray, k: int = 1) -> np.ndarray:
    """image(x − ½·F(x)) by bilinear backward sampling; ``flow`` (h, w, 2) in pixels (dx, dy) of an image
    ``k`` times smaller than ``image``: F is it upsampled and scaled by k. One 2-channel map, built by one
    multiply-add on a cached pixel grid (−½·k·flow is exact for k ≤ 2, so the map equals gx − ½·F there)."""
    h, w = image.shape[:2]
    f = flow if k == 1 else cv2.resize(flow, (w, h), interpolation=cv2.INTER_LINEAR)
    maps = cv2.scaleAdd(f, -0.5 * k, _pixel_grid(h, w))
    return cv2.remap(image, maps, None, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)


def _check_image(image: np.ndarray, j: int) -> np.ndarray:
    img = np.ascontiguousarray(image)
    if img.dtype != np.uint8 or img.ndim != 3 or img.shape[2] != 3:
        raise ParameterError(f"target frame {j}: expected (H, W, 3) uint8, got {img.dtype} {img.shape}")
    return img
