"""Chin / neck / background extension of the face depth map (paper 000 §3.2.1, Eq. 7–8).

Depth f is known on the face region Ω' of a grid over the canonical frontal plane. We find f*
on the whole grid Ω minimising the squared second derivatives ∂²f/∂x² and ∂²f/∂y² (Eq. 7)
subject to f* = f on Ω' and ∇f* = 0 on the boundary ∂Ω (Eq. 8), both as soft constraints,
discretised by finite differences into one sparse linear least-squares problem.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla
from scipy.interpolate import LinearNDInterpolator


def _second_difference(n: int) -> sp.csr_matrix:
    """(n-2, n) operator f[i-1] - 2 f[i] + f[i+1]."""
    return sp.diags([1.0, -2.0, 1.0], [0, 1, 2], shape=(n - 2, n), format="csr")


def extend_depth(depth: np.ndarray, known: np.ndarray, data_weight: float = 100.0,
                 boundary_weight: float = 100.0) -> np.ndarray:
    """Solve Eq. 7–8 on a grid.

    Parameters
    ----------
    depth : ndarray, shape (H, W)
        Depth (mm) where ``known``; ignored elsewhere.
    known : ndarray, shape (H, W), bool
        The face region Ω'.
    data_weight, boundary_weight : float
        Weights of the soft constraints f* = f on Ω' and ∇f* = 0 on ∂Ω relative to the
        smoothness term (grid units).

    Returns
    -------
    ndarray, shape (H, W), float64 — f* on the whole grid.
    """
    H, W = depth.shape
    n = H * W
    idx = np.arange(n).reshape(H, W)
    Ix, Iy = sp.identity(W, format="csr"), sp.identity(H, format="csr")
    Dxx = sp.kron(Iy, _second_difference(W))           # second derivative along x, each row
    Dyy = sp.kron(_second_difference(H), Ix)           # along y, each column
    # boundary: first difference across the border (normal derivative) on all four sides
    rows = []
    for a, b in [(idx[:, 0], idx[:, 1]), (idx[:, -1], idx[:, -2]), (idx[0, :], idx[1, :]), (idx[-1, :], idx[-2, :])]:
        m = len(a)
        rows.append(sp.csr_matrix((np.r_[np.ones(m), -np.ones(m)], (np.r_[np.arange(m), np.arange(m)], np.r_[a, b])),
                                  shape=(m, n)))
    G = sp.vstack(rows)
    k = known.ravel()
    S = sp.identity(n, format="csr")[np.flatnonzero(k)]
    A = sp.vstack([Dxx, Dyy, np.sqrt(boundary_weight) * G, np.sqrt(data_weight) * S]).tocsr()
    b = np.zeros(A.shape[0])
    b[-S.shape[0]:] = np.sqrt(data_weight) * depth.ravel()[k]
    f = spla.spsolve((A.T @ A).tocsc(), A.T @ b)
    return f.reshape(H, W)


def face_depth_on_grid(shape3d: np.ndarray, xs: np.ndarray, ys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Depth of the 68-point model linearly interpolated over its convex hull on a grid.

    Parameters
    ----------
    shape3d : (68, 3) canonical model (mm).
    xs : (W,) and ys : (H,) grid coordinates (mm).

    Returns
    -------
    depth (H, W) with NaN outside the hull, known (H, W) bool.
    """
    interp = LinearNDInterpolator(shape3d[:, :2], shape3d[:, 2])
    gx, gy = np.meshgrid(xs, ys)
    depth = interp(gx, gy)
    return depth, np.isfinite(depth)
