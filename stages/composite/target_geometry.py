"""What compositing needs of one target frame alone, computed once per target frame and reused.

Re-timing shows a target frame more than once (held frames, and a target shorter than the speech
is played back and forth), and everything here depends on the target frame j and the texture size
only, not on the synthesized texture: the layer masks (§3.4.2), the skin region and the target's
colour statistics (colour match), the jaw band (§3.4.1), the blurred clothing mask, and the ray map
that renders the texture back into frame j (``render.inverse_map``, the costliest part). Kept in an
LRU cache bounded in bytes; worker threads share it.
"""
from __future__ import annotations

import dataclasses
import threading
from collections import OrderedDict

import cv2
import numpy as np

from pipeline.params import Composite
from stages.composite.layers import jaw_band, lab_stats, layer_masks, skin_region
from stages.composite.render import inverse_map, texture_footprint


RAY_MAP_SPACING = 8.0   #: at most this many texture px between solved ray-map samples (bilinear between them:
                        #: p99 error ≤ 0.09 texture px on GRID, 720p and 1080p faces against a map solved per pixel)


@dataclasses.dataclass
class TargetGeometry:
    """One target frame's part of compositing (T = texture size px; box = frame px x0, y0, x1, y1)."""
    texture: np.ndarray            # (T, T, 3) uint8 target frontal texture
    mouth: np.ndarray              # (T, T) float32 layer 1 mask
    neck: np.ndarray               # (T, T) float32 layer 3 mask (before the inpainted pixels are taken out)
    skin: np.ndarray | None        # (T, T) bool colour-match region (None without colour matching)
    lab: tuple | None              # the target's Lab (mean, std) over ``skin``; None: too few pixels
    band: np.ndarray | None        # (T, T) float32 jaw band (None without jaw correction)
    shirt: np.ndarray              # (T, T) float32 blurred clothing mask (layer 2)
    box: tuple[int, int, int, int]
    map_u: np.ndarray | None       # (y1 − y0, x1 − x0) float32 texture coordinates of each box pixel
    map_v: np.ndarray | None

    @property
    def nbytes(self) -> int:
        return sum(a.nbytes for a in (self.texture, self.mouth, self.neck, self.skin, self.band, self.shirt,
                                      self.map_u, self.map_v) if a is not None)


def target_geometry(tgt, j: int, T: int, p: Composite, frame_shape: tuple) -> TargetGeometry:
    """Compute target frame j's geometry (``tgt`` a ``composite.Target`` whose pose of frame j is valid;
    ``frame_shape`` (H, W, …) of its frames)."""
    lm = tgt.flm[j]
    texture = tgt.texture(j)
    px = T / 128.0                                     # feather and jaw band are given in px at T = 128
    mouth, neck = layer_masks(lm, T, px * p.feather_px, overlap=3.0 * px, neck_depth=p.neck_depth)
    skin = skin_region(lm, mouth) if p.colour_match else None
    lab = lab_stats(texture, skin) if p.colour_match else None
    band = jaw_band(lm, T, px * p.jaw_band_px) if p.jaw_correction else None
    shirt = cv2.GaussianBlur(tgt.clothing(j), (0, 0), 1.5)
    rvec, tvec = tgt.pose[j, :3], tgt.pose[j, 3:]
    # the blend box: the texture's footprint plus the reach of the coarsest pyramid level
    margin = 2 ** p.pyramid_levels
    box = texture_footprint(tgt.outline_points, rvec, tvec, tgt.K, frame_shape, margin=margin)
    x0, y0, x1, y1 = box
    map_u = map_v = None
    if x1 > x0 and y1 > y0:
        step = ray_map_step(x1 - x0 - 2 * margin, T)
        map_u, map_v = inverse_map(box, tgt.surface, tgt.window, rvec, tvec, tgt.K, step=step)
    return TargetGeometry(texture, mouth, neck, skin, lab, band, shirt, box, map_u, map_v)


def ray_map_step(footprint_px: int, T: int, spacing_texture_px: float = RAY_MAP_SPACING) -> int:
    """Frame px between the ray map's solved samples: the largest power of two (at least 4) that spaces them at
    most ``spacing_texture_px`` texture px apart — the same accuracy in the texture whatever the face's size in
    the frame (``footprint_px`` wide for a T px texture). A power of two because ``cv2.remap`` reads its
    coordinates in 1/32 px: k/step is exact then, while e.g. step 6 shifts the map by up to 6/64 frame px."""
    steps = 4
    while 2 * steps * T <= spacing_texture_px * max(footprint_px, 1):
        steps *= 2
    return steps


class GeometryCache:
    """``target_geometry`` per (j, T), least recently used dropped beyond ``budget_bytes``; thread-safe
    (two threads asking for one frame at once may both compute it: same result).

    A target shorter than the speech is played back and forth, which is least-recently-used's worst case:
    every frame not held is made again on every pass. The default 1 GiB (as ``media.FrameReader``'s frame
    cache) holds ≈ 240 frames of a 352 px texture on a 1080-line face (≈ 4.2 MB each), 8 s at 30 fps."""

    def __init__(self, budget_bytes: int = 1 << 30):
        self.budget, self.used = int(budget_bytes), 0
        self.items: OrderedDict = OrderedDict()
        self.lock = threading.Lock()
        self.hits = self.misses = 0

    def get(self, tgt, j: int, T: int, p: Composite, frame_shape: tuple) -> TargetGeometry:
        key = (int(j), int(T))
        with self.lock:
            g = self.items.get(key)
            if g is not None:
                self.items.move_to_end(key)
                self.hits += 1
                return g
            self.misses += 1
        g = target_geometry(tgt, j, T, p, frame_shape)
        with self.lock:
            if key not in self.items:
                self.items[key] = g
                self.used += g.nbytes
            while self.used > self.budget and len(self.items) > 1:
                _, old = self.items.popitem(last=False)
                self.used -= old.nbytes
        return g
