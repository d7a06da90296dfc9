"""``params.yaml`` as typed sections, validated once when it is loaded.

One dataclass per section (``data``, ``cluster`` and one per stage). ``load_params`` reads the
file, checks every key against its section's fields — an unknown key, a missing section, a
value of the wrong type or outside its allowed choices stops with one line naming
``section.key`` — and returns a ``Params`` whose sections are read as attributes
(``params.ingest.crop_size``). A key the file leaves out takes the default below, which equals
the shipped params.yaml. Code never reads raw dicts of parameters.

Each field says what it means once, here: ``metadata["help"]`` is its one-line meaning (units
where it has them) and ``metadata["advanced"]`` marks the few keys an ordinary user never
touches. ``lipsynth params-doc --write`` renders them into docs/parameters_reference.md.

Applications may adjust a loaded tree (``lipsynth speak`` points the preprocessing outputs at
its cache): ``copy.deepcopy`` it and assign attributes; ``check`` re-validates.
"""
from __future__ import annotations

import dataclasses
import os
import types
import typing
from dataclasses import dataclass, field
from pathlib import Path

import yaml

from .errors import ParameterError

PARAMS_FILE = Path(os.environ.get("LIPSYNTH_PARAMS", "params.yaml"))


@dataclass
class SyntheticSpeaker:
    seed: int = field(default=7,
        metadata={"help": "master seed; video i uses the sub-seed (seed, i)"})
    n_videos: int = field(default=6,
        metadata={"help": "number of clips generated (speaker_00.mp4, speaker_01.mp4, …)"})
    seconds_per_video: float = field(default=10.0,
        metadata={"help": "clip length (s)"})
    fps: int = field(default=25,
        metadata={"help": "video frame rate (frames/s)"})
    width: int = field(default=360,
        metadata={"help": "frame width (px, even)"})
    height: int = field(default=288,
        metadata={"help": "frame height (px, even)"})
    sample_rate: int = field(default=16000,
        metadata={"help": "audio sample rate (Hz), mono"})
    out_dir: str = field(default="data/synthetic_speaker",
        metadata={"help": "folder the generated clips are written to"})


@dataclass
class Data:
    videos: str | list = field(default="data/synthetic_speaker",
        metadata={"help": "the training footage: a video file or a folder (a glob or a list also work outside DVC)"})
    val_fraction: float = field(default=0.2,
        metadata={"help": "share of the footage held out for validation"})
    split_seed: int = field(default=0,
        metadata={"help": "seed of the hash that splits the videos"})
    split: str = field(default="video",
        metadata={"help": "video: whole videos by a seeded hash | time: the last val_fraction of each cut video's segments (`lipsynth cut`)"})
    on_bad_input: str = field(default="error",
        metadata={"help": "error: stop at the first bad video | skip: warn and leave it out"})

    CHOICES = {"on_bad_input": ("error", "skip"), "split": ("video", "time")}


@dataclass
class ClusterSecurity:
    """TLS for ``cluster.address = tls://…`` (``distributed.security.Security``): PEM files."""
    tls_ca_file: str | None = field(default=None,
        metadata={"help": "PEM file of the CA that signed the scheduler's and workers' certificates"})
    tls_client_cert: str | None = field(default=None,
        metadata={"help": "PEM file of this client's certificate (may also hold its key)"})
    tls_client_key: str | None = field(default=None,
        metadata={"help": "PEM file of its private key (null: inside tls_client_cert)"})
    require_encryption: bool = field(default=False,
        metadata={"help": "true: refuse a tcp:// address (unencrypted, unauthenticated)"})


@dataclass
class Cluster:
    address: str | None = field(default=None,
        metadata={"help": "dask scheduler: null = a LocalCluster on this machine | tcp://host:8786 or tls://… | in-process = no cluster, tasks one by one (debugging)"})
    n_workers: int | None = field(default=None,
        metadata={"help": "LocalCluster workers (null: one per core)"})
    memory_limit: str | int | float = field(default="auto",
        metadata={"help": "memory per LocalCluster worker (dask's memory_limit: auto, bytes or e.g. 4GB)"})
    connect_timeout: float = field(default=30.0,
        metadata={"help": "seconds to wait for cluster.address"})
    security: ClusterSecurity = field(default_factory=ClusterSecurity,
        metadata={"help": "TLS for a tls:// address: PEM files (the cluster.security keys)"})


@dataclass
class Ingest:
    out: str = field(default="store/ingest.zarr",
        metadata={"help": "output store: face crops, 16 kHz audio, MFCC features"})
    crop_size: int | str = field(default="auto",
        metadata={"help": "stored square face crop side (px); auto: crop_scale × the face width found on a few key frames, ≥ 224"})
    max_crop_size: int = field(default=448,
        metadata={"help": "largest crop side auto may choose (px)"})
    crop_scale: float = field(default=2.0,
        metadata={"help": "crop side / detected face-box width"})
    crop_shift_down: float = field(default=0.3,
        metadata={"help": "crop centre below the face-box centre, in face widths"})
    detect_samples: int = field(default=8,
        metadata={"help": "key frames searched for the face per video"})
    detect_upsample: int = field(default=1,
        metadata={"help": "max dlib HOG upsampling when no face is found without"})
    min_face_px: float = field(default=40,
        metadata={"help": "faces narrower than this (px) are rejected as too small"})
    min_seconds: float = field(default=0.5,
        metadata={"help": "videos shorter than this (s) are rejected as too short"})
    min_fps: float = field(default=10,
        metadata={"help": "lowest accepted video frame rate (frames/s)"})
    max_fps: float = field(default=120,
        metadata={"help": "highest accepted video frame rate (frames/s)"})
    rms_target_dbfs: float = field(default=-23.0,
        metadata={"help": "RMS volume the audio is normalised to (dBFS; paper §3.1 step 1)"})
    shard_frames: int = field(default=256,
        metadata={"help": "frames per shard file (one dask task each); every video starts on a shard", "advanced": True})
    shard_seconds: int = field(default=10,
        metadata={"help": "audio / MFCC shard length (s)", "advanced": True})
    chunk_frames: int = field(default=8,
        metadata={"help": "frames per compressed chunk inside a shard", "advanced": True})

    AUTO = ("crop_size",)            # an int, or "auto": follow the face's size in the footage


@dataclass
class Landmarks:
    out: str = field(default="store/landmarks.zarr",
        metadata={"help": "output store: 68 dlib landmarks per frame and their validity"})
    detect_every: int = field(default=50,
        metadata={"help": "re-run the HOG face detector at least every N frames while tracking"})
    detect_upsample: int = field(default=1,
        metadata={"help": "max HOG upsampling on the crop when no face is found without"})
    jitter: float = field(default=0.05,
        metadata={"help": "box shift for the landmark confidence test, × box width", "advanced": True})
    min_confidence: float = field(default=0.5,
        metadata={"help": "frames below this confidence are flagged invalid (and tracking restarts)"})
    margin: float = field(default=0.1,
        metadata={"help": "landmarks may lie this far outside the crop (× crop size)"})
    min_valid_fraction: float = field(default=0.5,
        metadata={"help": "a video with a smaller share of valid frames is an error (or skipped)"})


@dataclass
class Frontalize:
    out: str = field(default="store/frontalize.zarr",
        metadata={"help": "output store: 3D model, head pose, frontal textures"})
    focal_factor: float = field(default=1.5,
        metadata={"help": "assumed focal length / max(frame width, height)"})
    model_frames: int = field(default=300,
        metadata={"help": "training frames used to build the 3D face model"})
    min_conditioning: float = field(default=6.0,
        metadata={"help": "singular-value ratio s3/s4 needed to trust the factorisation over the prior", "advanced": True})
    ba_iterations: int = field(default=100,
        metadata={"help": "pycolmap bundle-adjustment iterations"})
    grid_mm: float = field(default=2.0,
        metadata={"help": "canonical grid spacing for the chin extension (mm)"})
    grid_x_mm: list = field(default_factory=lambda: [-110, 110],
        metadata={"help": "canonical grid extent across, [min, max] mm from the eye midpoint"})
    grid_y_mm: list = field(default_factory=lambda: [-80, 220],
        metadata={"help": "canonical grid extent down, [min, max] mm from the eye midpoint"})
    data_weight: float = field(default=100.0,
        metadata={"help": "Eq. 8 soft-constraint weight of f* = f on the face region", "advanced": True})
    boundary_weight: float = field(default=100.0,
        metadata={"help": "Eq. 8 soft-constraint weight of ∇f* = 0 on the grid boundary", "advanced": True})
    texture_size: int | str = field(default="auto",
        metadata={"help": "frontal texture side N (px); auto: as fine as the face in the stored crops, ≥ 128; px-valued synthesize/composite params scale with N/128"})
    max_texture_size: int = field(default=256,
        metadata={"help": "largest texture side auto may choose (px; synthesis cost grows with N²)"})
    texture_x_mm: list = field(default_factory=lambda: [-80, 80],
        metadata={"help": "lower-face texture window across, [min, max] mm from the eye midpoint"})
    texture_y_mm: list = field(default_factory=lambda: [20, 180],
        metadata={"help": "lower-face texture window down, [min, max] mm from the eye midpoint"})
    max_reprojection: float = field(default=0.15,
        metadata={"help": "a pose is rejected above this RMS reprojection error × inter-ocular px"})
    cloth_dark_value: int = field(default=50,
        metadata={"help": "HSV value (0–255) below which a pixel below the chin is dark clothing"})
    cloth_white_saturation: int = field(default=40,
        metadata={"help": "HSV saturation (0–255) below which, with value above cloth_white_value, a pixel is a white shirt"})
    cloth_white_value: int = field(default=185,
        metadata={"help": "HSV value (0–255) above which, with low saturation, a pixel is a white shirt"})
    cloth_dilate_px: int = field(default=2,
        metadata={"help": "dilation of the clothing mask (px)"})
    inpaint_radius: float = field(default=3.0,
        metadata={"help": "Telea inpainting radius of the clothing (px; solved at half resolution: steps of 2 px)"})
    chunk_frames: int = field(default=8,
        metadata={"help": "frames per compressed chunk inside a shard", "advanced": True})

    AUTO = ("texture_size",)         # an int, or "auto": as fine as the face in the stored crops


@dataclass
class Pca:
    out: str = field(default="store/pca.zarr",
        metadata={"help": "output store: mouth PCA basis and coefficients per frame and at 100 Hz"})
    n_components: int = field(default=20,
        metadata={"help": "PCA coefficients kept of the 18 lip points (36-D)"})


@dataclass
class Phonetic:
    out: str = field(default="store/phonetic.zarr",
        metadata={"help": "output store: pocketsphinx phone indicators per 10 ms"})


@dataclass
class Whisper:
    out: str = field(default="store/whisper.zarr",
        metadata={"help": "output store: Whisper tiny.en encoder states per 10 ms"})
    window_seconds: float = field(default=10.0,
        metadata={"help": "encoder window (s): audio is encoded in windows of this length"})
    overlap_seconds: float = field(default=2.0,
        metadata={"help": "overlap of consecutive encoder windows, cross-faded (s)"})


@dataclass
class Train:
    model: str = field(default="lstm",
        metadata={"help": "model family: lstm (paper 000's time-delayed LSTM)"})
    out: str = field(default="models/lstm",
        metadata={"help": "model folder: weights, normalisation, PCA basis, params, speaker"})
    metrics: str = field(default="metrics/train.json",
        metadata={"help": "DVC metrics file: losses and validation mouth errors of the model and its baselines"})
    plots: str = field(default="plots/train_loss.csv",
        metadata={"help": "DVC plot of the loss curves (CSV)"})
    delay: int = field(default=0,
        metadata={"help": "target delay d in 10 ms steps: the model hears d steps of audio past the mouth it predicts (the paper: 20)"})
    hidden: int = field(default=60,
        metadata={"help": "LSTM cells"})
    layers: int = field(default=1,
        metadata={"help": "stacked LSTM layers"})
    batch_size: int = field(default=100,
        metadata={"help": "parallel training streams (fewer when the corpus is small)"})
    bptt: int = field(default=100,
        metadata={"help": "truncated back-propagation window (steps)"})
    lr: float = field(default=0.001,
        metadata={"help": "Adam learning rate"})
    steps: int = field(default=300,
        metadata={"help": "training budget in optimizer steps (one per bptt window of ≤ batch_size streams)"})
    val_every: int = field(default=10,
        metadata={"help": "optimizer steps between validation points (the loss curve)"})
    patience: int | None = field(default=None,
        metadata={"help": "stop after this many validations without improvement, keeping the best weights (null: the whole budget)"})
    min_delta: float = field(default=0.0,
        metadata={"help": "relative validation gain that counts as an improvement for patience"})
    baselines: bool = field(default=True,
        metadata={"help": "also train the same LSTM with delay 0 (when delay ≠ 0) for comparison"})
    feature_norm: str = field(default="corpus",
        metadata={"help": "corpus: input dims by the training mean/variance (the paper) | utterance: per-video CMVN first"})
    features: str = field(default="whisper",
        metadata={"help": "audio front end: whisper (384-D Whisper tiny.en encoder states) | mfcc (the paper's 28-D) | phonetic (40 phone indicators) | mfcc+phonetic (68-D)"})
    feature_store: str = field(default="store/whisper.zarr",
        metadata={"help": "the one store `features` reads, the train stage's dependency: whisper.out (whisper), phonetic.out (phonetic, mfcc+phonetic) or ingest.out (mfcc)"})
    vtlp_warps: list = field(default_factory=list,
        metadata={"help": "MFCC front ends only: VTLP augmentation, extra copies at these frequency-warp factors, one drawn per epoch"})
    pitch_shifts: list = field(default_factory=list,
        metadata={"help": "MFCC front ends only: extra pitch-shifted copies by these semitones, formants and timing kept"})
    extra_corpora: list = field(default_factory=list,
        metadata={"help": "base models only (bench/base_model.py): folders of other people's stores, trained on too"})
    extra_repeat: int = field(default=1,
        metadata={"help": "each video of extra_corpora is used this many times"})
    init_from: str | None = field(default=None,
        metadata={"help": "a model folder to start from (a base model); its read-out is re-expressed in this store's PCA basis"})
    fine_tune: str = field(default="all",
        metadata={"help": "with init_from: all = train every weight | output = the read-out only"})
    train_seconds: float | None = field(default=None,
        metadata={"help": "a seeded subset of the training videos reaching this many seconds (learning curves); null: all"})
    seed: int = field(default=0,
        metadata={"help": "training seed"})
    device: str = field(default="auto",
        metadata={"help": "torch device; auto: CUDA when present, else CPU"})
    bank_frames: int = field(default=3000,
        metadata={"help": "training frames (frontal texture, landmarks, pose) in the model folder's candidate bank for `lipsynth speak`"})
    identity_frames: int = field(default=60,
        metadata={"help": "frames whose face descriptors make the speaker's identity"})

    CHOICES = {"model": ("lstm",), "feature_norm": ("corpus", "utterance"), "fine_tune": ("all", "output"),
               "features": ("mfcc", "phonetic", "mfcc+phonetic", "whisper")}


@dataclass
class Brand:
    out: str = field(default="models/brand",
        metadata={"help": "model folder: HMM, face + voice Gaussians, PCA bases, speaker"})
    metrics: str = field(default="metrics/train_brand.json",
        metadata={"help": "DVC metrics: entropic vs ML HMM (validation mouth error, Eq. 7, entropy rate, perplexity)"})
    plots: str = field(default="plots/train_brand.csv",
        metadata={"help": "EM history (log likelihood / posterior per frame, states, transitions)"})
    rate: float = field(default=25.0,
        metadata={"help": "model frame rate (Hz): faces and voice are resampled to it"})
    features: str = field(default="whisper",
        metadata={"help": "voice: whisper (encoder states on a PCA of voice_dims) | mfcc (the 28-D MFCC) | paper (LPC + RASTA-PLP + formants + band energies, 33-D)"})
    voice_dims: int = field(default=24,
        metadata={"help": "whisper: PCA dims of the encoder states kept for the voice Gaussians"})
    face_dims: int = field(default=12,
        metadata={"help": "PCA coordinates kept of the 39 face points (lips, jaw, brows), plus their velocities"})
    states: int = field(default=26,
        metadata={"help": "initial HMM states (the paper's 26)"})
    prior_weight: float = field(default=1.0,
        metadata={"help": "Z in P(θ) ∝ exp(−Z·H(θ)); 1 = the paper's entropic prior"})
    trim: bool = field(default=True,
        metadata={"help": "trim transitions when the prior's gain outweighs their likelihood"})
    iterations: int = field(default=60,
        metadata={"help": "EM iterations at most"})
    tolerance: float = field(default=1e-4,
        metadata={"help": "EM stops when the log posterior per frame improves by less", "advanced": True})
    reg: float = field(default=1e-3,
        metadata={"help": "ridge added to every covariance (standardised units)", "advanced": True})
    min_state_frames: float = field(default=25.0,
        metadata={"help": "a state occupied by fewer frames is removed (too few for its covariance)"})
    decode: str = field(default="viterbi",
        metadata={"help": "viterbi (the paper) | posterior (forward–backward state weights in Eq. 5)"})
    baseline: bool = field(default=True,
        metadata={"help": "also train the maximum-likelihood HMM (same states, data) for comparison"})
    train_seconds: float | None = field(default=None,
        metadata={"help": "a seeded subset of the training videos of about this much audio (s); null: all"})
    seed: int = field(default=0,
        metadata={"help": "training seed"})

    CHOICES = {"features": ("paper", "mfcc", "whisper"), "decode": ("viterbi", "posterior")}


@dataclass
class Karras:
    out: str = field(default="models/karras",
        metadata={"help": "model folder: network, mouth PCA, mined emotion vectors, speaker"})
    metrics: str = field(default="metrics/train_karras.json",
        metadata={"help": "DVC metrics: validation mouth error vs the mean shape, emotion mining counts, timing"})
    plots: str = field(default="plots/train_karras_loss.csv",
        metadata={"help": "per validation point: loss terms (position/motion/emotion) and the validation curve"})
    train_seconds: float | None = field(default=None,
        metadata={"help": "a seeded subset of about this much speech (s); null: every training video (the paper: 3–5 minutes)"})
    steps: int = field(default=120,
        metadata={"help": "training budget in optimizer steps of `batch` samples"})
    batch: int = field(default=100,
        metadata={"help": "minibatch size in samples (batch / 2 temporal pairs)"})
    lr: float = field(default=0.003,
        metadata={"help": "Adam base rate (ramped up over epoch 1, then 1/√t, ramped down at the end)"})
    emotion_dim: int = field(default=16,
        metadata={"help": "E: size of the learned emotion vector of each training frame"})
    emotion_sigma: float = field(default=0.01,
        metadata={"help": "σ of the emotion vectors' initialisation N(0, σ²)", "advanced": True})
    motion: bool = field(default=True,
        metadata={"help": "ablation switch: the motion loss term ℓᴹ"})
    emotions: bool = field(default=True,
        metadata={"help": "ablation switch: the emotion database (false: a zero vector in and out)"})
    time_shift: bool = field(default=True,
        metadata={"help": "ablation switch: the ±16.6 ms time-shift augmentation"})
    val_every: int = field(default=12,
        metadata={"help": "steps between points of the validation curve"})
    patience: int | None = field(default=None,
        metadata={"help": "early stop after this many validations without improvement, keeping the best (null: the whole budget)"})
    min_delta: float = field(default=0.0,
        metadata={"help": "relative validation gain that counts as an improvement for patience"})
    val_frames: int = field(default=2000,
        metadata={"help": "validation frames sampled (fixed) for the curve"})
    mine_candidates: int = field(default=500,
        metadata={"help": "emotion mining (§5.1): database vectors scanned"})
    mine_probes: int = field(default=8,
        metadata={"help": "emotion mining: closed-mouth and open-mouth validation windows each vector is tested against"})
    mine_playback: int = field(default=64,
        metadata={"help": "emotion mining: the strongest responders kept and played over validation clips"})
    mine_playback_clips: int = field(default=8,
        metadata={"help": "emotion mining: validation clips the responders are played over"})
    emotion_clusters: int = field(default=8,
        metadata={"help": "emotion mining: the surviving vectors are clustered into this many candidates"})
    seed: int = field(default=0,
        metadata={"help": "training seed"})
    device: str = field(default="auto",
        metadata={"help": "torch device; auto: CUDA when present, else CPU"})
    threads: int | None = field(default=None,
        metadata={"help": "torch CPU threads (null: all cores)"})


@dataclass
class RenderMesh:
    model: str = field(default="models/karras",
        metadata={"help": "any model folder with a speaker (karras drives jaw + lips, others the lips)"})
    out: str = field(default="outputs/synthetic_speaker_3d/karras_mesh.mp4",
        metadata={"help": "output MP4 of synthesize.audio: the textured head, front + three-quarter view, H.264 + AAC"})
    export: str = field(default="outputs/synthetic_speaker_3d/karras_head",
        metadata={"help": "folder for the animated mesh: head.obj/.mtl/.png (rest, textured) + head.pc2 (point cache)"})
    fps: float = field(default=25.0,
        metadata={"help": "output frame rate (frames/s)"})
    size: int = field(default=512,
        metadata={"help": "height of each view (px)"})
    step_mm: float = field(default=2.0,
        metadata={"help": "head mesh grid spacing on the face surface (mm): 2 mm ≈ 5,000 vertices"})
    emotion: int | str | None = field(default=None,
        metadata={"help": "Karras emotion candidate K or K1:K2:t (null: the model's default)"})


@dataclass
class DelaySweep:
    delays: list = field(default_factory=lambda: [0, 5, 10, 20, 40],
        metadata={"help": "target delays to compare (10 ms steps)"})
    steps: int = field(default=300,
        metadata={"help": "budget per delay in optimizer steps (the other settings come from train)"})
    plots: str = field(default="plots/delay_sweep.csv",
        metadata={"help": "DVC plot: validation loss per delay (CSV)"})


@dataclass
class Synthesize:
    audio: str = field(default="data/synthetic_speaker/speaker_03.mp4",
        metadata={"help": "new speech: any audio or video file"})
    target: str = field(default="speaker_00",
        metadata={"help": "target video: the name of a corpus video (any other video: `lipsynth speak`)"})
    model: str = field(default="models/lstm",
        metadata={"help": "model folder that predicts the mouth shapes"})
    out: str = field(default="store/synthesize.zarr",
        metadata={"help": "output store: re-timed lower-face textures"})
    retime: bool = field(default=True,
        metadata={"help": "re-time the target's frames to the new speech (§3.3); false keeps its own timing (evaluation)"})
    alpha_b: float = field(default=1.0,
        metadata={"help": "§3.3 blink weight α_B"})
    alpha_s: float = field(default=2.0,
        metadata={"help": "§3.3 repeat-during-motion weight α_s"})
    alpha_u: float = field(default=2.0,
        metadata={"help": "§3.3 motion-after-speech-onset weight α_u"})
    blink_threshold: float = field(default=0.010,
        metadata={"help": "eye area / IOD² below which an eye counts as blinking"})
    speech_threshold_db: float = field(default=-35.0,
        metadata={"help": "volume below the loudest 10 ms window (dB) under which audio counts as silence"})
    n: int = field(default=50,
        metadata={"help": "candidate frames per output frame"})
    alpha: float = field(default=0.9,
        metadata={"help": "Eq. 12: weight share of the n candidates"})
    pool_min: int = field(default=500,
        metadata={"help": "add corpus training frames when the target has fewer frames than this"})
    pool_max: int = field(default=4000,
        metadata={"help": "most frames in the candidate pool"})
    retarget: str = field(default="auto",
        metadata={"help": "move predicted shapes onto the target's mean mouth: auto = when the model's PCA basis differs (another corpus) | always | never"})
    exclude_target_from_pool: bool = field(default=False,
        metadata={"help": "true: candidates only from other videos (evaluation against the target)"})
    teeth_upper: int | None = field(default=None,
        metadata={"help": "target frame index of the upper-teeth proxy (null: automatic)"})
    teeth_lower: int | None = field(default=None,
        metadata={"help": "target frame index of the lower-teeth proxy (null: automatic)"})
    teeth_sigmas: list = field(default_factory=lambda: [1.0, 2.0, 4.0],
        metadata={"help": "Eq. 13 high-pass σ's (px at texture size 128): single teeth, teeth rows, the teeth band"})
    teeth_strength: float = field(default=0.3,
        metadata={"help": "Eq. 13 strength s per scale"})
    teeth_s_max: float = field(default=0.45,
        metadata={"help": "teeth pixels: HSV saturation (0–1) at most this"})
    teeth_v_min: float = field(default=0.45,
        metadata={"help": "teeth pixels: HSV value (0–1) at least this"})
    teeth_feather_px: float = field(default=1.0,
        metadata={"help": "Gaussian σ of the teeth/mouth mask borders (px)"})
    unsharp_sigma: float = field(default=1.0,
        metadata={"help": "§3.2 unsharp mask of the mouth region: Gaussian σ (px)"})
    unsharp_amount: float = field(default=0.25,
        metadata={"help": "§3.2 unsharp mask of the mouth region: amount a in I + a (I − G*I)"})
    min_target_fraction: float = field(default=0.5,
        metadata={"help": "a target with a face in a smaller share of its frames is refused"})
    threads: int = field(default=2,
        metadata={"help": "frames synthesized in parallel (threads)"})
    device: str = field(default="auto",
        metadata={"help": "torch device of the model; auto: CUDA when present, else CPU"})
    emotion: int | str | None = field(default=None,
        metadata={"help": "Karras models only: a mined emotion K, or K1:K2:t to interpolate (null: the model's default)"})

    CHOICES = {"retarget": ("auto", "always", "never")}


@dataclass
class Composite:
    out_dir: str = field(default="outputs/synthetic_speaker",
        metadata={"help": "folder result.mp4 (and result.diagnostic.mp4) are written to"})
    diagnostic: bool = field(default=True,
        metadata={"help": "also write result.diagnostic.mp4: target | result | synthesized texture + lip points"})
    jaw_correction: bool = field(default=True,
        metadata={"help": "§3.4.1 jaw correction"})
    jaw_band_px: float = field(default=6.0,
        metadata={"help": "width of the jawline alpha map (texture px)"})
    feather_px: float = field(default=2.0,
        metadata={"help": "softness of the layer masks (texture px)"})
    neck_depth: float = field(default=0.3,
        metadata={"help": "neck layer below the chin, × nose-to-chin height"})
    colour_match: bool = field(default=True,
        metadata={"help": "match the synthesized skin's Lab mean/std to the target frame's"})
    pyramid_levels: int = field(default=5,
        metadata={"help": "Laplacian pyramid levels of the blend"})
    sharpen: float = field(default=0.5,
        metadata={"help": "unsharp-mask amount on the rendered face: undoes the crop → texture → frame resampling blur (0: off)"})
    sharpen_sigma: float = field(default=1.0,
        metadata={"help": "Gaussian σ of that unsharp mask (px)"})
    threads: int = field(default=2,
        metadata={"help": "frames composited in parallel"})
    crf: int = field(default=18,
        metadata={"help": "H.264 quality (x264 CRF: lower is better and larger)"})
    preset: str = field(default="veryfast",
        metadata={"help": "x264 encoder preset (speed against file size)"})
    audio_rate: int = field(default=48000,
        metadata={"help": "AAC sample rate of the muxed audio (Hz)"})
    self_check: bool = field(default=True,
        metadata={"help": "dlib re-reads the mouth of every output frame; frames that fail the check fall back to the target frame"})
    check_max_error: float = field(default=0.12,
        metadata={"help": "self-check: fall back when the re-read mouth is further than this × IOD from the synthesized one (mean point distance)"})
    check_max_face_error: float = field(default=0.1,
        metadata={"help": "self-check: fall back when the re-read nose and chin are further than this × IOD from the target's (the chin moved with the synthesized lower lip)"})
    check_max_sharpness: float = field(default=4.0,
        metadata={"help": "self-check: fall back when the mouth box is this many times sharper (Laplacian energy) than the target's"})
    check_fade_frames: int = field(default=3,
        metadata={"help": "cross-fade length (frames) into and out of a fallback"})


@dataclass
class Speak:
    same_speaker_distance: float = field(default=0.5,
        metadata={"help": "face-descriptor distance below which the target is the model's speaker"})
    identity_frames: int = field(default=20,
        metadata={"help": "target frames whose face descriptors make its identity"})
    min_mouth_shapes: int = field(default=30,
        metadata={"help": "warn when another person's target covers fewer distinct mouth shapes"})
    max_reprojection_median: float = field(default=0.08,
        metadata={"help": "refuse a target whose median 3D-fit reprojection error (× IOD) is above this"})
    max_pose_jump_deg: float = field(default=10.0,
        metadata={"help": "report head-pose jumps above this between consecutive frames (degrees)"})
    audio_shift_factor: float = field(default=1.2,
        metadata={"help": "warn when the audio's mean MFCC is further from the training audio than this × the furthest of the corpus's held-out clips"})
    target_shard_frames: int = field(default=64,
        metadata={"help": "frames per shard of a target's cached stores (one task each; a multiple of the chunk_frames)", "advanced": True})


@dataclass
class Evaluate:
    clips: int = field(default=3,
        metadata={"help": "validation clips evaluated, spread over the validation split by name (fewer if there are fewer)"})
    out: str = field(default="outputs/evaluate",
        metadata={"help": "folder: per clip <clip>.mp4 (result), <clip>.diagnostic.mp4, <clip>.opening.csv"})
    metrics: str = field(default="metrics/evaluate.json",
        metadata={"help": "DVC metrics: per-clip measures and their medians"})
    exclude_target_from_pool: bool = field(default=True,
        metadata={"help": "candidates only from other videos, so the true frames cannot be copied"})
    diagnostic: bool = field(default=True,
        metadata={"help": "also write <clip>.diagnostic.mp4: target | result | texture (shown in the report)"})


@dataclass
class Report:
    out: str = field(default="reports/synthetic_speaker",
        metadata={"help": "folder of the HTML report: index.html + its assets"})
    title: str = field(default="lipsynth — synthetic speaker",
        metadata={"help": "page title"})
    paper_delay_ms: float = field(default=200.0,
        metadata={"help": "the paper's target delay, marked on the delay sweep (ms)"})
    benches: str | None = field(default=None,
        metadata={"help": "a folder of bench results to show too (other voices, the speak path; bench/report.py sets it)"})


@dataclass
class Params:
    """The whole params file: one attribute per section."""

    synthetic_speaker: SyntheticSpeaker = field(default_factory=SyntheticSpeaker)
    data: Data = field(default_factory=Data)
    cluster: Cluster = field(default_factory=Cluster)
    ingest: Ingest = field(default_factory=Ingest)
    landmarks: Landmarks = field(default_factory=Landmarks)
    frontalize: Frontalize = field(default_factory=Frontalize)
    pca: Pca = field(default_factory=Pca)
    phonetic: Phonetic = field(default_factory=Phonetic)
    whisper: Whisper = field(default_factory=Whisper)
    train: Train = field(default_factory=Train)
    brand: Brand = field(default_factory=Brand)
    karras: Karras = field(default_factory=Karras)
    render_mesh: RenderMesh = field(default_factory=RenderMesh)
    delay_sweep: DelaySweep = field(default_factory=DelaySweep)
    synthesize: Synthesize = field(default_factory=Synthesize)
    composite: Composite = field(default_factory=Composite)
    speak: Speak = field(default_factory=Speak)
    evaluate: Evaluate = field(default_factory=Evaluate)
    report: Report = field(default_factory=Report)


SECTIONS = {f.name: f.default_factory for f in dataclasses.fields(Params)}
FEATURE_STORE_OF = {"whisper": "whisper", "phonetic": "phonetic", "mfcc+phonetic": "phonetic", "mfcc": "ingest"}


def front_end_store(params) -> str:
    """The store ``train.features`` reads — the path ``train.feature_store`` must name: ``whisper.out``,
    ``phonetic.out`` or ``ingest.out`` (MFCC). ``params``: a ``Params`` or a params dict."""
    get = (lambda s, k: params[s][k]) if isinstance(params, dict) else (lambda s, k: getattr(getattr(params, s), k))
    return get(FEATURE_STORE_OF[get("train", "features")], "out")


def _type_ok(value, kind) -> bool:
    """Does ``value`` (from YAML) fit the annotation ``kind``? ints are accepted for floats."""
    if kind is typing.Any:
        return True
    origin = typing.get_origin(kind)
    if origin in (typing.Union, types.UnionType):
        return any(_type_ok(value, k) for k in typing.get_args(kind))
    if kind is type(None):
        return value is None
    if kind is bool:
        return isinstance(value, bool)
    if kind is int:
        return isinstance(value, int) and not isinstance(value, bool)
    if kind is float:
        return isinstance(value, (int, float)) and not isinstance(value, bool)
    if kind is list or origin is list:
        return isinstance(value, (list, tuple))
    return isinstance(value, kind)


def _type_name(kind) -> str:
    if typing.get_origin(kind) in (typing.Union, types.UnionType):
        return " or ".join(_type_name(k) for k in typing.get_args(kind))
    return "null" if kind is type(None) else getattr(kind, "__name__", str(kind))


def check(section, name: str, where: str = "params") -> None:
    """Validate one section object (types and choices); raise ParameterError naming the key.
    A key whose type is itself a section (``cluster.security``) is checked the same way."""
    hints = typing.get_type_hints(type(section))
    for f in dataclasses.fields(section):
        value = getattr(section, f.name)
        if dataclasses.is_dataclass(hints[f.name]):
            if not isinstance(value, hints[f.name]):
                raise ParameterError(f"{where}: {name}.{f.name}={value!r}: expected a mapping of keys")
            check(value, f"{name}.{f.name}", where)
            continue
        if not _type_ok(value, hints[f.name]):
            raise ParameterError(f"{where}: {name}.{f.name}={value!r}: expected {_type_name(hints[f.name])}")
        if isinstance(value, str) and f.name in getattr(type(section), "AUTO", ()) and value != "auto":
            raise ParameterError(f"{where}: {name}.{f.name}={value!r}: expected an int or auto")
        choices = getattr(type(section), "CHOICES", {}).get(f.name)
        if choices and value not in choices:
            raise ParameterError(f"{where}: {name}.{f.name}={value!r}: choose one of {', '.join(choices)}")


def parse(tree: dict, where: str = "params") -> Params:
    """Typed ``Params`` from a nested dict (a loaded params.yaml); see the module doc."""
    if not isinstance(tree, dict):
        raise ParameterError(f"{where}: expected a mapping of sections")
    unknown = sorted(set(tree) - set(SECTIONS))
    if unknown:
        raise ParameterError(f"{where}: unknown section '{unknown[0]}' (sections: {', '.join(SECTIONS)})")
    sections = {}
    for name, make in SECTIONS.items():
        values = tree.get(name) or {}
        if not isinstance(values, dict):
            raise ParameterError(f"{where}: section '{name}' must be a mapping of keys, got {values!r}")
        section = _fill(make(), values, name, where)
        check(section, name, where)
        sections[name] = section
    return Params(**sections)


def _fill(section, values: dict, name: str, where: str):
    """``section`` with the keys of ``values`` set; a nested section (``cluster.security``) is
    filled from its own mapping. Unknown keys stop with one line naming them."""
    known = {f.name for f in dataclasses.fields(section)}
    bad = sorted(set(values) - known)
    if bad:
        raise ParameterError(f"{where}: unknown key {name}.{bad[0]} (known keys: {', '.join(sorted(known))})")
    for k, v in values.items():
        current = getattr(section, k)
        if dataclasses.is_dataclass(current) and isinstance(v, dict):
            v = _fill(type(current)(), v, f"{name}.{k}", where)
        elif dataclasses.is_dataclass(current) and v is None:
            v = type(current)()                # `security:` left empty = the defaults
        setattr(section, k, v)
    return section


def load_params(path: str | os.PathLike | None = None) -> Params:
    """Read and validate a params file (default ``$LIPSYNTH_PARAMS`` or ./params.yaml)."""
    path = Path(path) if path is not None else PARAMS_FILE
    if not path.exists():
        raise ParameterError(f"{path}: params file not found (run from the project root)")
    try:
        tree = yaml.safe_load(path.read_text()) or {}
    except yaml.YAMLError as exc:
        raise ParameterError(f"{path}: not valid YAML ({str(exc).splitlines()[0]})") from None
    return parse(tree, str(path))


def as_dict(section) -> dict:
    """A section (or the whole tree) as plain dicts, e.g. to record it beside a model."""
    return dataclasses.asdict(section)
