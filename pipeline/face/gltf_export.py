"""The animated head as glTF 2.0 binary (``.glb``), the format Blender, three.js, Unity, Unreal and
``<model-viewer>`` import, with its audio beside it (same stem, ``.wav``).

The file holds two nodes: ``head`` (one mesh, three primitives — the textured skin, upper teeth, lower
teeth — sharing K morph targets) and ``mouth_cavity`` (static). The motion is compressed into the morph
targets: the frames' displacements from the rest head, (T, 3M) for M moving vertices, are factorised by
an uncentred SVD, D ≈ W B; the K rows of B become morph targets (POSITION and NORMAL deltas) and the
animation ``speech`` drives the node's morph weights W (T, K) at the audio's frame rate (LINEAR). The
motion of a face driven by ~40 points is close to linear: K ≈ 24 reproduces every vertex of a Karras
clip within 0.1 mm (``tol_mm``; the figure is reported), K ≤ 64. Importers: three.js GLTFLoader +
AnimationMixer (morph targets in a texture, any count), Blender (shape keys driven by the action).

Coordinates: glTF metres, y up, +z towards the viewer; the canonical face (mm, y down, z away from the
camera) is centred on the face and turned 180° about x (a rotation: the winding still faces the viewer).
Texture coordinates: glTF's v runs down the image, as the head texture's rows do.
"""
from __future__ import annotations

import os
import wave
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pipeline.errors import LipsynthError

_AXES = np.array([1e-3, -1e-3, -1e-3])          # mm, y down, z away → m, y up, z towards the viewer
FLOAT, UINT16, UINT32 = 5126, 5123, 5125
ARRAY_BUFFER, ELEMENT_ARRAY_BUFFER = 34962, 34963


@dataclass
class MorphAnimation:
    """Frames as morph targets: positions ≈ rest + Σ_k weights[t, k] · deltas[k].

    deltas : (K, M, 3) position deltas (m); normals : (K, M, 3) normal deltas; weights : (T, K);
    max_error_mm : the largest vertex error of the reconstruction over all frames (mm).
    """

    deltas: np.ndarray
    normals: np.ndarray
    weights: np.ndarray
    max_error_mm: float


def vertex_normals(vertices: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Area-weighted unit vertex normals: vertices (N, 3) or (B, N, 3), triangles (F, 3) → the same shape."""
    v = np.asarray(vertices, np.float64)
    vb = v.reshape(-1, v.shape[-2], 3)
    B, N = vb.shape[:2]
    a, b, c = (vb[:, triangles[:, i]] for i in range(3))
    fn = np.cross(b - a, c - a).reshape(-1, 3)                        # (B·F, 3) area-weighted face normals
    n = np.zeros((B * N, 3))
    for i in range(3):
        idx = (np.arange(B)[:, None] * N + triangles[None, :, i]).ravel()
        for j in range(3):
            n[:, j] += np.bincount(idx, fn[:, j], minlength=B * N)
    n /= np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-12)
    return n.reshape(v.shape)


def morph_animation(rest: np.ndarray, frames: np.ndarray, triangles: np.ndarray, max_targets: int = 64,
                    tol_mm: float = 0.1, fit_frames: int = 300) -> MorphAnimation:
    """Compress vertex animation into morph targets.

    Parameters
    ----------
    rest : ndarray
        (M, 3) rest positions (m, glTF axes).
    frames : ndarray
        (T, M, 3) positions per frame (m).
    triangles : ndarray
        (F, 3) indices into the M vertices (for the normals).
    max_targets : int
        The most morph targets K.
    tol_mm : float
        The fewest K whose worst vertex error is below this (mm) is kept.
    fit_frames : int
        The basis is fitted on at most this many evenly spaced frames (all frames are projected).

    Returns
    -------
    MorphAnimation
        Deltas, normal deltas, weights (T, K) and the worst vertex error (mm).
    """
    T, M, _ = frames.shape
    d = (frames - rest[None]).reshape(T, 3 * M)
    sub = np.unique(np.linspace(0, T - 1, min(T, fit_frames)).round().astype(int))
    vt = _right_singular_vectors(d[sub], max_targets)
    w_all = d @ vt.T                                                   # (T, K_max) weights
    residual, err, k = d.copy(), 0.0, 0
    for k in range(1, len(vt) + 1):                                    # the fewest targets within tol_mm
        residual -= np.outer(w_all[:, k - 1], vt[k - 1])
        err = float(np.abs(residual).max()) * 1e3
        if err <= tol_mm:
            break
    w = w_all[:, :k]
    basis = vt[:k].reshape(k, M, 3)
    nrest = vertex_normals(rest, triangles)
    dn = (vertex_normals(frames[sub], triangles) - nrest[None]).reshape(len(sub), 3 * M)
    nb = np.linalg.lstsq(w[sub], dn, rcond=None)[0].reshape(k, M, 3)
    return MorphAnimation(basis.astype(np.float32), nb.astype(np.float32), w.astype(np.float32), float(err))


def unit_weights(rest: np.ndarray, anim: MorphAnimation) -> tuple[np.ndarray, MorphAnimation]:
    """The same motion with every weight in [0, 1] (Blender clamps shape-key values to their slider range,
    0–1 unless the first key says otherwise): w = lo + (hi − lo) w', so the base mesh takes rest + Σ lo·B and
    each target (hi − lo)·B.

    Parameters
    ----------
    rest : ndarray
        (M, 3) rest positions.
    anim : MorphAnimation
        From ``morph_animation``.

    Returns
    -------
    tuple of (ndarray, MorphAnimation)
        The base positions (M, 3) and the rescaled targets and weights (T, K) in [0, 1]; the mesh's default
        weights should be frame 0's, so that a file read without its animation shows the first frame.
    """
    lo, hi = anim.weights.min(0), anim.weights.max(0)
    span = np.maximum(hi - lo, 1e-12)
    base = rest + np.einsum("k,kmc->mc", lo, anim.deltas)
    w = np.clip((anim.weights - lo) / span, 0.0, 1.0)
    return base, MorphAnimation((anim.deltas * span[:, None, None]).astype(np.float32),
                                (anim.normals * span[:, None, None]).astype(np.float32), w.astype(np.float32),
                                anim.max_error_mm)


def _right_singular_vectors(a: np.ndarray, k: int) -> np.ndarray:
    """(≤ k, C) the leading right singular vectors of a (R, C), R ≪ C, through the R × R Gram matrix;
    directions with no motion (singular value below 1e-6 of the largest) are dropped (at least one is kept)."""
    evals, u = np.linalg.eigh(a @ a.T)
    order = np.argsort(evals)[::-1][:k]
    s = np.sqrt(np.maximum(evals[order], 0))
    keep = s > max(s[0], 1e-300) * 1e-6
    keep[:1] = True
    vt = (u[:, order[keep]].T @ a) / np.maximum(s[keep], 1e-300)[:, None]
    return vt / np.maximum(np.linalg.norm(vt, axis=1, keepdims=True), 1e-300)


class _Blob:
    """The GLB's binary chunk: 4-byte aligned buffer views and their accessors."""

    def __init__(self, gltf):
        self.gltf, self.data = gltf, bytearray()

    def view(self, raw: bytes, target: int | None = None) -> int:
        import pygltflib as g
        self.data += b"\0" * (-len(self.data) % 4)
        self.gltf.bufferViews.append(g.BufferView(buffer=0, byteOffset=len(self.data), byteLength=len(raw),
                                                  target=target))
        self.data += raw
        return len(self.gltf.bufferViews) - 1

    def accessor(self, array: np.ndarray, kind: str, target: int | None = None, bounds: bool = False) -> int:
        import pygltflib as g
        ctype = {np.dtype(np.float32): FLOAT, np.dtype(np.uint16): UINT16, np.dtype(np.uint32): UINT32}[array.dtype]
        flat = array.reshape(len(array), -1)
        acc = g.Accessor(bufferView=self.view(np.ascontiguousarray(array).tobytes(), target), componentType=ctype,
                         count=len(array), type=kind)
        if bounds:
            acc.min, acc.max = flat.min(0).tolist(), flat.max(0).tolist()
        self.gltf.accessors.append(acc)
        return len(self.gltf.accessors) - 1


def _linear(rgb) -> list[float]:
    return [float(c) ** 2.2 for c in rgb] + [1.0]


def _primitive(blob: _Blob, vertices, triangles, uv, material: int, targets=None) -> "object":
    import pygltflib as g
    v = np.asarray(vertices, np.float32)
    attrs = g.Attributes(POSITION=blob.accessor(v, "VEC3", ARRAY_BUFFER, bounds=True),
                         NORMAL=blob.accessor(vertex_normals(v, triangles).astype(np.float32), "VEC3", ARRAY_BUFFER))
    if uv is not None:
        uv = np.column_stack([uv[:, 0], 1.0 - uv[:, 1]]).astype(np.float32)    # glTF: v down the image
        attrs.TEXCOORD_0 = blob.accessor(uv, "VEC2", ARRAY_BUFFER)
    idx = np.asarray(triangles, np.uint16 if len(v) < 65536 else np.uint32).reshape(-1)
    prim = g.Primitive(attributes=attrs, indices=blob.accessor(idx, "SCALAR", ELEMENT_ARRAY_BUFFER), material=material)
    if targets is not None:
        prim.targets = [{"POSITION": blob.accessor(p, "VEC3", ARRAY_BUFFER, bounds=True),
                         "NORMAL": blob.accessor(n, "VEC3", ARRAY_BUFFER)} for p, n in zip(*targets)]
    return prim


def build_glb(mesh, motion, texture: np.ndarray, fps: float, audio_name: str | None = None,
              tol_mm: float = 0.1) -> tuple[bytes, dict]:
    """The animated head as GLB bytes, and figures (morph targets, worst vertex error mm, bytes).

    Parameters
    ----------
    mesh : HeadMesh
        The head at rest (mm).
    motion : HeadMotion
        skin (T, N, 3), upper_teeth (T, Nu, 3), lower_teeth (T, Nl, 3), mm.
    texture : ndarray
        (H, W, 3) uint8 RGB head texture.
    fps : float
        Frames per second of the animation.
    audio_name : str, optional
        The audio file beside it (recorded in the scene's extras).
    tol_mm : float
        The worst vertex error (mm) the morph targets may leave (``morph_animation``).

    Returns
    -------
    raw : bytes
        The ``.glb`` file.
    figures : dict
        ``morph_targets``, ``max_error_mm``, ``frames``, ``bytes``.
    """
    import cv2
    import pygltflib as g
    from pipeline.face.head_mesh import CAVITY_RGB, TEETH_RGB

    parts = [mesh.skin, mesh.upper_teeth, mesh.lower_teeth]
    moving = [motion.skin, motion.upper_teeth, motion.lower_teeth]
    v = mesh.skin.vertices
    centre = np.array([v[:, 0].mean(), v[:, 1].mean(), np.median(v[:, 2])])
    to_gl = lambda x: ((np.asarray(x, np.float64) - centre) * _AXES)
    sizes = np.cumsum([0] + [len(p.vertices) for p in parts])
    rest = np.concatenate([to_gl(p.vertices) for p in parts])
    frames = np.concatenate([to_gl(m) for m in moving], axis=1)
    tris = np.concatenate([p.triangles + o for p, o in zip(parts, sizes[:-1])])
    anim = morph_animation(rest, frames, tris, tol_mm=tol_mm)
    base, anim = unit_weights(rest, anim)

    gltf = g.GLTF2(asset=g.Asset(version="2.0", generator="lipsynth render-mesh (pygltflib)"), scene=0)
    blob = _Blob(gltf)
    ok, png = cv2.imencode(".png", np.ascontiguousarray(texture[..., ::-1]))
    gltf.images = [g.Image(bufferView=blob.view(png.tobytes()), mimeType="image/png")]
    gltf.samplers = [g.Sampler(magFilter=9729, minFilter=9987, wrapS=33071, wrapT=33071)]
    gltf.textures = [g.Texture(sampler=0, source=0)]
    pbr = dict(metallicFactor=0.0, roughnessFactor=0.75)
    gltf.materials = [
        g.Material(name="skin", doubleSided=True,
                   pbrMetallicRoughness=g.PbrMetallicRoughness(baseColorTexture=g.TextureInfo(index=0), **pbr)),
        g.Material(name="teeth", doubleSided=True,
                   pbrMetallicRoughness=g.PbrMetallicRoughness(baseColorFactor=_linear(TEETH_RGB), **pbr)),
        g.Material(name="mouth_cavity", doubleSided=True,
                   pbrMetallicRoughness=g.PbrMetallicRoughness(baseColorFactor=_linear(CAVITY_RGB), **pbr))]
    prims = []
    for i, p in enumerate(parts):
        sl = slice(sizes[i], sizes[i + 1])
        prims.append(_primitive(blob, base[sl], p.triangles, p.uv, 0 if i == 0 else 1,
                                (anim.deltas[:, sl], anim.normals[:, sl])))
    k = anim.weights.shape[1]
    gltf.meshes = [g.Mesh(name="head", primitives=prims, weights=[float(x) for x in anim.weights[0]],
                          extras={"targetNames": [f"speech_{i:02d}" for i in range(k)]}),
                   g.Mesh(name="mouth_cavity", primitives=[_primitive(blob, to_gl(mesh.cavity.vertices),
                                                                      mesh.cavity.triangles, None, 2)])]
    T = len(anim.weights)
    _animate(gltf, blob, anim.weights, motion, to_gl, fps)
    gltf.scenes = [g.Scene(name="lipsynth head", nodes=[0],
                           extras={"fps": float(fps), "frames": T, "audio": audio_name})]
    blob.data += b"\0" * (-len(blob.data) % 4)
    gltf.buffers = [g.Buffer(byteLength=len(blob.data))]
    gltf.set_binary_blob(bytes(blob.data))
    raw = b"".join(gltf.save_to_bytes())
    return raw, dict(morph_targets=k, max_error_mm=round(anim.max_error_mm, 4), frames=T, bytes=len(raw))


def _animate(gltf, blob: _Blob, weights: np.ndarray, motion, to_gl, fps: float) -> None:
    """Nodes ``lipsynth_head`` (turns about the neck pivot) → ``head`` (morphing), ``mouth_cavity``; the animation
    ``speech``: the morph weights (T, K) and, when the head turns (``motion.rotation``), the root's rotation."""
    import pygltflib as g
    from scipy.spatial.transform import Rotation
    T = len(weights)
    piv = to_gl(motion.pivot) if motion.rotation is not None else np.zeros(3)
    child = [float(c) for c in -piv]
    gltf.nodes = [g.Node(name="lipsynth_head", children=[1, 2], translation=[float(c) for c in piv]),
                  g.Node(name="head", mesh=0, translation=child),
                  g.Node(name="mouth_cavity", mesh=1, translation=child)]
    times = blob.accessor((np.arange(T) / fps).astype(np.float32), "SCALAR", bounds=True)
    out = blob.accessor(weights.reshape(-1, 1).astype(np.float32), "SCALAR", bounds=True)     # in [0, 1]
    samplers = [g.AnimationSampler(input=times, output=out, interpolation="LINEAR")]
    channels = [g.AnimationChannel(sampler=0, target=g.AnimationChannelTarget(node=1, path="weights"))]
    if motion.rotation is not None:
        flip = np.diag([1.0, -1.0, -1.0])                              # canonical axes → glTF axes (a rotation)
        q = Rotation.from_matrix(flip @ motion.rotation @ flip).as_quat()          # (T, 4) x, y, z, w
        q[np.cumsum(np.r_[0, (np.sum(q[1:] * q[:-1], 1) < 0)]) % 2 == 1] *= -1     # one hemisphere: no long way round
        samplers.append(g.AnimationSampler(input=times, output=blob.accessor(q.astype(np.float32), "VEC4"),
                                           interpolation="LINEAR"))
        channels.append(g.AnimationChannel(sampler=1, target=g.AnimationChannelTarget(node=0, path="rotation")))
    gltf.animations = [g.Animation(name="speech", samplers=samplers, channels=channels)]


def write_wav(path, samples: np.ndarray, sample_rate: int = 16000) -> None:
    """Mono float samples in [-1, 1] → 16-bit PCM WAV."""
    pcm = (np.clip(np.asarray(samples, np.float64), -1, 1) * 32767).round().astype("<i2")
    with wave.open(str(path), "wb") as w:
        w.setnchannels(1)
        w.setsampwidth(2)
        w.setframerate(sample_rate)
        w.writeframes(pcm.tobytes())


def check_writable(glb) -> Path:
    """The ``.glb`` path, or a LipsynthError in one line when it cannot be written (checked before any work:
    its folder is created and a probe file written and removed there)."""
    import tempfile
    path = Path(glb)
    if path.suffix.lower() != ".glb":
        raise LipsynthError(f"{glb}: a glTF binary path must end in .glb")
    if path.is_dir():
        raise LipsynthError(f"{glb}: cannot write the glTF file there (a folder of that name exists)")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile(dir=path.parent, prefix=f".{path.stem}.probe"):
            pass
    except OSError as e:
        raise LipsynthError(f"{glb}: cannot write the glTF file there ({e.strerror or e})") from None
    return path


def write_glb(glb, mesh, motion, texture: np.ndarray, fps: float, samples: np.ndarray | None = None,
              sample_rate: int = 16000) -> dict:
    """Write ``glb`` and, with ``samples``, its audio (same stem, ``.wav``), each via a temporary file
    renamed into place: an error leaves neither half-written. Returns ``build_glb``'s figures + paths."""
    path = check_writable(glb)
    wav = path.with_suffix(".wav") if samples is not None else None
    raw, figures = build_glb(mesh, motion, texture, fps, wav.name if wav else None)
    written = []
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        for final, write in ((wav, lambda p: write_wav(p, samples, sample_rate)), (path, lambda p: p.write_bytes(raw))):
            if final is None:
                continue
            tmp = final.with_name(f".{final.stem}.tmp{os.getpid()}{final.suffix}")
            try:
                write(tmp)
                os.replace(tmp, final)
            finally:
                tmp.unlink(missing_ok=True)
            written.append(final)
    except OSError as e:
        for p in written:
            p.unlink(missing_ok=True)
        raise LipsynthError(f"{glb}: cannot write the glTF file ({e.strerror or e})") from None
    return dict(figures, glb=str(path), audio=str(wav) if wav else None)
