"""Sections of synthesis and its applications: synthesize, composite, speak, evaluate, report."""
from __future__ import annotations

from dataclasses import dataclass, field

from .section import Section, bad


@dataclass
class Synthesize(Section):
    audio: str = "data/synthetic_speaker/speaker_03.mp4"
    target: str = "speaker_00"
    model: str = "models/lstm"
    out: str = "store/synthesize.zarr"
    retime: bool = True
    alpha_b: float = 1.0
    alpha_s: float = 2.0
    alpha_u: float = 2.0
    blink_threshold: float = 0.010
    speech_threshold_db: float = -35.0
    n: int = field(default=50, metadata={"min": 1})
    alpha: float = 0.9
    pool_min: int = field(default=500, metadata={"min": 1})
    pool_max: int = field(default=4000, metadata={"min": 1})
    retarget: str = "auto"
    max_spread_gain: float = field(default=3.0, metadata={"min": 1.0})
    exclude_target_from_pool: bool = False
    teeth_upper: int | None = None
    teeth_lower: int | None = None
    teeth_sigmas: list = field(default_factory=lambda: [1.0, 2.0, 4.0])
    teeth_strength: float = 0.3
    teeth_s_max: float = field(default=0.45, metadata={"min": 0, "max": 1})
    teeth_v_min: float = field(default=0.45, metadata={"min": 0, "max": 1})
    teeth_feather_px: float = 1.0
    unsharp_sigma: float = 1.0
    unsharp_amount: float = 0.25
    detail: str = "auto"
    detail_candidates: int = field(default=8, metadata={"min": 1})
    detail_switch_cost: float = field(default=6.0, metadata={"min": 0.0})
    detail_hold_cost: float = field(default=1.0, metadata={"min": 0.0})
    detail_fade_frames: int = field(default=3, metadata={"min": 0})
    detail_band_px: float = field(default=2.0, metadata={"min": 0.3})
    detail_warp_px: float = field(default=8.0, metadata={"min": 1.0})
    median_max_size: int = field(default=256, metadata={"min": 64})
    min_target_fraction: float = field(default=0.5, metadata={"min": 0, "max": 1})
    threads: int = field(default=2, metadata={"min": 1})
    device: str = "auto"
    emotion: int | str | None = None

    CHOICES = {"retarget": ("auto", "always", "never"), "detail": ("auto", "median", "aligned", "two_band", "warped")}

    def validate(self) -> None:
        super().validate()
        if self.median_max_size % 16:
            raise bad("median_max_size", self.median_max_size, "must be a multiple of 16 (I420 textures)")


@dataclass
class Composite(Section):
    CHOICES = {"preset": ("ultrafast", "superfast", "veryfast", "faster", "fast", "medium", "slow", "slower",
                          "veryslow", "placebo")}
    out_dir: str = "outputs/synthetic_speaker"
    diagnostic: bool = True
    jaw_correction: bool = True
    jaw_band_px: float = 6.0
    feather_px: float = 2.0
    neck_depth: float = 0.3
    colour_match: bool = True
    pyramid_levels: int = field(default=5, metadata={"min": 1, "max": 10})
    sharpen: float = 0.5
    sharpen_sigma: float = 1.0
    threads: int = field(default=2, metadata={"min": 1})
    crf: int = field(default=18, metadata={"min": 0, "max": 51})
    preset: str = "veryfast"
    x264_options: str = ""
    audio_rate: int = field(default=48000, metadata={"min": 8000, "max": 192000})
    self_check: bool = True
    check_max_error: float = 0.12
    check_max_face_error: float = 0.1
    check_max_sharpness: float = 4.0
    check_fade_frames: int = field(default=3, metadata={"min": 0})

    def validate(self) -> None:
        super().validate()
        if self.x264_options and not all("=" in o for o in self.x264_options.split(":")):
            raise bad("x264_options", self.x264_options, "must be x264-params 'key=value:key=value' (or '')")


@dataclass
class Speak(Section):
    same_speaker_distance: float = 0.5
    identity_frames: int = field(default=20, metadata={"min": 1})
    min_mouth_shapes: int = 30
    max_reprojection_median: float = 0.08
    max_pose_jump_deg: float = 10.0
    audio_shift_factor: float = 1.2
    target_shard_frames: int = field(default=64, metadata={"min": 1})
    warn_fallback_share: float = 0.1
    max_fallback_share: float = 0.5


@dataclass
class Evaluate(Section):
    clips: int = field(default=3, metadata={"min": 1})
    out: str = "outputs/evaluate"
    metrics: str = "metrics/evaluate.json"
    exclude_target_from_pool: bool = True
    diagnostic: bool = True


@dataclass
class Report(Section):
    out: str = "reports/synthetic_speaker"
    title: str = "lipsynth — synthetic speaker"
    paper_delay_ms: float = 200.0
    benches: str | None = None
