"""composite — put the synthesized lower face into the target video (paper 000 §3.4).

For every output frame i showing target frame j (after re-timing): jaw correction of the
synthesized texture against the target's frontal texture (§3.4.1), the four layers as one alpha
in the canonical texture (``layers``), both rendered back into frame j through its pose and the
extended face surface (``render``), a Laplacian-pyramid blend over the target frame, and
H.264/yuv420p encoding at the target's frame rate with the source audio as AAC.

Input ``store/synthesize.zarr`` (see stages/synthesize); output ``composite.out_dir``/result.mp4,
replaced atomically, plus an optional side-by-side diagnostic video result.diagnostic.mp4
(target | result | synthesized texture with the predicted lip points).

Run: ``python -m stages.composite.composite``.
"""
from __future__ import annotations

import contextlib
import logging
import time
from collections import deque
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import cv2
import numpy as np
from tqdm import tqdm

from pipeline.io import media
from pipeline.face.canonical import Surface, TextureWindow
from pipeline.face.geometry import intrinsics
from pipeline.video.repeats import halfway_frame, repeat_partners
from pipeline.params import Composite, Params
from pipeline.io.runner import stage_main, write_timing
from pipeline.io.threads import library_threads
from pipeline.io.store import atomic_output, i420_to_rgb, open_group
from stages.composite.layers import colour_match, jaw_correction, pyramid_blend, synth_alpha
from stages.composite import self_check
from stages.composite.render import render
from stages.composite.target_geometry import GeometryCache

log = logging.getLogger("lipsynth.composite")


class Target:
    """The target video's frames and per-frame geometry, from the stores it was preprocessed into.

    ``frontalize`` is the frontalize store that holds the target, ``video`` its index entry and
    ``video_path`` the source file its full frames are read from.
    """

    def __init__(self, frontalize, video: dict, video_path):
        self.fr = frontalize
        self.video = video
        self.reader = media.FrameReader(video_path)
        self.K = intrinsics(self.video["width"], self.video["height"], self.fr.attrs["focal_factor"])
        g = self.fr.attrs["grid"]
        self.surface = Surface(np.asarray(self.fr["model/depth"][...], np.float64), g["x0"], g["y0"], g["step"])
        self.window = TextureWindow(**self.fr.attrs["texture_window"])
        points = np.asarray(self.fr["model/texture_points"][...], np.float64)      # (T, T, 3) mm
        keep = np.unique(np.r_[0:len(points):4, len(points) - 1])
        self.outline_points = points[keep][:, keep]    # every 4th texture point and the border: the footprint
        f0, n = self.video["first_frame"], self.video["n_frames"]
        self.pose = np.asarray(self.fr["pose"][f0:f0 + n], np.float64)
        self.pose_ok = np.asarray(self.fr["pose_valid"][f0:f0 + n])
        self.flm = np.asarray(self.fr["frontal_landmarks"][f0:f0 + n], np.float64)
        self.f0 = f0
        self.geometry = GeometryCache()                 # per target frame: masks, colour statistics, ray map

    BLOCK = 64                                          # target frames read from the store at once

    def _block(self, j: int) -> tuple[np.ndarray, np.ndarray]:
        b = j // self.BLOCK
        cached = getattr(self, "_cached", (None,))            # one read per block; safe across threads
        if cached[0] != b:
            sl = slice(self.f0 + b * self.BLOCK, self.f0 + min((b + 1) * self.BLOCK, self.video["n_frames"]))
            cached = (b, np.asarray(self.fr["texture"][sl]), np.asarray(self.fr["clothing_mask"][sl]))
            self._cached = cached
        return cached[1][j % self.BLOCK], cached[2][j % self.BLOCK]

    def texture(self, j: int) -> np.ndarray:
        """Frontal texture (T, T, 3) uint8 RGB of target frame j."""
        return i420_to_rgb(self._block(j)[0])

    def expected_landmarks(self, j: int, synthesized: np.ndarray) -> np.ndarray:
        """Where the landmarks (68, 2) of output frame showing target frame j should lie, in frame px:
        the target's own, with the mouth (48–67) of ``synthesized`` (68, 2) texture px and the chin
        (6–10) moved as the synthesized lower lip moved from the target's."""
        lm = self.flm[j].copy()
        lm[self_check.CHIN] += (synthesized[self_check.LOWER_LIP] - lm[self_check.LOWER_LIP]).mean(0)
        lm[48:68] = synthesized[48:68]
        return self_check.to_frame(lm, self.surface, self.window, self.pose[j, :3], self.pose[j, 3:], self.K)

    def mouth_energy_reference(self, n: int = 30) -> float:
        """90th percentile of the mouth box's Laplacian energy over ``n`` evenly spaced posed frames."""
        posed = np.flatnonzero(self.pose_ok)
        if not len(posed):
            return float("nan")
        pick = posed[np.unique(np.linspace(0, len(posed) - 1, min(n, len(posed))).round().astype(int))]
        e = [self_check.mouth_energy(self.reader.get(int(j)), self.expected_landmarks(int(j), self.flm[j])) for j in pick]
        return float(np.nanpercentile(e, 90))

    def clothing(self, j: int) -> np.ndarray:
        """Clothing mask (T, T) float32 {0, 1} of target frame j."""
        return self._block(j)[1].astype(np.float32)


def composite_frame(frame: np.ndarray, synth_rgb: np.ndarray, j: int, tgt: Target, p: Composite,
                    timing: dict | None = None, inpainted: np.ndarray | None = None) -> np.ndarray:
    """One output frame: target frame j (H, W, 3) with the synthesized texture (T, T, 3) blended in.

    ``inpainted`` (T, T) uint8: how much (×255) of each synthesized pixel came from inpainted
    clothing; those pixels are kept out of the neck layer.
    """
    t0 = time.perf_counter()
    if not tgt.pose_ok[j]:
        return frame                                   # no face geometry for this frame: keep the target
    g = tgt.geometry.get(tgt, j, synth_rgb.shape[0], p, frame.shape)
    x0, y0, x1, y1 = g.box
    if g.map_u is None:
        return frame
    t1 = time.perf_counter()
    neck = g.neck
    if inpainted is not None:
        neck = neck * (1 - cv2.GaussianBlur(inpainted.astype(np.float32) / 255, (0, 0), 1.5))
    if p.colour_match:
        synth_rgb = colour_match(synth_rgb, g.texture, g.skin, g.lab)
    if p.jaw_correction:
        synth_rgb = jaw_correction(synth_rgb, g.texture, g.band)
    t2 = time.perf_counter()
    alpha = synth_alpha(g.mouth, neck, g.shirt)
    layer = np.dstack([synth_rgb, np.round(alpha * 255).astype(np.uint8)])
    rendered, cover = render(layer, g.map_u, g.map_v)
    t3 = time.perf_counter()
    a = rendered[..., 3].astype(np.float32) / 255 * cover
    back = frame[y0:y1, x0:x1]
    rgb = cv2.cvtColor(rendered, cv2.COLOR_RGBA2RGB)     # the colour channels, contiguous
    if p.sharpen > 0:              # give back the detail the resampling chain took (unsharp mask)
        rgb = cv2.addWeighted(rgb, 1 + p.sharpen, cv2.GaussianBlur(rgb, (0, 0), p.sharpen_sigma), -p.sharpen, 0)
    # outside the layer's support the front image is the target itself, so the pyramid's coarse
    # levels blend the synthesized face with the target only where they actually differ
    support = cv2.dilate((a > 1e-3).astype(np.uint8), np.ones((5, 5), np.uint8))
    front = cv2.copyTo(rgb, support, back.copy())
    out = frame.copy()
    out[y0:y1, x0:x1] = pyramid_blend(front, back, a, p.pyramid_levels)
    if timing is not None:
        t4 = time.perf_counter()
        for k, dt in (("target_geometry", t1 - t0), ("flow", t2 - t1), ("render_back", t3 - t2), ("blend", t4 - t3)):
            timing[k] = timing.get(k, 0.0) + dt
    return out


def diagnostic(target: np.ndarray, result: np.ndarray, texture: np.ndarray, lip_uv: np.ndarray) -> np.ndarray:
    """Side-by-side (target | result | synthesized texture with the predicted lip points), same height.

    ``texture`` is the (T, T, 3) synthesized texture, ``lip_uv`` (18, 2) the predicted lip points
    in its pixels; the texture panel is scaled to the frame height.
    """
    h = target.shape[0]
    s = h / texture.shape[0]
    panel = cv2.resize(texture, (h, h), interpolation=cv2.INTER_LINEAR)
    for u, v in lip_uv:
        cv2.circle(panel, (int(round(u * s)), int(round(v * s))), max(2, h // 150), (255, 40, 40), -1, cv2.LINE_AA)
    return np.hstack([target, result, panel])


def composite_one(frame: np.ndarray, following: np.ndarray | None, texture: np.ndarray, j: int, inpainted: np.ndarray,
                  tgt: Target, p: Composite, candidate: np.ndarray, reference: float | None):
    """One output frame (runs on a worker thread): the target frame (half-way to ``following`` for a repeated
    frame), the texture composited into it, and its self-check. Returns (frame, result, phase seconds, check)."""
    t: dict = {}
    if following is not None:
        t0 = time.perf_counter()
        frame = halfway_frame(frame, following)
        t["retime_flow"] = time.perf_counter() - t0
    result = composite_frame(frame, texture, j, tgt, p, t, inpainted)
    check = None
    if p.self_check and tgt.pose_ok[j]:
        t0 = time.perf_counter()
        check = self_check.check_frame(result, tgt.expected_landmarks(j, candidate), reference, frame,
                                       tgt.expected_landmarks(j, tgt.flm[j]))
        t["check"] = time.perf_counter() - t0      # the phase; "self_check" is the summary
    return frame, result, t, check


class OrderedOutput:
    """Output frames written in order, each once the self-checks of the ``fade`` frames after it are known; around a
    frame that failed its check the result cross-fades to the target frame (``self_check.fallback_weights``)."""

    def __init__(self, writer, diagnostic_writer, lips: np.ndarray, fade: int, timing: dict, bar):
        self.writer, self.diagnostic_writer, self.lips, self.fade = writer, diagnostic_writer, lips, fade
        self.ok = np.ones(len(lips), bool)       # frames not checked (yet) count as passing
        self.ready: deque = deque()
        self.timing, self.bar = timing, bar

    def add(self, i: int, frame: np.ndarray, result: np.ndarray, texture: np.ndarray, ok: bool) -> None:
        self.ok[i] = ok
        self.ready.append((i, frame, result, texture))
        self.emit(keep=self.fade)

    def emit(self, keep: int = 0) -> None:
        while len(self.ready) > keep:
            i, frame, result, texture = self.ready.popleft()
            lo = max(i - self.fade, 0)
            wgt = self_check.fallback_weights(self.ok[lo:i + self.fade + 1], self.fade)[i - lo]
            if wgt < 1:
                result = np.clip(wgt * result.astype(np.float32) + (1 - wgt) * frame + 0.5, 0, 255).astype(np.uint8)
            t0 = time.perf_counter()
            self.writer.write(result)
            if self.diagnostic_writer is not None:
                self.diagnostic_writer.write(diagnostic(frame, result, texture, self.lips[i]))
            self.timing["encode"] = self.timing.get("encode", 0.0) + time.perf_counter() - t0
            self.bar.update()


def collect_frame(i: int, done: tuple, timing: dict, checks: list[dict],
                  p: Composite) -> tuple[np.ndarray, np.ndarray, bool]:
    """``composite_one``'s result ``done`` for output frame ``i``: its thread seconds are added to ``timing``, its
    self-check (if any) appended to ``checks``; returns the target frame, the result and whether it passes."""
    frame, result, t, check = done
    for k, v in t.items():
        timing[k] = timing.get(k, 0.0) + v
    ok = True
    if check is not None:
        checks.append(check)
        ok = self_check.passes(check, p.check_max_error, p.check_max_sharpness, p.check_max_face_error)
        if not ok:
            log.debug("self-check: output frame %d fails (mouth error %.3f × IOD, nose and chin %.3f × IOD, "
                      "sharpness × %.1f)", i, check["error"], check["face_error"], check["sharpness"])
    return frame, result, ok


def run(params: Params, synth_path: str, out_video: str, frontalize_path: str, video_path: str, audio_path: str) -> dict:
    """Composite the textures of ``synth_path`` into the target video and mux ``audio_path``.

    Parameters
    ----------
    frontalize_path : the frontalize store that holds the target (its geometry and textures).
    video_path : the target's source video (full frames).
    audio_path : the new speech (any file PyAV reads).

    Returns the thread time per output frame of each phase (ms). The video (and the diagnostic video) appear
    only when every frame is written.
    """
    p = params.composite
    synth = open_group(synth_path)
    tgt = Target(open_group(frontalize_path), synth.attrs["target"], video_path)
    mapping = np.asarray(synth["target_frame"][...])
    lips = np.asarray(synth["lip_points"][...])
    cand = np.asarray(synth["candidate_landmarks"][...], np.float64)
    partner = repeat_partners(mapping)        # repeated frames become half-way flow frames (§3.3)
    sr = int(p.audio_rate)
    audio, _ = media.read_audio(audio_path, sr)
    audio = audio[:int(round(len(mapping) / tgt.video["fps"] * sr))]
    out = Path(out_video)
    diag = out.with_name(out.stem + ".diagnostic.mp4") if p.diagnostic else None
    fps = tgt.video["fps"]
    timing: dict = {}
    checks: list[dict] = []
    reference = tgt.mouth_energy_reference() if p.self_check else None
    fade = max(int(p.check_fade_frames), 0) if p.self_check else 0
    t_start = time.perf_counter()
    with contextlib.ExitStack() as stack:           # closed in reverse: writers finish before the renames
        tmp = stack.enter_context(atomic_output(out, suffix=".mp4"))
        diag_tmp = stack.enter_context(atomic_output(diag, suffix=".mp4")) if diag else None
        writer = stack.enter_context(media.VideoWriter(tmp, fps, p.crf, p.preset, audio, sr, x264_options=p.x264_options))
        diag_writer = stack.enter_context(media.VideoWriter(diag_tmp, fps, p.crf, p.preset, audio, sr,
                                                                      x264_options=p.x264_options)) if diag else None
        pool = stack.enter_context(ThreadPoolExecutor(p.threads))
        stack.enter_context(library_threads(1))
        bar = stack.enter_context(tqdm(total=len(mapping), desc="composite", unit="frame", dynamic_ncols=True))
        output = OrderedOutput(writer, diag_writer, lips, fade, timing, bar)
        pending: deque = deque()                    # submitted to the pool, in output order

        def finish_oldest() -> None:
            i, texture, fut = pending.popleft()
            frame, result, ok = collect_frame(i, fut.result(), timing, checks, p)
            output.add(i, frame, result, texture, ok)

        for i in range(len(mapping)):
            j = int(mapping[i])
            if i % 256 == 0:
                textures = np.asarray(synth["texture"][i:i + 256])
                inpainted = np.asarray(synth["inpainted"][i:i + 256])
            t0 = time.perf_counter()
            frame = tgt.reader.get(j)
            following = tgt.reader.get(int(partner[i])) if partner[i] >= 0 else None
            timing["decode"] = timing.get("decode", 0.0) + time.perf_counter() - t0
            texture = textures[i % 256]
            pending.append((i, texture, pool.submit(composite_one, frame, following, texture, j, inpainted[i % 256],
                                                    tgt, p, cand[i], reference)))
            while len(pending) > 2 * p.threads:
                finish_oldest()
        while pending:
            finish_oldest()
        output.emit(keep=0)
    total = time.perf_counter() - t_start
    log.info("wrote %s: %d frames at %.3f fps in %.1f s (%.1f frames/s)", out, len(mapping), fps, total,
             len(mapping) / total)
    ms = {k: v / len(mapping) * 1000 for k, v in timing.items()}       # thread time per frame
    if p.self_check:
        ms["self_check"] = self_check_summary(checks, output.ok, p)
        ms["self_check"]["not_posed"] = int((~np.asarray(tgt.pose_ok)[mapping]).sum())   # left as the target
    return ms


def self_check_summary(checks: list[dict], ok: np.ndarray, p: Composite) -> dict:
    """Counts and medians of the self-check over the output, logged in one line."""
    def median(key):
        return float(np.median([c[key] for c in checks])) if checks else None
    summary = dict(checked=len(checks), frames=len(ok), fallen_back=int((~ok).sum()), median_error=median("error"),
                   median_face_error=median("face_error"), median_sharpness=median("sharpness"),
                   failed_by=dict(mouth_error=sum(c["error"] > p.check_max_error for c in checks),
                                  face_error=sum(c.get("face_error", 0.0) > p.check_max_face_error for c in checks),
                                  sharpness=sum(c["sharpness"] > p.check_max_sharpness for c in checks)))
    log.info("self-check: %d frames checked, %d fell back to the target frame (mouth error > %.2f × IOD, "
             "nose and chin > %.2f × IOD or sharpness > %.1f×; median errors %.3f and %.3f, median sharpness "
             "%.2f×)", summary["checked"], summary["fallen_back"], p.check_max_error, p.check_max_face_error,
             p.check_max_sharpness, summary["median_error"] or float("nan"),
             summary["median_face_error"] or float("nan"), summary["median_sharpness"] or float("nan"))
    return summary


def run_stage(params: Params) -> dict:
    """The DVC stage: ``composite.out_dir``/result.mp4 from the corpus target of ``synthesize``.

    Every input is a declared dependency: the synthesize and frontalize stores, the target's
    source video (a file of ``data.videos``, by its path relative to the project root) and
    ``synthesize.audio``. Per-phase timing goes to ``logs/composite.timing.json`` (untracked).
    """
    t0 = time.perf_counter()
    synth_path = params.synthesize.out
    video = open_group(synth_path).attrs["target"]
    ms = run(params, synth_path, str(Path(params.composite.out_dir) / "result.mp4"),
             params.frontalize.out, video["path"], params.synthesize.audio)
    ms["wall_fps"] = open_group(synth_path).attrs["n_frames"] / (time.perf_counter() - t0)
    check = ms.pop("self_check", None) or {}
    counts = {f"self_check_{k}_{kk}": vv for k, v in check.items() if isinstance(v, dict) for kk, vv in v.items()}
    write_timing("composite", dict(ms, **{f"self_check_{k}": v for k, v in check.items() if not isinstance(v, dict)},
                                   **counts))
    return ms


def main(argv=None) -> int:
    return stage_main("lipsynth composite", __doc__, run_stage, argv)


if __name__ == "__main__":
    raise SystemExit(main())
