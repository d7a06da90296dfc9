"""pca — mouth-shape features (paper 000 §3.1, "Mouth Shape Features").

The 18 lip fiducials of each frontalized frame (dlib outer lip 48–59 and inner lip 61–63,
65–67; the inner corners 60 and 64 duplicate the outer corners' motion and are left out, as
the paper's 18-point tracker has none) in canonical texture pixels → a 36-D vector → PCA with
20 components fitted on the training split only. Coefficients are stored per video frame, and
a 100 Hz copy on the MFCC time axis (linear interpolation of the coefficients, as the paper
does) is stored for training.

Store ``store/pca.zarr``:
    coeffs        (N, 20) float32   per video frame (NaN where the frame has no valid shape)
    valid         (N,) bool
    coeffs_100hz  (M, 20) float32   on ingest's MFCC axis (same M, same per-video offsets)
    valid_100hz   (M,) bool         both neighbouring frames valid
    mean (36,), components (20, 36), explained_variance (20,), explained_variance_ratio (20,)
    attrs: lip_points, fingerprint (hash of mean+components), iod_px (canonical IOD), videos

Run: ``python -m stages.pca.pca``.
"""
from __future__ import annotations

import logging

import numpy as np

from pipeline.errors import LipsynthError
from pipeline.face.dlib_face import IOD_MM, LIP_POINTS
from pipeline.models.mouth_pca import fingerprint, lip_vectors, project, resample_to_100hz
from pipeline.params import Params
from pipeline.io.runner import stage_main
from pipeline.io.store import atomic_output, create_group, create_timed, open_group

log = logging.getLogger("lipsynth.pca")


def fit_pca(x: np.ndarray, n_components: int) -> dict:
    """PCA of (n, 36) vectors by SVD. Returns mean (36,), components (k, 36), explained variance."""
    if len(x) <= n_components:
        raise LipsynthError(f"PCA needs more than {n_components} valid training frames, got {len(x)}")
    mean = x.mean(0)
    _, s, vt = np.linalg.svd(x - mean, full_matrices=False)
    var = s ** 2 / (len(x) - 1)
    comps = vt[:n_components]
    comps *= np.where(comps[np.arange(n_components), np.abs(comps).argmax(1)] < 0, -1, 1)[:, None]  # sign convention
    return dict(mean=mean, components=comps, explained_variance=var[:n_components],
                explained_variance_ratio=var[:n_components] / var.sum())


def run(params: Params, ingest_path: str, landmarks_path: str, frontalize_path: str, out: str) -> dict:
    p = params.pca
    src, lmg, fr = open_group(ingest_path), open_group(landmarks_path), open_group(frontalize_path)
    videos = [dict(v) for v in fr.attrs["videos"]]
    flm = np.asarray(fr["frontal_landmarks"][...], np.float64)
    valid = np.asarray(fr["pose_valid"][...]) & np.asarray(lmg["valid"][...])
    x = lip_vectors(flm)
    train = np.zeros(len(x), bool)
    for v in videos:
        if v["split"] == "train" and not v.get("excluded"):
            train[v["first_frame"]:v["first_frame"] + v["n_frames"]] = True
    basis = fit_pca(x[train & valid], p.n_components)
    coeffs = np.where(valid[:, None], project(x, basis), np.nan).astype(np.float32)
    frame_time = np.asarray(src["frame_time"][...])
    M = src["mfcc"].shape[0]
    c100 = np.zeros((M, p.n_components), np.float32)
    v100 = np.zeros(M, bool)
    for v in videos:
        f0, n, m0, m = v["first_frame"], v["n_frames"], v["first_mfcc"], v["n_mfcc"]
        c100[m0:m0 + m], v100[m0:m0 + m] = resample_to_100hz(
            np.nan_to_num(coeffs[f0:f0 + n]), valid[f0:f0 + n] & ~v.get("excluded", False), frame_time[f0:f0 + n], m)
    iod_px = IOD_MM / fr.attrs["texture_window"]["mm_per_px"]
    with atomic_output(out) as tmp:
        g = create_group(tmp, dict(lip_points=LIP_POINTS, fingerprint=fingerprint(basis), iod_px=iod_px,
                                   videos=videos, n_components=p.n_components,
                                   units="canonical texture pixels"))
        shard = src["crops"].shards[0]
        create_timed(g, "coeffs", len(x), (p.n_components,), "float32", shard, shard,
                     fill_value=float("nan"))[:] = coeffs
        create_timed(g, "valid", len(x), (), "bool", shard, shard, fill_value=False)[:] = valid
        create_timed(g, "coeffs_100hz", M, (p.n_components,), "float32", 6000, 6000)[:] = c100
        create_timed(g, "valid_100hz", M, (), "bool", 6000, 6000, fill_value=False)[:] = v100
        for k, val in basis.items():
            g.create_array(k, data=np.asarray(val, np.float32))
    cum = np.cumsum(basis["explained_variance_ratio"])
    log.info("PCA of %d training lip shapes: %d components explain %.1f%% (first 5: %.1f%%); fingerprint %s",
             int((train & valid).sum()), p.n_components, 100 * cum[-1], 100 * cum[min(4, len(cum) - 1)],
             fingerprint(basis))
    return basis


def main(argv=None) -> int:
    return stage_main("lipsynth pca", __doc__, lambda p: run(p, p.ingest.out, p.landmarks.out, p.frontalize.out, p.pca.out), argv)


if __name__ == "__main__":
    raise SystemExit(main())
