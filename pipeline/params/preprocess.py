"""Sections of the data and preprocessing stages: synthetic_speaker, data, cluster, ingest,
landmarks, frontalize, pca, phonetic, whisper."""
from __future__ import annotations

from dataclasses import dataclass, field

from .section import Section, bad


@dataclass
class SyntheticSpeaker(Section):
    seed: int = 7
    n_videos: int = field(default=6, metadata={"min": 1})
    seconds_per_video: float = field(default=10.0, metadata={"min": 0.5})
    fps: int = field(default=25, metadata={"min": 1, "max": 240})
    width: int = field(default=360, metadata={"min": 32})
    height: int = field(default=288, metadata={"min": 32})
    sample_rate: int = field(default=16000, metadata={"min": 8000, "max": 192000})
    out_dir: str = "data/synthetic_speaker"


@dataclass
class Data(Section):
    videos: str | list = "data/synthetic_speaker"
    val_fraction: float = field(default=0.2, metadata={"min": 0.0})
    split_seed: int = 0
    split: str = "video"
    on_bad_input: str = "error"

    CHOICES = {"on_bad_input": ("error", "skip"), "split": ("video", "time")}

    def validate(self) -> None:
        super().validate()
        if self.val_fraction >= 1:
            raise bad("val_fraction", self.val_fraction, "must be in [0, 1)")


@dataclass
class ClusterSecurity(Section):
    """TLS for ``cluster.address = tls://…`` (``distributed.security.Security``): PEM files."""
    tls_ca_file: str | None = None
    tls_client_cert: str | None = None
    tls_client_key: str | None = None
    require_encryption: bool = False


@dataclass
class Cluster(Section):
    address: str | None = None
    n_workers: int | None = None
    memory_limit: str | int | float = "auto"
    connect_timeout: float = 30.0
    security: ClusterSecurity = field(default_factory=ClusterSecurity)


@dataclass
class Ingest(Section):
    out: str = "store/ingest.zarr"
    crop_size: int | str = "auto"
    max_crop_size: int = 1024
    crop_scale: float = 2.0
    crop_shift_down: float = 0.3
    detect_samples: int = field(default=8, metadata={"min": 1})
    detect_upsample: int = field(default=1, metadata={"min": 0, "max": 3})
    min_face_px: float = 40
    min_seconds: float = 0.5
    min_fps: float = field(default=10, metadata={"min": 1})
    max_fps: float = 120
    rms_target_dbfs: float = -23.0
    shard_frames: int = field(default=256, metadata={"min": 1})
    shard_seconds: int = field(default=10, metadata={"min": 1})
    chunk_frames: int = field(default=8, metadata={"min": 1})

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
    out: str = "store/landmarks.zarr"
    detect_every: int = 50
    detect_upsample: int = field(default=1, metadata={"min": 0, "max": 3})
    jitter: float = 0.05
    min_confidence: float = field(default=0.5, metadata={"min": 0, "max": 1})
    margin: float = 0.1
    min_valid_fraction: float = field(default=0.5, metadata={"min": 0, "max": 1})


@dataclass
class Frontalize(Section):
    out: str = "store/frontalize.zarr"
    focal_factor: float = 1.5
    model_frames: int = field(default=300, metadata={"min": 10})
    min_conditioning: float = 6.0
    ba_iterations: int = 100
    grid_mm: float = 2.0
    grid_x_mm: list = field(default_factory=lambda: [-110, 110])
    grid_y_mm: list = field(default_factory=lambda: [-80, 220])
    data_weight: float = 100.0
    boundary_weight: float = 100.0
    texture_size: int | str = "auto"
    max_texture_size: int = field(default=512, metadata={"min": 64})
    texture_x_mm: list = field(default_factory=lambda: [-80, 80])
    texture_y_mm: list = field(default_factory=lambda: [20, 180])
    max_reprojection: float = 0.15
    cloth_dark_value: int = 50
    cloth_white_saturation: int = 40
    cloth_white_value: int = 185
    cloth_dilate_px: int = 2
    inpaint_radius: float = 3.0
    chunk_frames: int = field(default=8, metadata={"min": 1})

    AUTO = ("texture_size",)         # an int, or "auto": as fine as the face in the stored crops


@dataclass
class Pca(Section):
    out: str = "store/pca.zarr"
    n_components: int = field(default=20, metadata={"min": 1, "max": 36})


@dataclass
class Phonetic(Section):
    out: str = "store/phonetic.zarr"


@dataclass
class Whisper(Section):
    out: str = "store/whisper.zarr"
    window_seconds: float = 10.0
    overlap_seconds: float = field(default=2.0, metadata={"min": 0.0})
    layers: list[int] = field(default_factory=lambda: [5])

    def validate(self) -> None:
        super().validate()
        if not self.layers or sorted(set(self.layers)) != list(self.layers) or not all(0 <= k <= 5 for k in self.layers):
            raise bad("layers", self.layers, "distinct encoder layers in increasing order, each 0 (the convolution "
                      "stem) … 4 (the blocks) or 5 (the final norm)")
        if not 1.0 <= self.window_seconds <= 30.0:
            raise bad("window_seconds", self.window_seconds, "the encoder takes windows of 1–30 s")
        if self.overlap_seconds > self.window_seconds / 2:
            raise bad("overlap_seconds", self.overlap_seconds, "must be between 0 and half the window")
