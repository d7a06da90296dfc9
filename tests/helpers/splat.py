"""A reference renderer independent of the project's warps: a textured surface splatted through a pinhole camera."""
import numpy as np

from pipeline.face.geometry import project, rotation


def render(surface, photo, rvec, tvec, K, size=(320, 400), density=4):
    """Point-splat renderer with a z-buffer (far points drawn first, near ones overwrite)."""
    h, w = photo.shape[:2]
    v, u = np.mgrid[0:h * density, 0:w * density] / density
    x, y = u - 110.0, v - 80.0
    z = surface.z(x, y)
    pts = np.stack([x, y, z], -1).reshape(-1, 3)
    colours = photo[v.astype(int).ravel(), u.astype(int).ravel()]
    cam_z = (pts @ rotation(rvec).T + tvec)[:, 2]
    uv = np.round(project(pts, rvec, tvec, K)).astype(int)
    order = np.argsort(-cam_z)
    uv, colours = uv[order], colours[order]
    ok = (uv[:, 0] >= 0) & (uv[:, 0] < size[0]) & (uv[:, 1] >= 0) & (uv[:, 1] < size[1])
    img = np.zeros((size[1], size[0], 3), np.uint8)
    img[uv[ok, 1], uv[ok, 0]] = colours[ok]
    return img
