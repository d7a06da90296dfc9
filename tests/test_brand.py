"""Voice Puppetry (paper 002): entropic estimation, decoding, the closed-form trajectory, voice features."""
import itertools

import numpy as np
import pytest
from scipy.special import logsumexp

from pipeline.audio import vocal_features
from pipeline.models import voice_puppet
from pipeline.errors import BadInputError
from stages.train_brand import entropic


def test_entropic_map_is_the_stationary_point_and_sparser_than_ml():
    omega = np.array([50.0, 30.0, 15.0, 4.0, 0.5, 0.05, 0.0])
    theta = entropic.entropic_multinomial(omega)
    assert theta.sum() == pytest.approx(1.0)
    nz = omega > 0
    grad = omega[nz] / theta[nz] + np.log(theta[nz]) + 1.0          # = −λ for every used entry
    assert np.ptp(grad) < 1e-6 * np.abs(grad).max()
    assert theta[~nz].sum() == 0
    ml = omega / omega.sum()
    entropy = lambda p: -np.sum(p[p > 0] * np.log(p[p > 0]))
    assert entropy(theta) < entropy(ml)
    # the log posterior Σ ω log θ + Σ θ log θ is higher at the MAP than at ML
    post = lambda p: np.sum(omega[nz] * np.log(p[nz])) + np.sum(p[p > 0] * np.log(p[p > 0]))
    assert post(theta) > post(ml)
    # a stronger prior (Z) concentrates the row further
    assert entropy(entropic.entropic_multinomial(omega, weight=20.0)) < entropy(theta)


def test_weak_evidence_falls_back_to_ml_and_trimming_keeps_the_largest():
    w = np.array([0.3, 0.2, 0.1])
    assert np.allclose(entropic.entropic_multinomial(w), w / w.sum())
    out = entropic.trim(np.array([0.9, 0.099, 0.001]), np.array([60.0, 60.0, 0.5]))
    assert out[2] == 0 and out.sum() == pytest.approx(1.0)
    assert entropic.trim(np.array([0.6, 0.4]), np.array([0.0, 0.0]))[0] > 0     # never empties a row


def _sample_cycle(n_seq=40, T=60, seed=0):
    """A sparse 3-state cycle with well separated 2-D Gaussian outputs."""
    rng = np.random.default_rng(seed)
    trans = np.array([[0.8, 0.2, 0.0], [0.0, 0.8, 0.2], [0.2, 0.0, 0.8]])
    means = np.array([[0.0, 0.0], [4.0, 0.0], [0.0, 4.0]])
    xs = []
    for _ in range(n_seq):
        s = rng.integers(3)
        for _ in range(T):
            xs.append(means[s] + 0.5 * rng.standard_normal(2))
            s = rng.choice(3, p=trans[s])
    return np.array(xs), np.full(n_seq, T)


@pytest.mark.parametrize("prior", ["entropic", "ml"])
def test_em_never_lowers_its_objective(prior):
    X, lengths = _sample_cycle()
    _, history = entropic.fit(X, lengths, 6, prior, 25, 0.0, 1e-3, 5.0, seed=1)
    post = np.array([h["log_posterior"] for h in history])
    # iteration k+1's E-step scores the parameters iteration k estimated; removals and trimming
    # (a first-order test) may lower it, an M-step never does
    steady = [k for k in range(1, len(history)) if history[k - 1]["states_after"] == history[k - 1]["states"]
              and history[k - 1]["transitions_after"] == history[k - 1]["transitions"]
              and history[k]["transitions"] == history[k - 1]["transitions"]]
    assert len(steady) > 5
    assert all(post[k] > post[k - 1] - 1e-6 for k in steady), post


def test_entropic_model_is_more_certain_than_ml():
    X, lengths = _sample_cycle()
    fits = {p: entropic.fit(X, lengths, 6, p, 40, 1e-6, 1e-3, 5.0, seed=1)[0] for p in ("entropic", "ml")}
    ent = {p: entropic.model_entropy(m) for p, m in fits.items()}
    assert ent["entropic"] < ent["ml"]
    # on fresh data from the same process the entropic model decodes with less posterior uncertainty
    Xt, lt = _sample_cycle(5, 60, seed=9)
    rate = {}
    for p, m in fits.items():
        ll = voice_puppet.gaussian_loglik(Xt[:60], m.means_, m.covars_)
        rate[p] = voice_puppet.sequence_entropy_rate(ll, m.startprob_, m.transmat_)
    assert rate["entropic"] <= rate["ml"] + 1e-9


def test_state_removal_survives_a_dead_row():
    X, lengths = _sample_cycle(10, 40)
    m = entropic.fit(X, lengths, 4, "entropic", 3, 0.0, 1e-3, 1.0, seed=0)[0]
    m.transmat_[0] = [0.0, 1.0, 0.0, 0.0][:m.n_components]
    keep = np.ones(m.n_components, bool)
    keep[1] = False
    small = entropic.subset(m, keep)
    assert np.allclose(small.transmat_.sum(1), 1.0) and small.n_components == m.n_components - 1


def _brute(loglik, start, trans):
    K, T = len(start), len(loglik)
    seqs = list(itertools.product(range(K), repeat=T))
    lp = np.array([np.log(start[s[0]]) + loglik[0, s[0]] + sum(np.log(trans[s[t - 1], s[t]]) + loglik[t, s[t]]
                                                               for t in range(1, T)) for s in seqs])
    return seqs, lp


def test_viterbi_and_sequence_entropy_match_enumeration():
    rng = np.random.default_rng(3)
    K, T = 3, 5
    start = rng.dirichlet(np.ones(K))
    trans = rng.dirichlet(np.ones(K), size=K)
    loglik = rng.normal(size=(T, K))
    seqs, lp = _brute(loglik, start, trans)
    path, best = voice_puppet.viterbi(loglik, start, trans)
    assert tuple(path) == seqs[int(np.argmax(lp))] and best == pytest.approx(lp.max())
    post = np.exp(lp - logsumexp(lp))
    h = -np.sum(post * np.log(post)) / T
    assert voice_puppet.sequence_entropy_rate(loglik, start, trans) == pytest.approx(h, rel=1e-8)
    gamma = voice_puppet.posteriors(loglik, start, trans)
    assert np.allclose(gamma[2], [post[[s[2] == k for s in seqs]].sum() for k in range(K)])


def _objective(Y, states, means, covars, fps):
    P, d = np.linalg.inv(covars), Y.shape[1]
    Pxx = np.linalg.inv(covars[:, :d, :d])
    r0 = Y[0] - means[states[0], :d]
    tot = r0 @ Pxx[states[0]] @ r0
    for t in range(1, len(Y)):
        r = np.concatenate([Y[t], fps * (Y[t] - Y[t - 1])]) - means[states[t]]
        tot += r @ P[states[t]] @ r
    return tot


def test_closed_form_trajectory_is_the_minimiser_of_eq5():
    rng = np.random.default_rng(0)
    K, d, T, fps = 3, 3, 9, 25.0
    A = rng.standard_normal((K, 2 * d, 2 * d))
    covars = np.einsum("kij,klj->kil", A, A) + 0.3 * np.eye(2 * d)
    means = rng.standard_normal((K, 2 * d))
    states = rng.integers(0, K, T)
    gauss = voice_puppet.split_covariances(means, covars)
    Y = voice_puppet.solve_trajectory(np.eye(K)[states], gauss, fps)
    f0 = _objective(Y, states, means, covars, fps)
    for _ in range(20):                                     # any perturbation raises the cost
        assert _objective(Y + 1e-3 * rng.standard_normal(Y.shape), states, means, covars, fps) > f0
    # the gradient vanishes (central differences)
    eps, g = 1e-5, np.zeros(Y.size)
    for i in range(Y.size):
        e = np.zeros(Y.size)
        e[i] = eps
        g[i] = (_objective(Y + e.reshape(Y.shape), states, means, covars, fps)
                - _objective(Y - e.reshape(Y.shape), states, means, covars, fps)) / (2 * eps)
    assert np.abs(g).max() < 1e-4 * max(1.0, abs(f0))


def test_trajectory_follows_state_means_and_velocities():
    # two states with position means 0 and 10 and a velocity prior of 0: the path moves smoothly between them
    means = np.array([[0.0, 0.0], [10.0, 0.0]])
    covars = np.array([np.diag([1.0, 100.0])] * 2)
    states = np.array([0] * 10 + [1] * 10)
    y = voice_puppet.solve_trajectory(np.eye(2)[states], voice_puppet.split_covariances(means, covars), 10.0)[:, 0]
    assert abs(y[0]) < 0.5 and abs(y[-1] - 10) < 0.5
    assert (np.diff(y) > -1e-9).all() and 0 < y[9] < 10          # monotone, no jump at the switch


def test_pool_to_rate_averages_each_frame_period():
    f100 = np.arange(100, dtype=float)[:, None]                  # 1 s at 100 Hz
    out = vocal_features.pool_to_rate(f100, 25, 25.0)
    assert out.shape == (25, 1)
    assert out[5, 0] == pytest.approx(np.mean(np.arange(18, 22)))  # frame 5 = 0.2 s covers rows 18–21


@pytest.mark.parametrize("kind", vocal_features.KINDS)
def test_voice_features_are_finite_on_speechlike_and_silent_audio(kind):
    t = np.arange(16000) / 16000
    vowel = (np.sin(2 * np.pi * 120 * t) * (1 + np.sin(2 * np.pi * 700 * t))).astype(np.float32) * 0.1
    for audio in (vowel, np.zeros(16000, np.float32)):
        f = vocal_features.vocal_features(audio, kind, 25.0, 25)
        assert f.shape == (25, vocal_features.DIMS[kind]) and np.isfinite(f).all()


def test_silent_or_short_audio_is_refused_with_the_file_name():
    puppet = dict(config=dict(rate=25.0, features="mfcc", decode="viterbi"))
    with pytest.raises(BadInputError, match="quiet.wav.*silent"):
        voice_puppet.decode_voice(np.zeros(16000, np.float32), puppet, "quiet.wav")
    with pytest.raises(BadInputError, match="blip.wav.*too short"):
        vocal_features.vocal_features(np.ones(100, np.float32), "mfcc", 25.0, 0, "blip.wav")
