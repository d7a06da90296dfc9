"""frontalize — 3D face model, chin extension, per-frame pose, frontal textures (paper 000 §3.2.1).

Plan (on the client, small data): sample valid frames of the training videos, build the
speaker's 3D landmark model (``model3d``: prior or factorisation, chosen by conditioning, then
pycolmap bundle adjustment), extend its depth over the canonical grid (``chin_extension``,
Eq. 7–8). Execution (dask, one task per shard of frames): pose by PnP against the model for
every frame, frontal texture of the lower face, frontal landmarks, clothing mask + Telea
inpainting (``warp``).

Store ``store/frontalize.zarr`` (same global frame axis as ingest):
    texture            (N, 3T/2, T) uint8  I420 frontal lower-face texture (clothing inpainted)
    clothing_mask      (N, T, T) bool      pixels that were clothing (before inpainting)
    frontal_landmarks  (N, 68, 2) float32  landmarks on the canonical plane, texture pixels
    pose               (N, 6) float32      rvec (rad), tvec (mm): model → camera
    pose_valid         (N,) bool
    reprojection_error (N,) float32        RMS px of the rigid landmarks
    model/shape3d (68, 3) mm, model/depth (H, W) mm, model/face_region (H, W) bool,
    model/texture_points (T, T, 3) mm;  attrs: grid, texture window, method, conditioning, BA errors

Run: ``python -m stages.frontalize.frontalize``.
"""
from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from pipeline.face import dlib_face
from pipeline.face.canonical import Surface, TextureWindow, frontal_landmarks
from pipeline.errors import LipsynthError
from pipeline.face.geometry import euler_degrees, intrinsics, solve_pose
from pipeline.io.parallel import client_for, run_tasks
from pipeline.params import Frontalize, Params
from pipeline.io.runner import stage_main
from pipeline.io.store import (atomic_output, create_group, create_timed, i420_to_rgb, occupied_shards, open_group,
                            rgb_to_i420, video_of_frames, videos_in)
from stages.frontalize import model3d
from stages.frontalize.chin_extension import extend_depth, face_depth_on_grid
from stages.frontalize.warp import clothing_mask, frontal_texture, inpaint

log = logging.getLogger("lipsynth.frontalize")


# ---------------------------------------------------------------- plan: the model
def sample_model_frames(videos: list[dict], valid: np.ndarray, max_frames: int) -> np.ndarray:
    """Evenly spaced valid frames of the non-excluded training videos (global indices)."""
    idx = np.concatenate([np.arange(v["first_frame"], v["first_frame"] + v["n_frames"]) for v in videos
                          if v["split"] == "train" and not v.get("excluded")] or [np.zeros(0, int)])
    idx = idx[valid[idx]]
    if len(idx) < 10:
        raise LipsynthError(f"only {len(idx)} valid training frames: too few to build a 3D face model")
    return idx[np.unique(np.linspace(0, len(idx) - 1, min(max_frames, len(idx))).round().astype(int))]


def build_model(lms: np.ndarray, Ks: list[np.ndarray], p: Frontalize) -> tuple[np.ndarray, dict]:
    """3D model (68, 3) mm from sampled landmarks (F, 68, 2); returns it with a report dict."""
    mean2d = model3d.mean_shape_2d(lms)
    prior = model3d.prior_shape(mean2d)
    kappa = model3d.conditioning(lms)
    method = "factorization" if kappa >= p.min_conditioning else "prior"
    start = model3d.factorize(lms) if method == "factorization" else model3d._to_canonical(prior)
    if method == "factorization" and not model3d._plausible(start):
        # a face that barely turns can pass the conditioning test on landmark noise alone (an
        # expressive mouth, a nodding head): its factorisation is then no face at all
        log.warning("3D model: the factorisation is not a face (conditioning s3/s4 = %.2f): starting from the "
                    "person's mean 2D shape with the anthropometric depth prior instead", kappa)
        method, start = "prior (factorisation not a face)", model3d._to_canonical(prior)
    shape, before, after = model3d.bundle_adjust(start, list(lms), Ks, p.ba_iterations,
                                                 fallback=model3d._to_canonical(prior))
    report = dict(method=method, conditioning=kappa, ba_rms_before=before, ba_rms_after=after, n_frames=len(lms))
    log.info("3D model: %s start (conditioning s3/s4 = %.2f, threshold %.1f), bundle adjustment over %d frames: "
             "RMS %.2f → %.2f px", method, kappa, p.min_conditioning, len(lms), before, after)
    return shape, report


def build_surface(shape: np.ndarray, p: Frontalize) -> tuple[Surface, np.ndarray]:
    """Extended depth map over the canonical grid (Eq. 7–8)."""
    step = p.grid_mm
    xs = np.arange(p.grid_x_mm[0], p.grid_x_mm[1] + 1e-9, step)
    ys = np.arange(p.grid_y_mm[0], p.grid_y_mm[1] + 1e-9, step)
    depth, known = face_depth_on_grid(shape, xs, ys)
    ext = extend_depth(np.nan_to_num(depth), known, p.data_weight, p.boundary_weight)
    return Surface(ext, float(xs[0]), float(ys[0]), step), known


MIN_TEXTURE = 128            #: px: the smallest automatic texture (the former fixed size)


def auto_texture_size(iod_crop_px: float, p: Frontalize) -> int:
    """Texture side N (px, a multiple of 16) whose pixels are as fine as the stored crops' (``frontalize.texture_size: auto``).

    Parameters
    ----------
    iod_crop_px : float
        Median outer-eye-corner distance of the face in stored-crop pixels (its IOD_MM = 90 mm).
    p : Frontalize
        ``texture_x_mm`` (the window's width in mm) and ``max_texture_size``.

    Returns
    -------
    int: width_mm × iod_crop_px / IOD_MM rounded down to 16, within [128, max_texture_size]: a
    360×288 face keeps 128, a 720×576 one gets about 2× — a texture finer than the crop adds nothing.
    """
    if not np.isfinite(iod_crop_px) or iod_crop_px <= 0:
        return min(MIN_TEXTURE, p.max_texture_size)
    n = (p.texture_x_mm[1] - p.texture_x_mm[0]) * iod_crop_px / dlib_face.IOD_MM
    return int(min(max(16 * int(n // 16), MIN_TEXTURE), p.max_texture_size))


def crop_interocular(lmg, videos: list[dict], per_video: int = 50) -> float:
    """Median outer-eye-corner distance in stored-crop pixels over up to ``per_video`` valid frames of each
    video (landmarks are in source pixels; a video's crop stores ``crop[2]`` source px per crop px)."""
    dists = []
    for v in videos:
        if v.get("excluded") or not v["n_frames"]:
            continue
        pick = np.unique(np.linspace(v["first_frame"], v["first_frame"] + v["n_frames"] - 1, per_video).round().astype(int))
        ok = np.asarray(lmg["valid"].get_orthogonal_selection((pick,)))
        if ok.any():
            lm = np.asarray(lmg["landmarks"].get_orthogonal_selection((pick[ok],)), np.float64)
            dists += list(dlib_face.interocular(lm) / float(v["crop"][2]))
    return float(np.median(dists)) if dists else float("nan")


def texture_window(p: Frontalize, size: int | None = None) -> TextureWindow:
    """The frontal texture window: ``texture_x_mm`` × ``texture_y_mm`` from its top-left corner, ``size``
    (default ``texture_size``, which must then be an int) pixels square."""
    size = int(p.texture_size if size is None else size)
    x0, x1 = p.texture_x_mm
    y0 = p.texture_y_mm[0]
    return TextureWindow(float(x0), float(y0), (x1 - x0) / size, size)


# ---------------------------------------------------------------- execution: per shard
def frontalize_block(job: dict) -> int:
    import cv2
    import zarr
    cv2.setNumThreads(1)

    p = job["params"]
    src = zarr.open_group(job["ingest"], mode="r")
    lmg = zarr.open_group(job["landmarks"], mode="r")
    dst = zarr.open_group(job["out"], mode="r+")
    a, b = job["start"], job["stop"]
    shape = np.asarray(dst["model/shape3d"][...])
    surface = Surface(np.asarray(dst["model/depth"][...]), *job["surface"])
    win = TextureWindow(**job["window"])
    points = np.asarray(dst["model/texture_points"][...])
    crops = src["crops"][a:b]
    lms = lmg["landmarks"][a:b]
    valid = lmg["valid"][a:b]
    T = win.size
    tex = np.zeros((b - a, T * 3 // 2, T), np.uint8)
    cloth = np.zeros((b - a, T, T), bool)
    flm = np.zeros((b - a, 68, 2), np.float32)
    pose = np.zeros((b - a, 6), np.float32)
    pok = np.zeros(b - a, bool)
    rerr = np.full(b - a, np.nan, np.float32)
    for v, lo, hi in video_of_frames(job["videos"], a, b):
        K = intrinsics(v["width"], v["height"], p.focal_factor)
        guess = None
        for i in range(lo - a, hi - a):
            if not valid[i] or v.get("excluded"):
                guess = None
                continue
            rvec, tvec, err = solve_pose(shape[model3d.RIGID], lms[i][model3d.RIGID], K, guess)
            iod_px = dlib_face.interocular(lms[i])
            if guess is not None and err > p.max_reprojection * iod_px:   # bad warm start: solve globally
                rvec, tvec, err = solve_pose(shape[model3d.RIGID], lms[i][model3d.RIGID], K)
            rerr[i] = err
            if err > p.max_reprojection * iod_px or tvec[2] <= 0:
                guess = None
                continue
            guess = (rvec, tvec)
            pose[i], pok[i] = np.r_[rvec, tvec], True
            rgb = i420_to_rgb(crops[i])
            texture = frontal_texture(rgb, points, rvec, tvec, K, v["crop"])
            xy = frontal_landmarks(lms[i].astype(np.float64), shape[:, :2], surface, rvec, tvec, K)
            uv = win.to_pixels(xy)
            flm[i] = uv
            m = clothing_mask(texture, uv[:17], p.cloth_dark_value, p.cloth_white_saturation,
                              p.cloth_white_value, p.cloth_dilate_px)
            texture = inpaint(texture, m, p.inpaint_radius)
            cloth[i] = m
            tex[i] = rgb_to_i420(texture)
    dst["texture"][a:b] = tex
    dst["clothing_mask"][a:b] = cloth
    dst["frontal_landmarks"][a:b] = flm
    dst["pose"][a:b] = pose
    dst["pose_valid"][a:b] = pok
    dst["reprojection_error"][a:b] = rerr
    return int(pok.sum())


def run(params: Params, ingest_path: str, landmarks_path: str, out: str, shape3d: np.ndarray | None = None) -> dict:
    """Frontalize every frame of the stores into ``out``.

    ``shape3d`` (68, 3) mm: a 3D face model to use as it is (``lipsynth speak`` passes the corpus
    model of a model folder for a target of the same speaker: pose alone is solved per frame);
    None builds the model from the training videos' frames.
    """
    p = params.frontalize
    src, lmg = open_group(ingest_path), open_group(landmarks_path)
    videos = [dict(v) for v in lmg.attrs["videos"]]
    valid = np.asarray(lmg["valid"][...])
    n, shard = len(valid), src["crops"].shards[0]
    if shape3d is None:
        pick = sample_model_frames(videos, valid, p.model_frames)
        lms = np.asarray(lmg["landmarks"].get_orthogonal_selection((pick,)), np.float64)
        by_frame = {}
        for v in videos:
            by_frame.update({i: v for i in range(v["first_frame"], v["first_frame"] + v["n_frames"])})
        Ks = [intrinsics(by_frame[i]["width"], by_frame[i]["height"], p.focal_factor) for i in pick]
        shape, report = build_model(lms, Ks, p)
    else:
        shape, report = np.asarray(shape3d, np.float64), dict(method="given")
        log.info("3D model: given (the model folder's corpus model); solving the pose of every frame")
    surface, known = build_surface(shape, p)
    if p.texture_size == "auto":
        iod = crop_interocular(lmg, videos)
        win = texture_window(p, auto_texture_size(iod, p))
        log.info("texture %d px (frontalize.texture_size: auto — the face's eye corners are %.0f px apart in the "
                 "stored crops, at most frontalize.max_texture_size=%d)", win.size, iod, p.max_texture_size)
    else:
        win = texture_window(p)
    points = win.grid_points(surface)
    T = win.size
    with atomic_output(out) as tmp, client_for(params.cluster) as client:
        g = create_group(tmp)
        mg = g.create_group("model")
        for name, arr in (("shape3d", shape), ("depth", surface.depth), ("face_region", known),
                          ("texture_points", points)):
            mg.create_array(name, data=np.asarray(arr, np.float32 if arr.dtype != bool else bool))
        create_timed(g, "texture", n, (T * 3 // 2, T), "uint8", shard, p.chunk_frames)
        create_timed(g, "clothing_mask", n, (T, T), "bool", shard, p.chunk_frames, fill_value=False)
        create_timed(g, "frontal_landmarks", n, (68, 2), "float32", shard, shard)
        create_timed(g, "pose", n, (6,), "float32", shard, shard)
        create_timed(g, "pose_valid", n, (), "bool", shard, shard, fill_value=False)
        create_timed(g, "reprojection_error", n, (), "float32", shard, shard, fill_value=float("nan"))
        ranges = occupied_shards(videos, n, shard)
        common = dict(ingest=str(Path(ingest_path).absolute()), landmarks=str(Path(landmarks_path).absolute()),
                      out=str(tmp), params=p, surface=(surface.x0, surface.y0, surface.step),
                      window=dict(x0=win.x0, y0=win.y0, mm_per_px=win.mm_per_px, size=win.size))
        jobs = [dict(common, start=a, stop=b, videos=list(videos_in(videos, a, b))) for a, b in ranges]
        frames = [sum(hi - lo for _, lo, hi in video_of_frames(videos, a, b)) for a, b in ranges]
        ok = sum(run_tasks(client, frontalize_block, jobs, "frontalize", "frame", frames))
        g.attrs.update(dict(videos=videos, model=report, texture_window=common["window"],
                            grid=dict(x0=surface.x0, y0=surface.y0, step=surface.step), focal_factor=p.focal_factor,
                            landmark_units="texture pixels", pose_units="rvec rad, tvec mm (model to camera)"))
        pose = np.asarray(g["pose"][...])
        pv = np.asarray(g["pose_valid"][...])
        if pv.any():
            ang = np.array([euler_degrees(r) for r in pose[pv, :3]])
            log.info("head pose range (yaw, pitch, roll) deg: %s", np.ptp(ang, axis=0).round(1).tolist())
        log.info("frontalized %d of %d frames", ok, sum(v["n_frames"] for v in videos))
    return report


def main(argv=None) -> int:
    return stage_main("lipsynth frontalize", __doc__, lambda p: run(p, p.ingest.out, p.landmarks.out, p.frontalize.out), argv)


if __name__ == "__main__":
    raise SystemExit(main())
