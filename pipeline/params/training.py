"""Sections of the model stages: train (LSTM), brand (Voice Puppetry), karras, render_mesh,
delay_sweep."""
from __future__ import annotations

from dataclasses import dataclass, field

from .section import Section, bad


@dataclass
class Train(Section):
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
        metadata={"help": "LSTM cells", "min": 1})
    layers: int = field(default=1,
        metadata={"help": "stacked LSTM layers", "min": 1})
    batch_size: int = field(default=100,
        metadata={"help": "parallel training streams (fewer when the corpus is small)", "min": 1})
    bptt: int = field(default=100,
        metadata={"help": "truncated back-propagation window (steps)", "min": 1})
    lr: float = field(default=0.001,
        metadata={"help": "Adam learning rate"})
    steps: int = field(default=300,
        metadata={"help": "training budget in optimizer steps (one per bptt window of ≤ batch_size streams)", "min": 1})
    val_every: int = field(default=10,
        metadata={"help": "optimizer steps between validation points (the loss curve)", "min": 1})
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
        metadata={"help": "each video of extra_corpora is used this many times", "min": 1})
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
        metadata={"help": "training frames (frontal texture, landmarks, pose) in the model folder's candidate bank for `lipsynth speak`", "min": 1})
    identity_frames: int = field(default=60,
        metadata={"help": "frames whose face descriptors make the speaker's identity", "min": 1})

    CHOICES = {"model": ("lstm",), "feature_norm": ("corpus", "utterance"), "fine_tune": ("all", "output"),
               "features": ("mfcc", "phonetic", "mfcc+phonetic", "whisper")}

    def validate(self) -> None:
        super().validate()
        if self.vtlp_warps or self.pitch_shifts:
            if "mfcc" not in self.features:
                raise bad("vtlp_warps / pitch_shifts", self.features, "augment MFCC: this train.features has none")
            if self.extra_corpora:
                raise bad("vtlp_warps / pitch_shifts", self.extra_corpora, "do not apply to train.extra_corpora")
        for a in self.vtlp_warps:
            if not isinstance(a, (int, float)) or not 0.7 <= a <= 1.3:
                raise bad("vtlp_warps", a, "is not a warp factor between 0.7 and 1.3")
        for a in self.pitch_shifts:
            if not isinstance(a, (int, float)) or not -12 <= a <= 12:
                raise bad("pitch_shifts", a, "is not a shift between -12 and 12 semitones")


@dataclass
class Brand(Section):
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
        metadata={"help": "whisper: PCA dims of the encoder states kept for the voice Gaussians", "min": 1})
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
class Karras(Section):
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
class RenderMesh(Section):
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
class DelaySweep(Section):
    delays: list = field(default_factory=lambda: [0, 5, 10, 20, 40],
        metadata={"help": "target delays to compare (10 ms steps)"})
    steps: int = field(default=300,
        metadata={"help": "budget per delay in optimizer steps (the other settings come from train)"})
    plots: str = field(default="plots/delay_sweep.csv",
        metadata={"help": "DVC plot: validation loss per delay (CSV)"})
