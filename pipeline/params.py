"""``params.yaml`` as typed sections, validated once when it is loaded.

One dataclass per section (``data``, ``cluster`` and one per stage). ``load_params`` reads the
file, checks every key against its section's fields — an unknown key, a missing section, a
value of the wrong type or outside its allowed choices stops with one line naming
``section.key`` — and returns a ``Params`` whose sections are read as attributes
(``params.ingest.crop_size``). A key the file leaves out takes the default below, which equals
the shipped params.yaml. Code never reads raw dicts of parameters.

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
    seed: int = 7
    n_videos: int = 6
    seconds_per_video: float = 10.0
    fps: int = 25
    width: int = 360
    height: int = 288
    sample_rate: int = 16000
    out_dir: str = "data/synthetic_speaker"


@dataclass
class Data:
    videos: str | list = "data/synthetic_speaker"
    val_fraction: float = 0.2
    split_seed: int = 0
    split: str = "video"
    on_bad_input: str = "error"

    CHOICES = {"on_bad_input": ("error", "skip"), "split": ("video", "time")}


@dataclass
class ClusterSecurity:
    """TLS for ``cluster.address = tls://…`` (``distributed.security.Security``): PEM files."""
    tls_ca_file: str | None = None         # the CA that signed the scheduler's and workers' certificates
    tls_client_cert: str | None = None     # this client's certificate (may hold the key too)
    tls_client_key: str | None = None      # its private key (null: inside tls_client_cert)
    require_encryption: bool = False       # refuse a tcp:// address


@dataclass
class Cluster:
    address: str | None = None
    n_workers: int | None = None
    memory_limit: str | int | float = "auto"
    connect_timeout: float = 30.0
    security: ClusterSecurity = field(default_factory=ClusterSecurity)


@dataclass
class Ingest:
    out: str = "store/ingest.zarr"
    crop_size: int | str = "auto"
    max_crop_size: int = 448
    crop_scale: float = 2.0
    crop_shift_down: float = 0.3
    detect_samples: int = 8
    detect_upsample: int = 1
    min_face_px: float = 40
    min_seconds: float = 0.5
    min_fps: float = 10
    max_fps: float = 120
    rms_target_dbfs: float = -23.0
    shard_frames: int = 256
    shard_seconds: int = 10
    chunk_frames: int = 8

    AUTO = ("crop_size",)            # an int, or "auto": follow the face's size in the footage


@dataclass
class Landmarks:
    out: str = "store/landmarks.zarr"
    detect_every: int = 50
    detect_upsample: int = 1
    jitter: float = 0.05
    min_confidence: float = 0.5
    margin: float = 0.1
    min_valid_fraction: float = 0.5


@dataclass
class Frontalize:
    out: str = "store/frontalize.zarr"
    focal_factor: float = 1.5
    model_frames: int = 300
    min_conditioning: float = 6.0
    ba_iterations: int = 100
    grid_mm: float = 2.0
    grid_x_mm: list = field(default_factory=lambda: [-110, 110])
    grid_y_mm: list = field(default_factory=lambda: [-80, 220])
    data_weight: float = 100.0
    boundary_weight: float = 100.0
    texture_size: int | str = "auto"
    max_texture_size: int = 256
    texture_x_mm: list = field(default_factory=lambda: [-80, 80])
    texture_y_mm: list = field(default_factory=lambda: [20, 180])
    max_reprojection: float = 0.15
    cloth_dark_value: int = 50
    cloth_white_saturation: int = 40
    cloth_white_value: int = 185
    cloth_dilate_px: int = 2
    inpaint_radius: float = 3.0
    chunk_frames: int = 8

    AUTO = ("texture_size",)         # an int, or "auto": as fine as the face in the stored crops


@dataclass
class Pca:
    out: str = "store/pca.zarr"
    n_components: int = 20


@dataclass
class Phonetic:
    out: str = "store/phonetic.zarr"


@dataclass
class Whisper:
    out: str = "store/whisper.zarr"
    window_seconds: float = 10.0
    overlap_seconds: float = 2.0


@dataclass
class Train:
    model: str = "lstm"
    out: str = "models/lstm"
    metrics: str = "metrics/train.json"
    plots: str = "plots/train_loss.csv"
    delay: int = 0
    hidden: int = 60
    layers: int = 1
    batch_size: int = 100
    bptt: int = 100
    lr: float = 0.001
    steps: int = 300
    val_every: int = 10
    patience: int | None = None
    min_delta: float = 0.0
    baselines: bool = True
    feature_norm: str = "corpus"
    features: str = "whisper"
    vtlp_warps: list = field(default_factory=list)
    pitch_shifts: list = field(default_factory=list)
    extra_corpora: list = field(default_factory=list)
    extra_repeat: int = 1
    init_from: str | None = None
    fine_tune: str = "all"
    train_seconds: float | None = None
    seed: int = 0
    device: str = "auto"
    bank_frames: int = 3000
    identity_frames: int = 60

    CHOICES = {"model": ("lstm",), "feature_norm": ("corpus", "utterance"), "fine_tune": ("all", "output"),
               "features": ("mfcc", "phonetic", "mfcc+phonetic", "whisper")}


@dataclass
class Brand:
    out: str = "models/brand"
    metrics: str = "metrics/train_brand.json"
    plots: str = "plots/train_brand.csv"
    rate: float = 25.0
    features: str = "whisper"
    voice_dims: int = 24
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
class Karras:
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
class RenderMesh:
    model: str = "models/karras"
    out: str = "outputs/synthetic_speaker_3d/karras_mesh.mp4"
    fps: float = 25.0
    size: int = 360
    step_mm: float = 2.5
    emotion: int | str | None = None


@dataclass
class DelaySweep:
    delays: list = field(default_factory=lambda: [0, 5, 10, 20, 40])
    steps: int = 300
    plots: str = "plots/delay_sweep.csv"


@dataclass
class Synthesize:
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
    n: int = 50
    alpha: float = 0.9
    pool_min: int = 500
    pool_max: int = 4000
    retarget: str = "auto"
    exclude_target_from_pool: bool = False
    teeth_upper: int | None = None
    teeth_lower: int | None = None
    teeth_sigmas: list = field(default_factory=lambda: [1.0, 2.0, 4.0])
    teeth_strength: float = 0.3
    teeth_s_max: float = 0.45
    teeth_v_min: float = 0.45
    teeth_feather_px: float = 1.0
    unsharp_sigma: float = 1.0
    unsharp_amount: float = 0.25
    min_target_fraction: float = 0.5
    threads: int = 2
    device: str = "auto"
    emotion: int | str | None = None

    CHOICES = {"retarget": ("auto", "always", "never")}


@dataclass
class Composite:
    out_dir: str = "outputs/synthetic_speaker"
    diagnostic: bool = True
    jaw_correction: bool = True
    jaw_band_px: float = 6.0
    feather_px: float = 2.0
    neck_depth: float = 0.3
    colour_match: bool = True
    pyramid_levels: int = 5
    sharpen: float = 0.5
    sharpen_sigma: float = 1.0
    threads: int = 2
    crf: int = 18
    preset: str = "veryfast"
    audio_rate: int = 48000
    self_check: bool = True
    check_max_error: float = 0.12
    check_max_sharpness: float = 4.0
    check_fade_frames: int = 3


@dataclass
class Speak:
    same_speaker_distance: float = 0.5
    identity_frames: int = 20
    min_mouth_shapes: int = 30
    max_reprojection_median: float = 0.08
    max_pose_jump_deg: float = 10.0
    audio_shift_factor: float = 1.2
    target_shard_frames: int = 64


@dataclass
class Evaluate:
    clips: int = 3
    out: str = "outputs/evaluate"
    metrics: str = "metrics/evaluate.json"
    exclude_target_from_pool: bool = True
    diagnostic: bool = True


@dataclass
class Report:
    out: str = "reports/synthetic_speaker"
    title: str = "lipsynth — synthetic speaker"
    paper_delay_ms: float = 200.0
    benches: str | None = None


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
