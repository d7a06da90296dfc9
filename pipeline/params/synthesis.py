"""Sections of synthesis and its applications: synthesize, composite, speak, evaluate, report."""
from __future__ import annotations

from dataclasses import dataclass, field

from .section import Section, bad


@dataclass
class Synthesize(Section):
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
        metadata={"help": "candidate frames per output frame", "min": 1})
    alpha: float = field(default=0.9,
        metadata={"help": "Eq. 12: weight share of the n candidates"})
    pool_min: int = field(default=500,
        metadata={"help": "add corpus training frames when the target has fewer frames than this", "min": 1})
    pool_max: int = field(default=4000,
        metadata={"help": "most frames in the candidate pool", "min": 1})
    retarget: str = field(default="auto",
        metadata={"help": "move predicted shapes onto the target's mean mouth: auto = when the model's PCA basis differs (another corpus) | always | never"})
    max_spread_gain: float = field(default=3.0,
        metadata={"help": "re-targeted shapes: widen their spread toward the target's own mouth motion (RMS), by at most this factor (1: off)", "min": 1.0})
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
        metadata={"help": "teeth pixels: HSV saturation (0–1) at most this", "min": 0, "max": 1})
    teeth_v_min: float = field(default=0.45,
        metadata={"help": "teeth pixels: HSV value (0–1) at least this", "min": 0, "max": 1})
    teeth_feather_px: float = field(default=1.0,
        metadata={"help": "Gaussian σ of the teeth/mouth mask borders (px)"})
    unsharp_sigma: float = field(default=1.0,
        metadata={"help": "§3.2 unsharp mask of the mouth region: Gaussian σ (px)"})
    unsharp_amount: float = field(default=0.25,
        metadata={"help": "§3.2 unsharp mask of the mouth region: amount a in I + a (I − G*I)"})
    detail: str = field(default="auto",
        metadata={"help": "median: §3.2 (weighted median, teeth, unsharp) | aligned: candidates warped first | two_band: + a real frame's detail | auto: two_band from 160 px"})
    detail_candidates: int = field(default=8,
        metadata={"help": "two_band: nearest candidates per frame the Viterbi picks the detail source from", "min": 1})
    detail_switch_cost: float = field(default=6.0,
        metadata={"help": "two_band: Viterbi cost of switching to another source (units: lip-shape distance / σ²)", "min": 0.0})
    detail_hold_cost: float = field(default=1.0,
        metadata={"help": "two_band: Viterbi cost of holding one source frame (moving to its next frame costs 0)", "min": 0.0})
    detail_fade_frames: int = field(default=3,
        metadata={"help": "two_band: frames a switch of detail source is cross-faded over", "min": 0})
    detail_band_px: float = field(default=2.0,
        metadata={"help": "two_band: σ (px at texture 128) splitting the median's low band from the real frame's detail", "min": 0.3})
    detail_warp_px: float = field(default=8.0,
        metadata={"help": "aligned, two_band: reach σ (px at texture 128) of the landmark warps (candidates, detail source)", "min": 1.0})
    median_max_size: int = field(default=256,
        metadata={"help": "the weighted median runs at most at this texture size (px, multiple of 16), then is upsampled; "
                          "two_band's detail keeps the full size", "min": 64})
    min_target_fraction: float = field(default=0.5,
        metadata={"help": "a target with a face in a smaller share of its frames is refused", "min": 0, "max": 1})
    threads: int = field(default=2,
        metadata={"help": "frames synthesized in parallel (threads)", "min": 1})
    device: str = field(default="auto",
        metadata={"help": "torch device of the model; auto: CUDA when present, else CPU"})
    emotion: int | str | None = field(default=None,
        metadata={"help": "Karras models only: a mined emotion K, or K1:K2:t to interpolate (null: the model's default)"})

    CHOICES = {"retarget": ("auto", "always", "never"), "detail": ("auto", "median", "aligned", "two_band")}

    def validate(self) -> None:
        super().validate()
        if self.median_max_size % 16:
            raise bad("median_max_size", self.median_max_size, "must be a multiple of 16 (I420 textures)")


@dataclass
class Composite(Section):
    CHOICES = {"preset": ("ultrafast", "superfast", "veryfast", "faster", "fast", "medium", "slow", "slower",
                          "veryslow", "placebo")}
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
        metadata={"help": "Laplacian pyramid levels of the blend", "min": 1, "max": 10})
    sharpen: float = field(default=0.5,
        metadata={"help": "unsharp-mask amount on the rendered face: undoes the crop → texture → frame resampling blur (0: off)"})
    sharpen_sigma: float = field(default=1.0,
        metadata={"help": "Gaussian σ of that unsharp mask (px)"})
    threads: int = field(default=2,
        metadata={"help": "frames composited in parallel", "min": 1})
    crf: int = field(default=18,
        metadata={"help": "H.264 quality (x264 CRF: lower is better and larger)", "min": 0, "max": 51})
    preset: str = field(default="veryfast",
        metadata={"help": "x264 encoder preset (speed against file size and detail; docs/encode.md measures settings)"})
    x264_options: str = field(default="",
        metadata={"help": "x264-params added to the preset ('key=value:…', e.g. 'subme=1'; '' for none): faster settings cost the mouth some detail (docs/encode.md)", "advanced": True})
    audio_rate: int = field(default=48000,
        metadata={"help": "AAC sample rate of the muxed audio (Hz)", "min": 8000, "max": 192000})
    self_check: bool = field(default=True,
        metadata={"help": "dlib re-reads the mouth of every output frame; frames that fail the check fall back to the target frame"})
    check_max_error: float = field(default=0.12,
        metadata={"help": "self-check: fall back when the re-read mouth is further than this × IOD from the synthesized one (mean point distance)"})
    check_max_face_error: float = field(default=0.1,
        metadata={"help": "self-check: fall back when the re-read nose and chin are further than this × IOD from the target's (the chin moved with the synthesized lower lip)"})
    check_max_sharpness: float = field(default=4.0,
        metadata={"help": "self-check: fall back when the mouth box is this many times sharper (Laplacian energy) than the target's"})
    check_fade_frames: int = field(default=3,
        metadata={"help": "cross-fade length (frames) into and out of a fallback", "min": 0})

    def validate(self) -> None:
        super().validate()
        if self.x264_options and not all("=" in o for o in self.x264_options.split(":")):
            raise bad("x264_options", self.x264_options, "must be x264-params 'key=value:key=value' (or '')")


@dataclass
class Speak(Section):
    same_speaker_distance: float = field(default=0.5,
        metadata={"help": "face-descriptor distance below which the target is the model's speaker"})
    identity_frames: int = field(default=20,
        metadata={"help": "target frames whose face descriptors make its identity", "min": 1})
    min_mouth_shapes: int = field(default=30,
        metadata={"help": "warn when another person's target covers fewer distinct mouth shapes"})
    max_reprojection_median: float = field(default=0.08,
        metadata={"help": "refuse a target whose median 3D-fit reprojection error (× IOD) is above this"})
    max_pose_jump_deg: float = field(default=10.0,
        metadata={"help": "report head-pose jumps above this between consecutive frames (degrees)"})
    audio_shift_factor: float = field(default=1.2,
        metadata={"help": "warn when the audio's mean MFCC is further from the training audio than this × the furthest of the corpus's held-out clips"})
    target_shard_frames: int = field(default=64,
        metadata={"help": "frames per shard of a target's cached stores (one task each; a multiple of the chunk_frames)", "advanced": True, "min": 1})
    warn_fallback_share: float = field(default=0.1,
        metadata={"help": "say so (one line: the share and its cause) when more than this share of the output frames fell back to the untouched target"})
    max_fallback_share: float = field(default=0.5,
        metadata={"help": "exit non-zero when more than this share of the output frames fell back to the untouched target (the file is still written: the line says so)"})


@dataclass
class Evaluate(Section):
    clips: int = field(default=3,
        metadata={"help": "validation clips evaluated, spread over the validation split by name (fewer if there are fewer)", "min": 1})
    out: str = field(default="outputs/evaluate",
        metadata={"help": "folder: per clip <clip>.mp4 (result), <clip>.diagnostic.mp4, <clip>.opening.csv"})
    metrics: str = field(default="metrics/evaluate.json",
        metadata={"help": "DVC metrics: per-clip measures and their medians"})
    exclude_target_from_pool: bool = field(default=True,
        metadata={"help": "candidates only from other videos, so the true frames cannot be copied"})
    diagnostic: bool = field(default=True,
        metadata={"help": "also write <clip>.diagnostic.mp4: target | result | texture (shown in the report)"})


@dataclass
class Report(Section):
    out: str = field(default="reports/synthetic_speaker",
        metadata={"help": "folder of the HTML report: index.html + its assets"})
    title: str = field(default="lipsynth — synthetic speaker",
        metadata={"help": "page title"})
    paper_delay_ms: float = field(default=200.0,
        metadata={"help": "the paper's target delay, marked on the delay sweep (ms)"})
    benches: str | None = field(default=None,
        metadata={"help": "a folder of bench results to show too (other voices, the speak path; bench/report.py sets it)"})
