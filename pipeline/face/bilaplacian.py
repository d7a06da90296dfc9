"""Smooth mesh deformation from a few moving points: a pre-factorised bi-Laplacian solve with soft handles.

For a triangle mesh with (uniform) graph Laplacian L, the per-vertex displacement D (N, 2) of a frame
minimises

    ‖L D‖² + w_h Σ_h ‖D[v_h] − d_h‖² + w_a Σ_a ‖D[v_a]‖²

— the smoothest (thin-plate-like, C¹ across the surface) field that carries each handle vertex v_h
by its driving point's displacement d_h and holds the anchors v_a still. The normal equations
(LᵀL + w_h C_hᵀC_h + w_a C_aᵀC_a) D = w_h C_hᵀ d have the same matrix in every frame, so it is
factorised once (sparse LU) and each frame costs one back-substitution. Because the energy is
measured along the mesh's own edges, vertices on the two sides of a cut (the mouth's inner-lip line,
where upper and lower handles nearly coincide) move independently: the lips part instead of tearing
(a radial-basis warp in the plane cannot tell the two sides apart).
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import splu


def graph_laplacian(n_vertices: int, triangles: np.ndarray) -> sp.csr_matrix:
    """(N, N) uniform Laplacian L = I − D⁻¹A of the mesh's edges (rows sum to 0; isolated vertices: 0 rows)."""
    t = np.asarray(triangles, np.int64)
    i = np.concatenate([t[:, 0], t[:, 1], t[:, 2], t[:, 1], t[:, 2], t[:, 0]])
    j = np.concatenate([t[:, 1], t[:, 2], t[:, 0], t[:, 0], t[:, 1], t[:, 2]])
    A = sp.coo_matrix((np.ones(len(i)), (i, j)), shape=(n_vertices, n_vertices)).tocsr()
    A.data[:] = 1.0                                       # an edge shared by two triangles counts once
    deg = np.asarray(A.sum(1)).ravel()
    inv = np.where(deg > 0, 1.0 / np.maximum(deg, 1), 0.0)
    return (sp.diags((deg > 0).astype(float)) - sp.diags(inv) @ A).tocsr()


class BiLaplacian:
    """Factorised deformation of one mesh: ``__call__(displacements)`` → per-vertex displacements.

    Parameters
    ----------
    n_vertices : int
        N, the mesh's vertex count.
    triangles : ndarray
        (F, 3) vertex indices.
    handles : ndarray
        (H,) vertex indices that follow the driving points (may repeat).
    anchors : ndarray
        (A,) vertex indices held still.
    handle_weight, anchor_weight : float
        Soft-constraint weights (dimensionless; ≫ 1 makes them nearly hard).
    """

    def __init__(self, n_vertices: int, triangles: np.ndarray, handles: np.ndarray, anchors: np.ndarray,
                 handle_weight: float = 100.0, anchor_weight: float = 100.0):
        L = graph_laplacian(n_vertices, triangles)
        self.handles = np.asarray(handles, np.int64)
        anchors = np.asarray(anchors, np.int64)
        Ch = sp.csr_matrix((np.ones(len(self.handles)), (np.arange(len(self.handles)), self.handles)),
                           shape=(len(self.handles), n_vertices))
        Ca = sp.csr_matrix((np.ones(len(anchors)), (np.arange(len(anchors)), anchors)), shape=(len(anchors), n_vertices))
        M = (L.T @ L + handle_weight * (Ch.T @ Ch) + anchor_weight * (Ca.T @ Ca)).tocsc()
        self._rhs = (handle_weight * Ch.T).tocsr()        # (N, H)
        self._lu = splu(M)
        self.n = n_vertices

    def __call__(self, displacements: np.ndarray) -> np.ndarray:
        """(T, H, k) handle displacements (mm) → (T, N, k) vertex displacements (mm)."""
        d = np.asarray(displacements, np.float64)
        T, H, k = d.shape
        rhs = self._rhs @ d.transpose(1, 0, 2).reshape(H, T * k)          # (N, T·k)
        return self._lu.solve(np.asarray(rhs)).reshape(self.n, T, k).transpose(1, 0, 2)
