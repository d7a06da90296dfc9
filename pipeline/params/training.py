"""Sections of the model stages: train (LSTM), brand (Voice Puppetry), karras, render_mesh,
delay_sweep."""
from __future__ import annotations

from dataclasses import dataclass, field

from .section import Section, bad


@dataclass
class Train(Section):
    model: str = "lstm"
    out: str = "models/lstm"
    metrics: str = "metrics/train.json"
    plots: str = "plots/train_loss.csv"
    delay: int = 0
    hidden: int = field(default=60, metadata={"min": 1})
    layers: int = field(default=1, metadata={"min": 1})
    batch_size: int = field(default=100, metadata={"min": 1})
    bptt: int = field(default=100, metadata={"min": 1})
    lr: float = 0.001
    steps: int = field(default=300, metadata={"min": 1})
    val_every: int = field(default=10, metadata={"min": 1})
    patience: int | None = None
    min_delta: float = 0.0
    baselines: bool = True
    feature_norm: str = "corpus"
    features: str = "whisper"
    feature_store: str = "store/whisper.zarr"
    vtlp_warps: list = field(default_factory=list)
    pitch_shifts: list = field(default_factory=list)
    extra_corpora: list = field(default_factory=list)
    extra_repeat: int = field(default=1, metadata={"min": 1})
    init_from: str | None = None
    fine_tune: str = "all"
    train_seconds: float | None = None
    seed: int = 0
    velocity_weight: float = field(default=0.0, metadata={"min": 0.0})
    opening_corr_weight: float = field(default=0.0, metadata={"min": 0.0})
    device: str = "auto"
    bank_frames: int = field(default=3000, metadata={"min": 1})
    identity_frames: int = field(default=60, metadata={"min": 1})

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
    out: str = "models/brand"
    metrics: str = "metrics/train_brand.json"
    plots: str = "plots/train_brand.csv"
    rate: float = 25.0
    features: str = "whisper"
    voice_dims: int = field(default=24, metadata={"min": 1})
    face_dims: int = 12
    states: int = 26
    prior_weight: float = 1.0
    trim: bool = True
    iterations: int = 60
    tolerance: float = 1e-4
    reg: float = 1e-3
    min_state_frames: float = 25.0
    decode: str = "viterbi"
    baseline: bool = True
    train_seconds: float | None = None
    seed: int = 0

    CHOICES = {"features": ("paper", "mfcc", "whisper"), "decode": ("viterbi", "posterior")}


@dataclass
class Karras(Section):
    out: str = "models/karras"
    metrics: str = "metrics/train_karras.json"
    plots: str = "plots/train_karras_loss.csv"
    train_seconds: float | None = None
    steps: int = 120
    batch: int = 100
    lr: float = 0.003
    emotion_dim: int = 16
    emotion_sigma: float = 0.01
    motion: bool = True
    emotions: bool = True
    time_shift: bool = True
    val_every: int = 12
    patience: int | None = None
    min_delta: float = 0.0
    val_frames: int = 2000
    mine_candidates: int = 500
    mine_probes: int = 8
    mine_playback: int = 64
    mine_playback_clips: int = 8
    emotion_clusters: int = 8
    seed: int = 0
    device: str = "auto"
    threads: int | None = None


@dataclass
class RenderMesh(Section):
    model: str = "models/karras"
    out: str = "outputs/synthetic_speaker_3d/karras_mesh.mp4"
    export: str = "outputs/synthetic_speaker_3d/karras_head"
    fps: float = 25.0
    size: int = 512
    step_mm: float = 2.0
    emotion: int | str | None = None
    footage: str = "store/frontalize.zarr"
    blinks: bool = True
    head_motion: bool = True


@dataclass
class DelaySweep(Section):
    delays: list = field(default_factory=lambda: [0, 5, 10, 20, 40])
    steps: int = 300
    plots: str = "plots/delay_sweep.csv"
