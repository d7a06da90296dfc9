"""Real footage from ../shared/data: landmark validity and frontalization stability."""
import numpy as np
import pytest
import zarr

from pipeline.face.dlib_face import IOD_MM

from tests.conftest import shared
from tests.helpers.stages import make_params, run_preprocessing

STABLE = [36, 39, 42, 45, 27, 28, 29, 30, 31, 33, 35]   # eye corners and nose


def check_corpus(out):
    lm = zarr.open_group(str(out / "landmarks.zarr"))
    fr = zarr.open_group(str(out / "frontalize.zarr"))
    in_video = np.zeros(lm["valid"].shape[0], bool)
    for v in lm.attrs["videos"]:
        in_video[v["first_frame"]:v["first_frame"] + v["n_frames"]] = True
    valid = np.asarray(lm["valid"][...])[in_video]
    assert valid.mean() >= 0.98, f"landmarks valid on only {100 * valid.mean():.1f}% of frames"
    iod_px = IOD_MM / fr.attrs["texture_window"]["mm_per_px"]      # the model's IOD in texture pixels
    flm = np.asarray(fr["frontal_landmarks"][...])
    ok = np.asarray(fr["pose_valid"][...])
    assert ok[in_video].mean() >= 0.98
    spreads = {}
    for v in fr.attrs["videos"]:
        sl = slice(v["first_frame"], v["first_frame"] + v["n_frames"])
        pts = flm[sl][ok[sl]][:, STABLE]
        spreads[v["name"]] = float(np.std(pts, axis=0).max() / iod_px)   # worst landmark, worst axis
    worst = max(spreads, key=spreads.get)
    assert spreads[worst] < 0.02, f"{worst}: frontal eye/nose landmarks vary by {100 * spreads[worst]:.2f}% IOD"
    return spreads


@pytest.mark.real
@pytest.mark.slow
def test_grid_s1_clips(grid_preprocessed):
    spreads = check_corpus(grid_preprocessed)
    assert len(spreads) == 12


@pytest.mark.real
@pytest.mark.slow
def test_obama_clips(tmp_path):
    clips = sorted(shared("obama").glob("obama_0*.mp4"))
    params = make_params(tmp_path, [str(c) for c in clips])
    run_preprocessing(params)
    check_corpus(tmp_path)
