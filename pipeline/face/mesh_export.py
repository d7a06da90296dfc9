"""The animated head in files a 3D user can load: Wavefront OBJ + MTL + PNG texture for the rest mesh,
and a PC2 point cache (Blender's Mesh Cache modifier, 3ds Max, Houdini) with every frame's vertices.

    <stem>.obj   rest skin: v (mm), vt, f v/vt — vertex order = the cache's point order
    <stem>.mtl   one material whose diffuse map is <stem>.png
    <stem>.png   the head texture
    <stem>.pc2   'POINTCACHE2\\0', int32 version 1, int32 points, float32 start frame, float32 frame step,
                 int32 frames, then frames × points × 3 float32 (mm) — little endian

Coordinates are the canonical face's (mm, x right, y down, z away from the camera); the OBJ flips y and z
(y up, z towards the viewer, the convention of 3D tools) and the cache does the same.
"""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np

_FLIP = np.array([1.0, -1.0, -1.0])


def write_pc2(path, frames: np.ndarray, fps: float) -> None:
    """(T, N, 3) positions → a PC2 point cache (start frame 0, one sample per frame at ``fps``)."""
    frames = np.asarray(frames, np.float32)
    T, N, _ = frames.shape
    with open(path, "wb") as f:
        f.write(b"POINTCACHE2\0")
        f.write(np.array([1, N], "<i4").tobytes())
        f.write(np.array([0.0, 1.0], "<f4").tobytes())
        f.write(np.array([T], "<i4").tobytes())
        f.write(np.ascontiguousarray(frames, "<f4").tobytes())


def read_pc2(path) -> np.ndarray:
    """A PC2 point cache → (T, N, 3) float32."""
    raw = Path(path).read_bytes()
    if raw[:12] != b"POINTCACHE2\0":
        raise ValueError(f"{path}: not a PC2 point cache")
    _, n = np.frombuffer(raw, "<i4", 2, 12)
    t = int(np.frombuffer(raw, "<i4", 1, 28)[0])
    return np.frombuffer(raw, "<f4", t * n * 3, 32).reshape(t, n, 3)


def write_animated_mesh(stem, part, frames: np.ndarray, texture: np.ndarray, fps: float) -> list[Path]:
    """Write ``stem``.obj/.mtl/.png/.pc2 (each atomically); returns the paths.

    part : the rest skin (vertices (N, 3) mm, triangles (F, 3), uv (N, 2)); frames : (T, N, 3) mm.
    """
    import cv2

    stem = Path(stem)
    stem.parent.mkdir(parents=True, exist_ok=True)
    name = stem.name
    v = part.vertices * _FLIP
    lines = [f"# lipsynth dense head: {len(v)} vertices, {len(part.triangles)} triangles, mm", f"mtllib {name}.mtl",
             f"usemtl {name}"]
    lines += [f"v {a:.4f} {b:.4f} {c:.4f}" for a, b, c in v]
    lines += [f"vt {a:.6f} {b:.6f}" for a, b in part.uv]
    lines += [f"f {a}/{a} {b}/{b} {c}/{c}" for a, b, c in part.triangles[:, ::-1] + 1]   # flipped axes: reverse winding
    mtl = f"newmtl {name}\nKa 1 1 1\nKd 1 1 1\nKs 0 0 0\nmap_Kd {name}.png\n"
    out = []
    for suffix, write in ((".obj", lambda p: Path(p).write_text("\n".join(lines) + "\n")),
                          (".mtl", lambda p: Path(p).write_text(mtl)),
                          (".png", lambda p: cv2.imwrite(str(p), np.ascontiguousarray(texture[..., ::-1]))),
                          (".pc2", lambda p: write_pc2(p, np.asarray(frames) * _FLIP, fps))):
        final = stem.with_suffix(suffix)
        tmp = final.with_name(final.stem + ".tmp" + suffix)
        write(tmp)
        os.replace(tmp, final)
        out.append(final)
    return out
