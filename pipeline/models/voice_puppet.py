"""Voice Puppetry at inference (Brand 1999, paper 002 §4.4–§4.5): new audio → the vocal HMM's
most likely facial state sequence (Viterbi) → the facial trajectory that maximises the likelihood
of positions *and* velocities under those states (Eq. 5–6, solved in closed form).

A *puppet* is a dict of arrays (the ``models/brand`` folder, written by ``stages/train_brand``):

    startprob (K,), transmat (K, K)          the facial HMM's state machine (shared by the vocal HMM)
    face_means (K, 2D), face_covars (K, 2D, 2D)
                                             per state: face position (D PCA coordinates of the
                                             face points, canonical texture px) and velocity (px/s)
    vocal_means (K, A), vocal_covars (K, A, A), vocal_mean (A,), vocal_std (A,)
                                             per state: the voice features (normalised by mean/std)
    face_pca_mean (2P,), face_pca_components (D, 2P), lip_index (18,)
                                             PCA coordinates ↔ the P face points; which are the lips
    pca_mean (36,), pca_components (k, 36)   the store's mouth PCA basis (the shared predict output)
    config: rate (Hz), features (pipeline.audio.vocal_features kind), decode ("viterbi" | "posterior")

The trajectory is solved at any frame rate: velocities are per second, so the velocity term of
Eq. 5 is h·(y_t − y_{t−1}) at h output frames/s ("by scaling the velocity terms", §4.5).
"""
from __future__ import annotations

import numpy as np
import scipy.linalg
from scipy.special import logsumexp

from pipeline.audio import vocal_features
from pipeline.errors import BadInputError, ParameterError
from pipeline.models.mouth_pca import project, reconstruct

DECODE = ("viterbi", "posterior")
SILENCE_DBFS = -70.0


def gaussian_loglik(x: np.ndarray, means: np.ndarray, covars: np.ndarray) -> np.ndarray:
    """log N(x_t; μ_k, K_k) for (T, D) x, (K, D) means, (K, D, D) covars → (T, K)."""
    out = np.empty((len(x), len(means)))
    for k, (m, c) in enumerate(zip(means, covars)):
        chol = np.linalg.cholesky(c)
        z = scipy.linalg.solve_triangular(chol, (x - m).T, lower=True)
        out[:, k] = -0.5 * (z * z).sum(0) - np.log(np.diag(chol)).sum() - 0.5 * len(m) * np.log(2 * np.pi)
    return out


def _log(p):
    with np.errstate(divide="ignore"):
        return np.log(p)


def viterbi(loglik: np.ndarray, startprob: np.ndarray, transmat: np.ndarray) -> tuple[np.ndarray, float]:
    """Most likely state sequence (T,) and its log probability, for (T, K) emission log-likelihoods."""
    ls, lt = _log(startprob), _log(transmat)
    delta = ls + loglik[0]
    back = np.zeros(loglik.shape, int)
    for t in range(1, len(loglik)):
        scores = delta[:, None] + lt
        back[t] = scores.argmax(0)
        delta = scores[back[t], np.arange(len(delta))] + loglik[t]
    path = np.empty(len(loglik), int)
    path[-1] = int(delta.argmax())
    for t in range(len(loglik) - 1, 0, -1):
        path[t - 1] = back[t, path[t]]
    return path, float(delta.max())


def forward_backward(loglik: np.ndarray, startprob: np.ndarray, transmat: np.ndarray):
    """Log-space forward–backward → (log α (T, K), log β (T, K), log P(X))."""
    ls, lt = _log(startprob), _log(transmat)
    T, K = loglik.shape
    la, lb = np.empty((T, K)), np.zeros((T, K))
    la[0] = ls + loglik[0]
    for t in range(1, T):
        la[t] = logsumexp(la[t - 1][:, None] + lt, axis=0) + loglik[t]
    for t in range(T - 2, -1, -1):
        lb[t] = logsumexp(lt + (loglik[t + 1] + lb[t + 1])[None, :], axis=1)
    return la, lb, float(logsumexp(la[-1]))


def posteriors(loglik, startprob, transmat) -> np.ndarray:
    """State occupancies γ (T, K) given the whole sequence."""
    la, lb, lp = forward_backward(loglik, startprob, transmat)
    return np.exp(la + lb - lp)


def sequence_entropy_rate(loglik, startprob, transmat) -> float:
    """H(S | X) / T in nats per frame: the entropy of the posterior over whole state sequences.

    The posterior is a Markov chain, so H(S|X) = H(s_1|X) + Σ_t E[H(s_t | s_{t−1}, X)], with
    P(s_t = j | s_{t−1} = i, X) = ξ_t(i, j) / γ_{t−1}(i). Low values mean the Viterbi sequence
    dominates (paper §5: 0.0315 entropic vs 0.875 conventional).
    """
    la, lb, lp = forward_backward(loglik, startprob, transmat)
    lt = _log(transmat)
    lg = la + lb - lp
    g0 = np.exp(lg[0])
    h = -float(np.sum(g0[g0 > 0] * lg[0][g0 > 0]))
    for t in range(1, len(loglik)):
        lxi = la[t - 1][:, None] + lt + (loglik[t] + lb[t])[None, :] - lp        # log ξ_t(i, j)
        xi = np.exp(lxi)
        ok = xi > 0
        h -= float(np.sum(xi[ok] * (lxi[ok] - np.broadcast_to(lg[t - 1][:, None], lxi.shape)[ok])))  # log P(j|i,X)
    return h / len(loglik)


def transition_perplexity(transmat: np.ndarray) -> float:
    """exp of the state machine's entropy rate Σ_i π_i H(θ_·|i) (π stationary), transitions per step."""
    w, v = np.linalg.eig(transmat.T)
    pi = np.abs(np.real(v[:, np.argmin(np.abs(w - 1))]))
    pi /= pi.sum()
    with np.errstate(divide="ignore", invalid="ignore"):
        rows = -np.nansum(np.where(transmat > 0, transmat * np.log(transmat), 0.0), axis=1)
    return float(np.exp(pi @ rows))


def split_covariances(face_means: np.ndarray, face_covars: np.ndarray) -> dict:
    """Per state the precision of (position, velocity), its precision-weighted mean, and the
    position-marginal precision (for the first frame, which has no velocity)."""
    d = face_means.shape[1] // 2
    prec = np.linalg.inv(face_covars)
    pos_prec = np.linalg.inv(face_covars[:, :d, :d])
    return dict(prec=prec, prec_mean=np.einsum("kij,kj->ki", prec, face_means),
                pos_prec=pos_prec, pos_prec_mean=np.einsum("kij,kj->ki", pos_prec, face_means[:, :d]), d=d)


def solve_trajectory(weights: np.ndarray, gauss: dict, fps: float) -> np.ndarray:
    """The face trajectory Y* of Eq. 5 for per-frame state weights (T, K) → (T, D).

    Minimises Σ_t Σ_k w_tk (r_t − m_k)ᵀ K_k⁻¹ (r_t − m_k) with r_t = [y_t, fps·(y_t − y_{t−1})]
    (the first frame: its position term only). One-hot weights (a Viterbi sequence) give the
    paper's Eq. 5 exactly; posterior weights give the expected cost under all sequences. The
    normal equations (Eq. 6) are block-tridiagonal with D × D blocks: solved as a banded
    symmetric system (``scipy.linalg.solveh_banded``) in O(T·D³).
    """
    T, d = len(weights), gauss["d"]
    A = np.einsum("tk,kij->tij", weights, gauss["prec"])              # (T, 2D, 2D)
    b = weights @ gauss["prec_mean"]                                   # (T, 2D)
    eye = np.eye(d)
    L = np.block([[np.zeros((d, d)), eye], [-fps * eye, fps * eye]])   # r_t = L [y_{t−1}; y_t]
    G = np.einsum("ji,tjk,kl->til", L, A, L)
    g = b @ L                                                          # Lᵀ b_t
    diag = np.zeros((T, d, d))
    off = np.zeros((max(T - 1, 0), d, d))                              # block (t, t+1)
    rhs = np.zeros((T, d))
    diag[0] += np.einsum("tk,kij->ij", weights[:1], gauss["pos_prec"])
    rhs[0] += weights[0] @ gauss["pos_prec_mean"]
    diag[:-1] += G[1:, :d, :d]
    diag[1:] += G[1:, d:, d:]
    off[:] = G[1:, :d, d:]
    rhs[:-1] += g[1:, :d]
    rhs[1:] += g[1:, d:]
    u = 2 * d - 1
    ab = np.zeros((u + 1, T * d))
    base = np.arange(T) * d
    for a in range(d):
        for c in range(d):
            if a <= c:                                                 # diagonal blocks, upper triangle
                ab[u + a - c, base + c] = diag[:, a, c]
            if T > 1:                                                  # block (t, t+1): row t·d+a, column (t+1)·d+c
                ab[u - (d + c - a), base[1:] + c] = off[:, a, c]
    return scipy.linalg.solveh_banded(ab, rhs.ravel()).reshape(T, d)


def check_puppet(puppet: dict, source="model") -> None:
    if puppet["config"].get("decode", "viterbi") not in DECODE:
        raise ParameterError(f"{source}: decode={puppet['config']['decode']!r}: choose one of {', '.join(DECODE)}")


def decode_voice(samples: np.ndarray, puppet: dict, source="audio") -> tuple[np.ndarray, np.ndarray]:
    """Normalised voice features (n, A) at the model rate and their state log-likelihoods (n, K)."""
    cfg = puppet["config"]
    rms = float(np.sqrt(np.mean(np.square(samples, dtype=np.float64)))) if len(samples) else 0.0
    if rms <= 10 ** (SILENCE_DBFS / 20):
        raise BadInputError(source, f"the audio is silent (RMS below {SILENCE_DBFS:.0f} dBFS): nothing to lip-sync")
    n = int(np.floor(len(samples) / 16000 * cfg["rate"] + 0.5))
    a = project_voice(vocal_features.vocal_features(samples, cfg["features"], cfg["rate"], n, source,
                                                                cfg.get("encoder")), puppet)
    a = (a - puppet["vocal_mean"]) / puppet["vocal_std"]
    return a, gaussian_loglik(a, puppet["vocal_means"], puppet["vocal_covars"])


def project_voice(a: np.ndarray, puppet: dict) -> np.ndarray:
    """(n, F) voice features → (n, A) on the model's voice PCA when it has one (wide encoder states), else as is."""
    if "vocal_projection" not in puppet:
        return a
    return (a - puppet["vocal_projection_mean"]) @ puppet["vocal_projection"].T


def state_weights(loglik: np.ndarray, puppet: dict, how: str) -> np.ndarray:
    """(n, K) one-hot Viterbi states or forward–backward occupancies."""
    if how == "viterbi":
        path, _ = viterbi(loglik, puppet["startprob"], puppet["transmat"])
        return np.eye(loglik.shape[1])[path]
    return posteriors(loglik, puppet["startprob"], puppet["transmat"])


def face_points(y: np.ndarray, puppet: dict) -> np.ndarray:
    """(T, D) PCA coordinates → (T, P, 2) face points, canonical texture px."""
    return (y @ puppet["face_pca_components"] + puppet["face_pca_mean"]).reshape(len(y), -1, 2)


def trajectory_at(weights: np.ndarray, puppet: dict, fps: float, n_out: int) -> np.ndarray:
    """Solve Eq. 5 at ``fps`` for model-rate state weights: output frame j takes the weights of the
    model frame nearest j / fps. Returns (n_out, D)."""
    rate = puppet["config"]["rate"]
    idx = np.clip(np.floor(np.arange(n_out) / fps * rate + 0.5).astype(int), 0, len(weights) - 1)
    if "gauss" not in puppet:
        puppet["gauss"] = split_covariances(puppet["face_means"], puppet["face_covars"])
    return solve_trajectory(weights[idx], puppet["gauss"], fps)


def predict(samples: np.ndarray, puppet: dict, fps: float, source="audio", decode: str | None = None) -> dict:
    """Mouth shapes at ``fps`` for 16 kHz mono samples (keys as ``pipeline.models.mouth_prediction``)."""
    check_puppet(puppet)
    how = decode or puppet["config"].get("decode", "viterbi")
    _, loglik = decode_voice(samples, puppet, source)
    weights = state_weights(loglik, puppet, how)
    n = int(np.floor(len(samples) / 16000 * fps + 0.5))
    y = trajectory_at(weights, puppet, fps, n)
    lips = face_points(y, puppet)[:, puppet["lip_index"]].reshape(n, -1)
    basis = dict(mean=puppet["pca_mean"], components=puppet["pca_components"])
    coeffs = project(lips, basis).astype(np.float32)
    return dict(coeffs=coeffs, lip_points=reconstruct(coeffs, basis).astype(np.float32),
                frame_time=np.arange(n) / fps, fps=fps, states=weights.argmax(1))
