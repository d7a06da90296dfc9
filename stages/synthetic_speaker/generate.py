"""Deterministic synthetic talking-head corpus (the "synthetic speaker").

A real photo (``skimage.data.astronaut()``) is animated with a piecewise-affine
mesh warp driven by a small landmark model (mouth opening / width / rounding,
blinks, head pose), and a matching speech-like soundtrack is produced by a
source-filter formant synthesiser over a random sequence of phone-like units.
The mouth moves *before* the sound (``articulation.MOUTH_LEAD_S``), with
co-articulation, so audio -> mouth is learnable but not a function of
instantaneous loudness.

This module scripts, renders and writes the clips; the parts live beside it:
``face_template`` (photo, landmarks, mesh), ``language`` (phone-like units),
``articulation`` (mouth, blinks, head pose, frame landmarks), ``render`` (mesh
warp, painted mouth and eyelids), ``speech`` (formant synthesis) and ``mux``
(MP4 writing).

Outputs, for video ``i`` in ``out_dir``:

``speaker_XX.mp4``
    H.264 yuv420p video (crf 18) + AAC mono audio, muxed with PyAV.
``speaker_XX.truth.npz``
    Ground truth, see :func:`truth_arrays`.

Everything is a pure function of ``(seed, i)`` and the frame/audio settings;
video ``i`` does not depend on ``n_videos``.

Run ``python -m stages.synthetic_speaker.generate --help``.
"""
from __future__ import annotations

import argparse
import logging
import os
import shutil
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from tqdm import tqdm

from pipeline.errors import LipsynthError, ParameterError
from pipeline.io.runner import record_wall_time
from pipeline.params import SyntheticSpeaker, as_dict, load_params
from stages.synthetic_speaker import articulation, face_template, language, mux, render, speech

log = logging.getLogger("lipsynth.synthetic_speaker")

HOG_MIN_FACE_PX = 80
"""dlib's frontal HOG detector (upsample 0) misses faces narrower than about this."""


# ----------------------------------------------------------------------------
# One video
# ----------------------------------------------------------------------------

@dataclass(frozen=True)
class VideoScript:
    """Everything about one clip except the rendered pixels.

    Attributes
    ----------
    phones : structured ndarray, (P,) of ``language.PHONE_DTYPE``
    stressed : ndarray, (P,) bool
    mouth : ndarray, (T, 3) float32
    closure : ndarray, (T,) float
    pose : ndarray, (T, 6) float32
    landmarks : ndarray, (T, 68, 2) float32
    audio : ndarray, (N,) float32
    """

    phones: np.ndarray
    stressed: np.ndarray
    mouth: np.ndarray
    closure: np.ndarray
    pose: np.ndarray
    landmarks: np.ndarray
    audio: np.ndarray


def video_rng(seed: int, video_index: int, stream: str) -> np.random.Generator:
    """Independent random stream per (seed, video, purpose)."""
    stream_id = {"phones": 0, "mouth": 1, "blinks": 2, "pose": 3, "audio": 4}[stream]
    return np.random.default_rng([seed, video_index, stream_id])


def script_video(template: face_template.FaceTemplate, seed: int, video_index: int, seconds: float,
                 fps: int, sample_rate: int) -> VideoScript:
    """Sample the phone sequence, articulation, pose, landmarks and audio of one clip."""
    n_frames = int(round(seconds * fps))
    frame_times = np.arange(n_frames) / fps
    phones, stressed = language.sample_phone_sequence(video_rng(seed, video_index, "phones"), seconds)
    targets, dominance = articulation.mouth_targets(phones, video_rng(seed, video_index, "mouth"))
    mouth = articulation.mouth_trajectory(phones, targets, dominance, frame_times)
    closure = articulation.blink_closure(video_rng(seed, video_index, "blinks"), frame_times)
    pose = articulation.head_pose_track(video_rng(seed, video_index, "pose"), frame_times,
                                        template.face_width)
    landmarks = np.stack([articulation.frame_landmarks(template, mouth[t], closure[t],
                                                       pose[t].astype(np.float64))
                          for t in range(n_frames)]).astype(np.float32)
    audio = speech.synthesize_speech(phones, stressed, video_rng(seed, video_index, "audio"),
                                     sample_rate, int(round(seconds * sample_rate)))
    return VideoScript(phones, stressed, mouth, closure, pose, landmarks, audio)


def render_frames(template: face_template.FaceTemplate, script: VideoScript):
    """Yield the RGB frames (H, W, 3) uint8 of a scripted clip."""
    for t in range(len(script.mouth)):
        yield render.render_frame(template, script.landmarks[t].astype(np.float64),
                                  float(script.closure[t]), script.pose[t].astype(np.float64))


def truth_arrays(script: VideoScript, fps: int, sample_rate: int) -> dict[str, np.ndarray]:
    """Ground-truth arrays saved in ``speaker_XX.truth.npz``.

    Returns
    -------
    dict
        ``landmarks`` (T, 68, 2) float32 px (x, y), dlib/iBUG order;
        ``pose`` (T, 6) float32 (yaw, pitch, roll deg, tx, ty px, scale);
        ``pose_names`` (6,) str; ``blink`` (T,) bool (eyes more than half closed);
        ``mouth`` (T, 3) float32 (open 0..1, width -1..1, round 0..1);
        ``mouth_names`` (3,) str; ``phones`` (P,) structured (label U3, start f8 s,
        end f8 s) tiling the clip, "sil" = silence; ``voiced`` (T,) bool, speech
        (non-silence unit) at the frame time; ``fps``, ``sample_rate`` and
        ``mouth_lead_s`` scalars.
    """
    frame_times = np.arange(len(script.mouth)) / fps
    return {
        "landmarks": script.landmarks.astype(np.float32),
        "pose": script.pose.astype(np.float32),
        "pose_names": np.array(articulation.POSE_NAMES),
        "blink": script.closure >= 0.5,
        "mouth": script.mouth.astype(np.float32),
        "mouth_names": np.array(articulation.MOUTH_NAMES),
        "phones": script.phones,
        "voiced": language.speech_activity(script.phones, frame_times),
        "fps": np.array(fps),
        "sample_rate": np.array(sample_rate),
        "mouth_lead_s": np.array(articulation.MOUTH_LEAD_S),
    }


def generate_video(template: face_template.FaceTemplate, settings: dict, video_index: int,
                   directory: Path) -> None:
    """Script, render and write ``speaker_XX.mp4`` and ``speaker_XX.truth.npz`` into ``directory``."""
    script = script_video(template, settings["seed"], video_index, settings["seconds_per_video"],
                          settings["fps"], settings["sample_rate"])
    stem = directory / f"speaker_{video_index:02d}"
    mux.write_mp4(stem.with_suffix(".mp4"), render_frames(template, script), script.audio,
                  settings["fps"], settings["sample_rate"], settings["width"], settings["height"])
    np.savez_compressed(stem.with_suffix(".truth.npz"),
                        **truth_arrays(script, settings["fps"], settings["sample_rate"]))


# ----------------------------------------------------------------------------
# Corpus and entry point
# ----------------------------------------------------------------------------

def validated_settings(params: SyntheticSpeaker) -> dict:
    """Check the ranges of the (already typed) ``synthetic_speaker`` params; return them as a dict."""
    where = "synthetic_speaker"
    settings = as_dict(params)
    settings["seconds_per_video"] = float(settings["seconds_per_video"])
    checks = (
        ("n_videos", settings["n_videos"] >= 1, ">= 1"),
        ("seconds_per_video", settings["seconds_per_video"] >= 1.0, ">= 1"),
        ("fps", settings["fps"] > 0, "> 0"),
        ("width", settings["width"] >= 160 and settings["width"] % 2 == 0, "even and >= 160"),
        ("height", settings["height"] >= 128 and settings["height"] % 2 == 0, "even and >= 128"),
        ("sample_rate", settings["sample_rate"] in mux.AAC_SAMPLE_RATES,
         f"one of {mux.AAC_SAMPLE_RATES}"),
    )
    for key, ok, rule in checks:
        if not ok:
            raise ParameterError(f"{where}.{key}={settings[key]!r}: must be {rule}")
    return settings


def replace_directory(source: Path, destination: Path) -> None:
    """Move ``source`` onto ``destination``, removing an existing ``destination`` first.

    The old directory is renamed aside before the new one is moved in, so a
    complete corpus is always either at ``destination`` or at the aside name.
    """
    aside = destination.with_name(f".{destination.name}.old-{os.getpid()}")
    if destination.exists():
        os.replace(destination, aside)
    os.replace(source, destination)
    shutil.rmtree(aside, ignore_errors=True)


def generate_corpus(settings: dict) -> Path:
    """Generate all clips into a temporary sibling directory, then move it onto ``out_dir``.

    Returns
    -------
    Path
        The output directory.
    """
    out_dir = Path(settings["out_dir"])
    out_dir.parent.mkdir(parents=True, exist_ok=True)
    staging = out_dir.with_name(f".{out_dir.name}.tmp-{os.getpid()}")
    shutil.rmtree(staging, ignore_errors=True)
    staging.mkdir()
    try:
        template = face_template.build_template(settings["width"], settings["height"])
        log.info("template face %.0f px wide, %d mesh points, %d triangles",
                 template.face_width, len(template.mesh_points), len(template.triangles))
        if template.face_width < HOG_MIN_FACE_PX:
            log.warning("face is only %.0f px wide: dlib's HOG detector will miss it "
                        "(use frames of at least 240 x 192)", template.face_width)
        for video_index in tqdm(range(settings["n_videos"]), desc="synthetic speaker", unit="video"):
            generate_video(template, settings, video_index, staging)
        replace_directory(staging, out_dir)
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise
    return out_dir


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    """Command-line arguments."""
    parser = argparse.ArgumentParser(
        prog="python -m stages.synthetic_speaker.generate",
        description=(
            "Generate a deterministic synthetic talking-head corpus: n_videos clips of the "
            "astronaut photo animated to speak a random phone-like language, written as "
            "OUT/speaker_XX.mp4 (H.264 + AAC) and OUT/speaker_XX.truth.npz (per-frame 68 "
            "landmarks, head pose, blinks, mouth parameters, phone timings, speech activity). "
            "Settings come from the 'synthetic_speaker' section of params.yaml (or the file "
            "named by $LIPSYNTH_PARAMS): seed, n_videos, seconds_per_video, fps, width, "
            "height, sample_rate, out_dir. The output directory is replaced atomically."),
        epilog=(
            "truth.npz keys: landmarks (T,68,2) float32 px, dlib/iBUG order; pose (T,6) "
            "yaw/pitch/roll deg, tx/ty px, scale; blink (T,) bool; mouth (T,3) open 0..1, "
            "width -1..1, round 0..1; phones (P,) label/start/end s ('sil' = silence); "
            "voiced (T,) bool speech activity; fps; sample_rate; mouth_lead_s. The mouth "
            f"anticipates the sound by {articulation.MOUTH_LEAD_S * 1000:.0f} ms."),
    )
    parser.add_argument("--out", metavar="DIR", help="output directory (overrides out_dir)")
    return parser.parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    """Entry point: read params, generate the corpus, report the time taken."""
    args = parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    try:
        settings = validated_settings(load_params().synthetic_speaker)
        if args.out:
            settings["out_dir"] = args.out
        started = time.perf_counter()
        out_dir = generate_corpus(settings)
    except LipsynthError as error:
        log.error("%s", error)
        return 2
    log.info("wrote %d videos to %s in %.1f s", settings["n_videos"], out_dir,
             time.perf_counter() - started)
    record_wall_time("synthetic_speaker", time.perf_counter() - started)
    return 0


if __name__ == "__main__":
    sys.exit(main())
