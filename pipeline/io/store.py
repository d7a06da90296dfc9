"""The zarr v3 store every stage reads and writes.

Each stage owns one zarr group (``store/<stage>.zarr``). Per-frame arrays share one global
frame axis: the videos of the corpus are concatenated in index order, and the per-video index
(``attrs["videos"]``) says where each video starts. Arrays are sharded along time so that DVC
hashes few files and so that one dask task writes whole shards (no two tasks touch a shard).

Stores record no machine-specific value: paths are relative to the project root
(``project_path``) and timings stay out of them, so the same inputs give the same bytes and DVC
hashes wherever the project is checked out.

A stage writes into ``.<out>.tmp-<pid>`` and renames it onto ``<out>`` when everything
succeeded (``atomic_output``), so a failed run never leaves a half-written store. A run that is
killed (SIGKILL, power loss) cannot clean up after itself: the next run of the stage sweeps the
temporary folders whose process is gone (``sweep_stale_temps``).
"""
from __future__ import annotations

import contextlib
import logging
import os
import re
import shutil
from pathlib import Path

import numpy as np
import zarr
from zarr.codecs import BloscCodec, BloscShuffle

COMPRESSOR = BloscCodec(cname="zstd", clevel=5, shuffle=BloscShuffle.bitshuffle)     # numbers
IMAGE_COMPRESSOR = BloscCodec(cname="zstd", clevel=3, shuffle=BloscShuffle.noshuffle)  # uint8 pixels

log = logging.getLogger("lipsynth.store")


def pid_alive(pid: int) -> bool:
    """Is ``pid`` a running process on this machine? (A process of another user counts as alive.)"""
    if pid <= 0:
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def sweep_stale_temps(out: str | os.PathLike) -> list[Path]:
    """Remove the leftovers of killed writers of ``out``: ``.<name>.tmp-<pid>[.ext]`` (a store or file
    being written) and ``.<name>.old-<pid>[.ext]`` (the previous one being replaced) beside it whose pid
    is not a live process. Logs one line per folder removed and returns them.

    Folders of live processes (another run writing the same output right now), of this process,
    and every other name are left alone. The pid is checked on this machine: two hosts writing
    the same output over a shared filesystem at the same time is not supported anyway (the
    stage driver — the process that runs ``dvc repro`` — is one process on one host).
    """
    out = Path(out).absolute()
    if not out.parent.is_dir():
        return []
    pattern = re.compile(rf"^\.{re.escape(out.name)}\.(tmp|old)-(\d+)(\.\w+)?$")
    swept = []
    for path in sorted(out.parent.iterdir()):
        m = pattern.match(path.name)
        if not m or int(m.group(2)) == os.getpid() or pid_alive(int(m.group(2))):
            continue
        if path.is_dir() and not path.is_symlink():
            shutil.rmtree(path, ignore_errors=True)
        else:
            path.unlink(missing_ok=True)
        log.info("removed %s: left behind by process %s, which is no longer running", path, m.group(2))
        swept.append(path)
    return swept


@contextlib.contextmanager
def atomic_output(out: str | os.PathLike, suffix: str = ""):
    """Yield a temporary path next to ``out``; on success replace ``out`` with it.

    The temporary path is ``.<name>.tmp-<pid><suffix>`` — a folder or a file, whichever the caller
    writes (``suffix`` keeps a file's extension, e.g. ``.mp4`` for a writer that picks the format from
    it). On any exception it is removed and ``out`` is left as it was. Stale temporaries of killed
    earlier runs are swept first (``sweep_stale_temps``).
    """
    out = Path(out).absolute()
    out.parent.mkdir(parents=True, exist_ok=True)
    sweep_stale_temps(out)
    tmp = out.with_name(f".{out.name}.tmp-{os.getpid()}{suffix}")
    _remove(tmp)
    try:
        yield tmp
    except BaseException:
        _remove(tmp)
        raise
    if out.exists():
        old = out.with_name(f".{out.name}.old-{os.getpid()}{suffix}")
        os.replace(out, old)
        os.replace(tmp, out)
        _remove(old)
    else:
        os.replace(tmp, out)


def _remove(path: Path) -> None:
    """Remove a folder tree or a file, if present."""
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path, ignore_errors=True)
    else:
        path.unlink(missing_ok=True)


def project_path(path: str | os.PathLike) -> str:
    """``path`` as stores record it: relative to the project root (the working directory stages
    run in), with forward slashes, so that a store's bytes do not depend on where the project
    folder is. Files outside the project keep a relative path too (``../shared/...``)."""
    return Path(os.path.relpath(Path(path).absolute(), Path.cwd())).as_posix()


def create_group(path, attrs: dict | None = None) -> zarr.Group:
    g = zarr.open_group(str(path), mode="w", zarr_format=3)
    if attrs:
        g.attrs.update(attrs)
    return g


def open_group(path, mode: str = "r") -> zarr.Group:
    if not Path(path).exists():
        from pipeline.errors import LipsynthError
        raise LipsynthError(f"{path}: store not found — run the stage that produces it first (dvc repro)")
    return zarr.open_group(str(path), mode=mode, zarr_format=3)


def create_timed(group: zarr.Group, name: str, length: int, item_shape: tuple, dtype,
                 shard_len: int, chunk_len: int, fill_value=0) -> zarr.Array:
    """Create an array with time as axis 0, chunked by ``chunk_len`` and sharded by ``shard_len``."""
    if shard_len % chunk_len:
        raise ValueError(f"shard_len {shard_len} must be a multiple of chunk_len {chunk_len}")
    shape = (max(length, 0),) + tuple(item_shape)
    return group.create_array(
        name, shape=shape, dtype=dtype,
        chunks=(chunk_len,) + tuple(item_shape),
        shards=(shard_len,) + tuple(item_shape),
        compressors=IMAGE_COMPRESSOR if np.dtype(dtype) == np.uint8 else COMPRESSOR, fill_value=fill_value)


def shard_ranges(length: int, shard_len: int) -> list[tuple[int, int]]:
    """Split ``[0, length)`` into shard-aligned ``(start, stop)`` ranges — one task each."""
    return [(s, min(s + shard_len, length)) for s in range(0, length, shard_len)]


def videos_in(videos: list[dict], start: int, stop: int):
    """The videos with frames in ``[start, stop)``."""
    return (v for v in videos if v["n_frames"] and v["first_frame"] < stop and v["first_frame"] + v["n_frames"] > start)


def occupied_shards(videos: list[dict], length: int, shard_len: int) -> list[tuple[int, int]]:
    """The shard ranges of a frame axis that hold frames of at least one video."""
    return [(a, b) for a, b in shard_ranges(length, shard_len) if any(True for _ in videos_in(videos, a, b))]


def stored_bytes(path) -> int:
    """Bytes on disk under ``path`` (a zarr array or group directory)."""
    return sum(f.stat().st_size for f in Path(path).rglob("*") if f.is_file())


def video_of_frames(videos: list[dict], start: int, stop: int):
    """Yield ``(video, lo, hi)``: the part ``[lo, hi)`` of global frames ``[start, stop)`` in each video."""
    for v in videos:
        if not v["n_frames"]:
            continue
        lo = max(start, v["first_frame"])
        hi = min(stop, v["first_frame"] + v["n_frames"])
        if lo < hi:
            yield v, lo, hi


def rgb_to_i420(rgb: np.ndarray) -> np.ndarray:
    """(S, S, 3) RGB uint8 → (3S/2, S) I420 (YUV 4:2:0): the store's image format, 1.5 B/pixel."""
    import cv2
    return cv2.cvtColor(np.ascontiguousarray(rgb), cv2.COLOR_RGB2YUV_I420)


def i420_to_rgb(i420: np.ndarray) -> np.ndarray:
    """(3S/2, S) I420 → (S, S, 3) RGB uint8. The first S rows alone are the grey (luma) image."""
    import cv2
    return cv2.cvtColor(np.ascontiguousarray(i420), cv2.COLOR_YUV2RGB_I420)


def resize_i420(i420: np.ndarray, size: int) -> np.ndarray:
    """(3S/2, S) I420 → (3·size/2, size) I420 uint8, each plane resized by area averaging (size a multiple of 4)."""
    import cv2
    s = i420.shape[1]
    if size % 4 or size < 4:
        raise ValueError(f"resize_i420: size {size} must be a positive multiple of 4")
    if size == s:
        return np.array(i420, copy=True)
    h, q = s // 2, size // 2
    y = cv2.resize(np.ascontiguousarray(i420[:s]), (size, size), interpolation=cv2.INTER_AREA)
    uv = [cv2.resize(np.ascontiguousarray(i420[s + k * h // 2: s + (k + 1) * h // 2]).reshape(h, h), (q, q),
                     interpolation=cv2.INTER_AREA).reshape(q // 2, size) for k in range(2)]
    return np.concatenate([y, *uv])


def take(array, rows: np.ndarray) -> np.ndarray:
    """``array[rows]`` for any row indices, read as runs of consecutive rows (one slice per run).

    zarr's orthogonal selection decodes a chunk once per selected row; pools of candidate
    frames are long runs of consecutive frames, so slices are much cheaper.
    """
    rows = np.asarray(rows, np.int64)
    if not len(rows):
        return np.zeros((0, *array.shape[1:]), array.dtype)
    breaks = np.flatnonzero(np.diff(rows) != 1) + 1
    parts = []
    for run in np.split(rows, breaks):
        parts.append(np.asarray(array[int(run[0]):int(run[-1]) + 1]))
    return np.concatenate(parts)
