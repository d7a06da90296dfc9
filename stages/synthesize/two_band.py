"""synthesize.two_band — a mouth as sharp as a real frame and as steady as the median.

The weighted median (§3.2.2) is steady because it averages 50 frames, and soft for the same
reason. Two bands keep the best of both: the median gives the low frequencies (shape, shading,
the teeth region's layout), one real candidate frame gives the detail layer (lip texture,
teeth edges, skin pores), warped onto the median's shape.

Which real frame: a Viterbi path over the pool (``detail_sources``). The unary cost is a
frame's lip-shape distance in units of that output frame's σ² (−log of its Eq. 11 weight); the
transition cost is 0 when the next source is the next frame of the same video (real motion),
``hold_cost`` when it stays on one frame, and ``switch_cost`` otherwise. The states of a frame
are its ``K`` nearest candidates (§3.2.1) and the continuations of the previous frame's paths. Where the path switches, the old run is continued for ``fade`` frames
and cross-faded into the new one (``crossfade_plan``), so a switch never pops; the blend keeps the
sources' detail energy (``two_band``), so a fade does not soften the mouth either.

How it is warped (``align_to``): a smooth displacement field through the candidate's and the
median's lower-face landmarks (Gaussian-weighted interpolation of the 35 jaw, nose and lip
point displacements), then DIS optical flow between the landmark-warped candidate and the
median's grey image corrects what the landmarks miss; both are composed into one resampling.

Sizes: the median may come from smaller candidates, upsampled (``synthesize.median_max_size``): only
its low band is kept. The detail is taken at the texture's full size — the texture follows the face
up to ``frontalize.max_texture_size`` — with the alignment's flow found at ≤ ``flow_max`` px.

Texture arrays are (T, T, 3) uint8 RGB in the frontal texture plane; landmarks (68, 2) px.
"""
from __future__ import annotations

import functools
import threading

import cv2
import numpy as np

from pipeline.errors import ParameterError
from pipeline.video.flow import flow_at_most

LOWER_FACE = np.r_[2:15, 31:36, 48:68]        # dlib points that move with the mouth and jaw (35)


# ----------------------------------------------------------------------------- which real frame

def next_rows(frame_ids: np.ndarray) -> np.ndarray:
    """(P,) pool row holding each row's next frame (frame id + 1), or −1. Negative ids (a model's
    candidate bank) have no next frame."""
    frame_ids = np.asarray(frame_ids)
    row_of = {int(f): r for r, f in enumerate(frame_ids) if f >= 0}
    return np.array([row_of.get(int(f) + 1, -1) if f >= 0 else -1 for f in frame_ids], np.int64)


def detail_sources(costs: np.ndarray, frame_ids: np.ndarray, k: int = 8, switch_cost: float = 6.0,
                   hold_cost: float = 1.0, reach: int = 50, beam: int | None = None) -> np.ndarray:
    """The Viterbi path of detail sources (a beam search over pool rows).

    Parameters
    ----------
    costs : (N, P) float, unary cost of pool row r at output frame i: its lip-shape distance to
        frame i's wanted shape / (2σ_i²), i.e. −log of its Eq. 11 weight.
    frame_ids : (P,) int, each pool row's frame id: consecutive ids ≥ 0 are consecutive frames of
        one video; negative ids (a model's candidate bank) are never consecutive.
    k : the states of frame i are its ``k`` cheapest rows, the next frames of frame i − 1's
        states (a run may go on although its frame is not among the k nearest) and those states
        held, while they are among its ``reach`` nearest (the median's own candidates: a run never
        shows a mouth unlike the wanted one); the ``beam`` (default 2k) cheapest paths are kept.
    switch_cost, hold_cost : transition costs (units of ``costs``) of jumping to another source /
        staying on the same source frame; moving on to the source's next frame costs 0.

    Returns
    -------
    (N,) int pool rows, one per output frame.
    """
    costs = np.asarray(costs, np.float64)
    if costs.ndim != 2 or not costs.size or costs.shape[1] != len(frame_ids):
        raise ParameterError(f"detail_sources: costs {costs.shape} must be a non-empty (N, P) with P = "
                             f"{len(frame_ids)} pool rows")
    if switch_cost < 0 or hold_cost < 0 or k < 1:
        raise ParameterError(f"detail_sources: k={k}, switch_cost={switch_cost}, hold_cost={hold_cost}: "
                             "need k ≥ 1 and costs ≥ 0")
    beam = beam or 2 * k
    k = min(k, costs.shape[1])
    nxt = next_rows(frame_ids)
    states = np.argsort(costs[0], kind="stable")[:k]
    total = costs[0, states]
    history = []                                           # per frame: (states, predecessor positions)
    for i in range(1, len(costs)):
        top = np.argpartition(costs[i], k - 1)[:k] if k < costs.shape[1] else np.arange(costs.shape[1])
        limit = np.partition(costs[i], min(reach, costs.shape[1]) - 1)[min(reach, costs.shape[1]) - 1]
        cont = nxt[states]
        cont[cont >= 0] = np.where(costs[i, cont[cont >= 0]] <= limit, cont[cont >= 0], -1)
        near = costs[i, states] <= limit
        cand = np.unique(np.concatenate([top, cont[cont >= 0], states[near]]))
        best = int(np.argmin(total))
        score = np.full(len(cand), total[best] + switch_cost)             # a switch from the best path
        pred = np.full(len(cand), best)
        pos = np.searchsorted(cand, states[near])
        held = total[near] + hold_cost
        better = held < score[pos]
        score[pos[better]], pred[pos[better]] = held[better], np.flatnonzero(near)[better]
        ok = np.flatnonzero(cont >= 0)
        for s in ok[np.argsort(total[ok], kind="stable")[::-1]]:          # cheapest last: it wins ties
            j = np.searchsorted(cand, cont[s])
            if total[s] < score[j]:
                score[j], pred[j] = total[s], s
        score += costs[i, cand]
        keep = np.argsort(score, kind="stable")[:beam]
        history.append((states, pred[keep]))
        states, total = cand[keep], score[keep]
    path = np.zeros(len(costs), np.int64)
    at = int(np.argmin(total))
    path[-1] = states[at]
    for i in range(len(costs) - 1, 0, -1):
        prev_states, preds = history[i - 1]
        at = int(preds[at])
        path[i - 1] = prev_states[at]
    return path


def crossfade_plan(sources: np.ndarray, frame_ids: np.ndarray, fade: int = 3) -> list[list[tuple[int, float]]]:
    """Per output frame, the detail sources and their weights (summing to 1).

    At a switch (the source is not the previous one's next frame, nor the same frame) the old run
    continues — the pool row of the next frame id, while the pool has it — for ``fade`` frames,
    its weight falling linearly (fade/(fade+1), …, 1/(fade+1)) as the new source's rises.

    sources : (N,) pool rows (``detail_sources``); frame_ids : (P,) pool frame ids.
    """
    frame_ids = np.asarray(frame_ids)
    row_of = {int(f): r for r, f in enumerate(frame_ids) if f >= 0}
    plan = [[(int(s), 1.0)] for s in sources]
    for i in range(1, len(sources)):
        a, b = int(frame_ids[sources[i - 1]]), int(frame_ids[sources[i]])
        if a < 0 or b in (a, a + 1):
            continue
        for j in range(fade):
            row = row_of.get(a + 1 + j)
            if i + j >= len(sources) or row is None:
                break
            w_old = (fade - j) / (fade + 1)
            plan[i + j] = [(row, w_old)] + [(r, w * (1 - w_old)) for r, w in plan[i + j]]
    return plan


# ----------------------------------------------------------------------------- warp and bands

def displacement_field(src_lm: np.ndarray, dst_lm: np.ndarray, size: int, sigma: float,
                       points: np.ndarray = LOWER_FACE, step: int = 4) -> tuple[np.ndarray, np.ndarray]:
    """Backward maps (map_x, map_y), (size, size) float32: output pixel p samples the source at
    p + d(p), d the Gaussian-weighted mean of the point displacements src − dst (σ in px), with a
    zero-displacement anchor so that far from the points nothing moves."""
    s, d = np.asarray(src_lm, np.float64)[points], np.asarray(dst_lm, np.float64)[points]
    g = np.arange(0, size + step, step, dtype=np.float64)
    k = -1 / (2 * sigma ** 2)
    ex = np.exp(k * (g[:, None] - d[:, 0]) ** 2)                  # (G, P): the Gaussian is separable in x, y
    ey = np.exp(k * (g[:, None] - d[:, 1]) ** 2)
    w = ey[:, None, :] * ex[None, :, :]                            # (G, G, P)
    den = w.sum(-1) + 0.05                                         # the anchor: d = 0
    disp = np.einsum("ijp,pk->ijk", w, s - d) / den[..., None]     # (G, G, 2); einsum's own loops, no BLAS
    coarse = disp.astype(np.float32)
    ux, uy = _node_coordinates(size, step)
    fine = cv2.remap(coarse, ux, uy, cv2.INTER_LINEAR)               # bilinear between nodes, corners aligned
    px = np.arange(size, dtype=np.float32)
    return (np.ascontiguousarray(fine[..., 0] + px[None, :]), np.ascontiguousarray(fine[..., 1] + px[:, None]))


@functools.lru_cache(maxsize=8)
def _node_coordinates(size: int, step: int) -> tuple[np.ndarray, np.ndarray]:
    """(size, size) float32 grid-node coordinates of every pixel (node j sits at pixel j·step); cached and
    read-only (the worker threads share them), like ``pipeline.video.repeats._pixel_grid``."""
    at = np.arange(size, dtype=np.float32) / step
    grids = np.meshgrid(at, at)
    for g in grids:
        g.setflags(write=False)
    return grids[0], grids[1]


def align_candidates(textures: np.ndarray, src_points: np.ndarray, dst_points: np.ndarray,
                     sigma: float) -> np.ndarray:
    """Candidates warped so that their lip points land on the wanted ones (before the median).

    textures : (n, T, T, 3) RGB or (n, 3T/2, T) I420 uint8 (the frontalize store's format; the
        chroma planes move with half the displacement at half resolution).
    src_points : (n, P, 2) each candidate's points; dst_points : (P, 2) the wanted ones, px.
    sigma : px, the reach of each point's displacement (``displacement_field``).
    Returns an array like ``textures``.
    """
    out = np.empty_like(textures)
    every = np.arange(np.asarray(dst_points).shape[0])
    size = textures.shape[2]
    for j, tex in enumerate(textures):
        mx, my = displacement_field(src_points[j], dst_points, size, sigma, points=every)
        if tex.ndim == 3:
            out[j] = cv2.remap(tex, mx, my, cv2.INTER_CUBIC, borderMode=cv2.BORDER_REFLECT)
            continue
        h = size // 2
        out[j, :size] = cv2.remap(tex[:size], mx, my, cv2.INTER_CUBIC, borderMode=cv2.BORDER_REFLECT)
        hx = cv2.resize(mx, (h, h), interpolation=cv2.INTER_AREA) / 2 - 0.25      # half-res pixel centres
        hy = cv2.resize(my, (h, h), interpolation=cv2.INTER_AREA) / 2 - 0.25
        for k in range(2):            # I420: U then V, each (T/2, T/2) stored as T/4 rows of T
            plane = tex[size + k * h // 2: size + (k + 1) * h // 2].reshape(h, h)
            warped = cv2.remap(plane, hx, hy, cv2.INTER_CUBIC, borderMode=cv2.BORDER_REFLECT)
            out[j, size + k * h // 2: size + (k + 1) * h // 2] = warped.reshape(h // 2, size)
    return out


_LOCAL = threading.local()          # one DIS object per thread: it keeps state between calls


def _dis() -> cv2.DISOpticalFlow:
    if not hasattr(_LOCAL, "dis"):
        _LOCAL.dis = cv2.DISOpticalFlow_create(cv2.DISOPTICAL_FLOW_PRESET_FAST)
        _LOCAL.dis.setUseSpatialPropagation(True)
    return _LOCAL.dis


def align_to(candidate: np.ndarray, cand_lm: np.ndarray, target: np.ndarray, target_lm: np.ndarray,
             sigma: float, flow: bool = True, flow_max: int = 256) -> np.ndarray:
    """``candidate`` (T, T, 3) or grey (T, T) uint8 warped onto ``target``'s shape (RGB or grey, T × T):
    landmarks, then DIS flow from the target's grey image to the landmark-warped candidate's (both smoothed
    by σ/4). Returns an image like ``candidate``.

    The landmark warp and the flow are composed into one (bicubic) resampling of the candidate: each
    resampling softens the finest detail, which is what this layer is for. Above ``flow_max`` px the
    flow is found between area-averaged copies of that size and scaled up, and the landmark field's
    grid nodes are spaced in proportion (the flow only corrects what the landmarks miss, a smooth field)."""
    size = candidate.shape[0]
    mx, my = displacement_field(cand_lm, target_lm, size, sigma, step=max(4, 4 * size // 256))
    if not flow:
        return cv2.remap(candidate, mx, my, cv2.INTER_CUBIC, borderMode=cv2.BORDER_REFLECT)
    grey = cv2.remap(_grey(candidate), mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
    f = flow_at_most(_dis(), _grey(target), grey, flow_max,           # a(p) ≈ b(p + f(p))
                     blur_sigma=max(0.5, min(size, flow_max) / size * sigma / 4))
    gx, gy = _node_coordinates(size, 1)
    both = cv2.remap(np.dstack([mx, my]), gx + f[..., 0], gy + f[..., 1], cv2.INTER_LINEAR,
                     borderMode=cv2.BORDER_REPLICATE)                 # the landmark map read at p + f(p)
    return cv2.remap(candidate, both[..., 0], both[..., 1], cv2.INTER_CUBIC, borderMode=cv2.BORDER_REFLECT)


def _grey(image: np.ndarray) -> np.ndarray:
    """(T, T) uint8 grey of an RGB or already grey image."""
    return image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_RGB2GRAY)


HALF_SIZE_SIGMA = 5.0        #: px: band splits this wide blur at half size (``split_bands``)


def split_bands(rgb: np.ndarray, sigma: float) -> tuple[np.ndarray, np.ndarray]:
    """(low, high) float32 bands of a uint8 image: Gaussian blur with σ px and the rest.

    For σ ≥ 5 px the blur runs at half size (area-averaged, σ/2, bilinear back up; at σ = 5.5 the low
    band differs from the full-size blur's by ≈ 1 % of the detail's rms on average) — a quarter of the
    work where the band is wide (textures from 320 px)."""
    x = rgb.astype(np.float32)
    if sigma < HALF_SIZE_SIGMA:
        low = cv2.GaussianBlur(x, (0, 0), sigma)
    else:
        h, w = x.shape[:2]
        half = cv2.resize(x, (w // 2, h // 2), interpolation=cv2.INTER_AREA)
        low = cv2.resize(cv2.GaussianBlur(half, (0, 0), sigma / 2), (w, h), interpolation=cv2.INTER_LINEAR)
    return low, x - low


def two_band(median: np.ndarray, median_lm: np.ndarray, sources: list[tuple[np.ndarray, np.ndarray, float]],
             band_sigma: float, warp_sigma: float, flow: bool = True, flow_max: int = 256) -> np.ndarray:
    """The median's low band plus the weighted detail bands of real frames aligned to it.

    The detail is the sources' luma (grey) band, added to every channel alike: the colour stays the
    median's. Where a source and the median disagree — teeth in one, a dark mouth or lipstick in the
    other — a colour detail band would add the difference of two colours and tint the mouth (cyan teeth
    under red lips); a luma band only brightens or darkens.

    During a cross-fade the blend of two sources' details is rescaled to the weighted mean of their
    energies (mean square): details of different frames are partly uncorrelated, and a plain weighted
    sum of two loses up to half its energy half-way — the fade would show as a soft frame
    (variance-preserving blending; the scale is bounded to [1, √2], its value for uncorrelated halves).

    median : (T, T, 3) uint8; median_lm : (68, 2) its (weight-averaged) landmarks, px.
    sources : [(texture (T, T, 3) uint8, landmarks (68, 2), weight)], weights summing to 1.
    band_sigma : px, the split between the bands; warp_sigma : px, the landmark field's reach.
    flow_max : px, the largest size the alignment's optical flow runs at (``align_to``).
    Returns (T, T, 3) uint8.
    """
    low, _ = split_bands(median, band_sigma)
    detail = np.zeros(low.shape[:2], np.float32)
    energy = 0.0
    median_grey = _grey(median)
    for tex, lm, w in sources:            # only the luma is kept: align the sources' grey images
        aligned = align_to(_grey(tex), lm, median_grey, median_lm, warp_sigma, flow, flow_max)
        _, high = split_bands(aligned, band_sigma)
        detail += w * high
        energy += w * float(np.mean(np.square(high)))
    if len(sources) > 1:
        blended = float(np.mean(np.square(detail)))
        detail *= np.float32(np.clip(np.sqrt(energy / max(blended, 1e-12)), 1.0, np.sqrt(2.0)))
    return np.clip(low + detail[..., None] + 0.5, 0, 255).astype(np.uint8)
