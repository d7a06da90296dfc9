"""Sections of the data and preprocessing stages: synthetic_speaker, data, cluster, ingest,
landmarks, frontalize, pca, phonetic, whisper."""
from __future__ import annotations

from dataclasses import dataclass, field

from .section import Section, bad


@dataclass
class SyntheticSpeaker(Section):
    seed: int = field(default=7,
        metadata={"help": "master seed; video i uses the sub-seed (seed, i)"})
    n_videos: int = field(default=6,
        metadata={"help": "number of clips generated (speaker_00.mp4, speaker_01.mp4, …)", "min": 1})
    seconds_per_video: float = field(default=10.0,
        metadata={"help": "clip length (s)", "min": 0.5})
    fps: int = field(default=25,
        metadata={"help": "video frame rate (frames/s)", "min": 1, "max": 240})
    width: int = field(default=360,
        metadata={"help": "frame width (px, even)", "min": 32})
    height: int = field(default=288,
        metadata={"help": "frame height (px, even)", "min": 32})
    sample_rate: int = field(default=16000,
        metadata={"help": "audio sample rate (Hz), mono", "min": 8000, "max": 192000})
    out_dir: str = field(default="data/synthetic_speaker",
        metadata={"help": "folder the generated clips are written to"})


@dataclass
class Data(Section):
    videos: str | list = field(default="data/synthetic_speaker",
        metadata={"help": "the training footage: a video file or a folder (a glob or a list also work outside DVC)"})
    val_fraction: float = field(default=0.2,
        metadata={"help": "share of the footage held out for validation", "min": 0.0})
    split_seed: int = field(default=0,
        metadata={"help": "seed of the hash that splits the videos"})
    split: str = field(default="video",
        metadata={"help": "video: whole videos by a seeded hash | time: the last val_fraction of each cut video's segments (`lipsynth cut`)"})
    on_bad_input: str = field(default="error",
        metadata={"help": "error: stop at the first bad video | skip: warn and leave it out"})

    CHOICES = {"on_bad_input": ("error", "skip"), "split": ("video", "time")}

    def validate(self) -> None:
        super().validate()
        if self.val_fraction >= 1:
            raise bad("val_fraction", self.val_fraction, "must be in [0, 1)")


@dataclass
class ClusterSecurity(Section):
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
class Cluster(Section):
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
class Ingest(Section):
    out: str = field(default="store/ingest.zarr",
        metadata={"help": "output store: face crops, 16 kHz audio, MFCC features"})
    crop_size: int | str = field(default="auto",
        metadata={"help": "stored square face crop side (px); auto: crop_scale × the face width found on a few key frames, ≥ 224"})
    max_crop_size: int = field(default=1024,
        metadata={"help": "largest crop side auto may choose (px): a face filmed larger is stored downsampled"})
    crop_scale: float = field(default=2.0,
        metadata={"help": "crop side / detected face-box width"})
    crop_shift_down: float = field(default=0.3,
        metadata={"help": "crop centre below the face-box centre, in face widths"})
    detect_samples: int = field(default=8,
        metadata={"help": "key frames searched for the face per video", "min": 1})
    detect_upsample: int = field(default=1,
        metadata={"help": "max dlib HOG upsampling when no face is found without", "min": 0, "max": 3})
    min_face_px: float = field(default=40,
        metadata={"help": "faces narrower than this (px) are rejected as too small"})
    min_seconds: float = field(default=0.5,
        metadata={"help": "videos shorter than this (s) are rejected as too short"})
    min_fps: float = field(default=10,
        metadata={"help": "lowest accepted video frame rate (frames/s)", "min": 1})
    max_fps: float = field(default=120,
        metadata={"help": "highest accepted video frame rate (frames/s)"})
    rms_target_dbfs: float = field(default=-23.0,
        metadata={"help": "RMS volume the audio is normalised to (dBFS; paper §3.1 step 1)"})
    shard_frames: int = field(default=256,
        metadata={"help": "frames per shard file (one dask task each); every video starts on a shard", "advanced": True, "min": 1})
    shard_seconds: int = field(default=10,
        metadata={"help": "audio / MFCC shard length (s)", "advanced": True, "min": 1})
    chunk_frames: int = field(default=8,
        metadata={"help": "frames per compressed chunk inside a shard", "advanced": True, "min": 1})

    AUTO = ("crop_size",)            # an int, or "auto": follow the face's size in the footage
    MIN_CROP = 224                   # px: the smallest crop auto chooses (the former fixed size)

    def validate(self) -> None:
        super().validate()
        if isinstance(self.crop_size, int) and (self.crop_size < 16 or self.crop_size % 4):
            raise bad("crop_size", self.crop_size, "must be a multiple of 4 (I420 storage), at least 16")
        if self.max_crop_size < self.MIN_CROP or self.max_crop_size % 16:
            raise bad("max_crop_size", self.max_crop_size, f"must be a multiple of 16, at least {self.MIN_CROP}")


@dataclass
class Landmarks(Section):
    out: str = field(default="store/landmarks.zarr",
        metadata={"help": "output store: 68 dlib landmarks per frame and their validity"})
    detect_every: int = field(default=50,
        metadata={"help": "re-run the HOG face detector at least every N frames while tracking"})
    detect_upsample: int = field(default=1,
        metadata={"help": "max HOG upsampling on the crop when no face is found without", "min": 0, "max": 3})
    jitter: float = field(default=0.05,
        metadata={"help": "box shift for the landmark confidence test, × box width", "advanced": True})
    min_confidence: float = field(default=0.5,
        metadata={"help": "frames below this confidence are flagged invalid (and tracking restarts)", "min": 0, "max": 1})
    margin: float = field(default=0.1,
        metadata={"help": "landmarks may lie this far outside the crop (× crop size)"})
    min_valid_fraction: float = field(default=0.5,
        metadata={"help": "a video with a smaller share of valid frames is an error (or skipped)", "min": 0, "max": 1})


@dataclass
class Frontalize(Section):
    out: str = field(default="store/frontalize.zarr",
        metadata={"help": "output store: 3D model, head pose, frontal textures"})
    focal_factor: float = field(default=1.5,
        metadata={"help": "assumed focal length / max(frame width, height)"})
    model_frames: int = field(default=300,
        metadata={"help": "training frames used to build the 3D face model", "min": 10})
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
    max_texture_size: int = field(default=512,
        metadata={"help": "largest texture side auto may choose (px): the texture follows the face up to this "
                          "(the weighted median runs at most at synthesize.median_max_size)", "min": 64})
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
        metadata={"help": "frames per compressed chunk inside a shard", "advanced": True, "min": 1})

    AUTO = ("texture_size",)         # an int, or "auto": as fine as the face in the stored crops


@dataclass
class Pca(Section):
    out: str = field(default="store/pca.zarr",
        metadata={"help": "output store: mouth PCA basis and coefficients per frame and at 100 Hz"})
    n_components: int = field(default=20,
        metadata={"help": "PCA coefficients kept of the 18 lip points (36-D)", "min": 1, "max": 36})


@dataclass
class Phonetic(Section):
    out: str = field(default="store/phonetic.zarr",
        metadata={"help": "output store: pocketsphinx phone indicators per 10 ms"})


@dataclass
class Whisper(Section):
    out: str = field(default="store/whisper.zarr",
        metadata={"help": "output store: Whisper tiny.en encoder states per 10 ms"})
    window_seconds: float = field(default=10.0,
        metadata={"help": "encoder window (s): audio is encoded in windows of this length"})
    overlap_seconds: float = field(default=2.0,
        metadata={"help": "overlap of consecutive encoder windows, cross-faded (s)", "min": 0.0})

    def validate(self) -> None:
        super().validate()
        if not 1.0 <= self.window_seconds <= 30.0:
            raise bad("window_seconds", self.window_seconds, "the encoder takes windows of 1–30 s")
        if self.overlap_seconds > self.window_seconds / 2:
            raise bad("overlap_seconds", self.overlap_seconds, "must be between 0 and half the window")
