"""A mouth the target never showed (issue 60): ``synthesize.detail: aligned`` warps the nearest real mouths onto
the wanted lip points before the weighted median, so the rendered opening follows the wanted shape; the
paper's plain median can only repeat the nearest mouths the pool has."""
import cv2
import numpy as np
import pytest

from pipeline.face.dlib_face import LIP_POINTS
from pipeline.params import load_params
from stages.synthesize.texture_pool import TexturePool, synthesize_frame

T = 96
CX, CY, HALF_W = 48.0, 62.0, 14.0


def landmarks(opening: float) -> np.ndarray:
    """(68, 2) texture px: a face whose inner lips are ``opening`` px apart (nose fixed above)."""
    lm = np.zeros((68, 2))
    lm[:27] = np.stack([np.linspace(10, 86, 27), np.full(27, 20.0)], 1)            # brows, jaw: far off
    lm[27:36] = np.stack([np.full(9, CX) + np.linspace(-6, 6, 9), np.linspace(30, 46, 9)], 1)
    lm[36:48] = np.stack([np.linspace(25, 71, 12), np.full(12, 28.0)], 1)
    t = np.linspace(0, np.pi, 7)
    lm[48:55] = np.stack([CX - HALF_W * np.cos(t), CY - 2 - opening / 2 - 3 * np.sin(t)], 1)   # upper outer
    lm[55:60] = np.stack([CX + HALF_W * np.cos(t[1:6]), CY + 2 + opening / 2 + 3 * np.sin(t[1:6])], 1)
    u = np.linspace(0, np.pi, 5)
    lm[60:65] = np.stack([CX - 10 * np.cos(u), CY - opening / 2 * np.sin(u)], 1)                  # upper inner
    lm[65:68] = np.stack([CX + 10 * np.cos(u[1:4]), CY + opening / 2 * np.sin(u[1:4])], 1)        # lower inner
    return lm


def texture(lm: np.ndarray) -> np.ndarray:
    """(3T/2, T) I420: skin 170, lips 120, the inner mouth 25 (its polygon from the inner lip points)."""
    rgb = np.full((T, T, 3), 170, np.uint8)
    cv2.fillPoly(rgb, [np.round(lm[48:60] * 16).astype(np.int32)], (120, 120, 120), cv2.LINE_AA, 4)
    cv2.fillPoly(rgb, [np.round(lm[60:68] * 16).astype(np.int32)], (25, 25, 25), cv2.LINE_AA, 4)
    return cv2.cvtColor(rgb, cv2.COLOR_RGB2YUV_I420)


def pool(method: str, openings) -> TexturePool:
    flm = np.stack([landmarks(h) for h in openings])
    tex = np.stack([texture(lm) for lm in flm])
    P = len(openings)
    return TexturePool(pool=np.arange(P), tex=tex, flm=flm, pose=np.zeros((P, 6)), shapes=flm[:, LIP_POINTS],
                       small=tex, scale=1.0, small_cloth=np.zeros((P, T, T), bool), method=method, proxies=None,
                       detail=dict(s_max=0.45, v_min=0.45, feather_px=0.75, unsharp_sigma=0.75, unsharp_amount=0.0),
                       px=T / 128, T=T, teeth=[])


def dark_rows(rgb: np.ndarray) -> int:
    """Rows of the inner mouth (dark) in the mouth's centre column band."""
    band = rgb[:, int(CX) - 2:int(CX) + 3].astype(float).mean((1, 2))
    return int((band < 70).sum())


@pytest.mark.parametrize("method", ["aligned", "warped"])
def test_a_wider_mouth_than_the_pool_ever_showed_is_made_by_warping_the_nearest_real_mouths(method):
    """``warped`` also lays a real frame's detail (here the most open one's) over the warped median."""
    p = load_params().synthesize
    openings = np.r_[np.linspace(1.0, 4.0, 40)]                      # the target only ever half-opens its mouth
    wanted = landmarks(12.0)[LIP_POINTS]
    plain = synthesize_frame(pool("median", openings), wanted, p).rgb
    sources = [(len(openings) - 1, 1.0)] if method == "warped" else None
    warped = synthesize_frame(pool(method, openings), wanted, p, sources=sources).rgb
    assert dark_rows(plain) <= 5                                       # the median repeats the nearest: ≈ 4 px
    assert dark_rows(warped) >= 9, dark_rows(warped)                   # the wanted 12 px, within the warp's reach
    same = synthesize_frame(pool("aligned", openings), landmarks(3.0)[LIP_POINTS], p).rgb
    assert abs(dark_rows(same) - dark_rows(synthesize_frame(pool("median", openings), landmarks(3.0)[LIP_POINTS], p).rgb)) <= 1
