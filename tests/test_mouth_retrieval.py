"""The person's own mouth shapes retrieved for new audio (pipeline/models/mouth_retrieval.py)."""
import numpy as np

from pipeline.models import mouth_retrieval as mr


def test_viterbi_trades_distance_for_continuity():
    shapes = np.array([[[0.0], [10.0]], [[0.0], [10.0]], [[10.0], [0.0]]])      # (T=3, K=2, k=1)
    cost = np.array([[0.0, 0.1], [0.0, 0.1], [0.0, 0.1]])                        # candidate 0 is nearest at every t
    assert mr.viterbi(cost, shapes, smooth=0.0, scale=1.0).tolist() == [0, 0, 0]   # 0, 0, 10: a jump at the end
    assert mr.viterbi(cost, shapes, smooth=1.0, scale=1.0).tolist() == [0, 0, 1]   # 0, 0, 0: continuity wins


def test_retrieval_returns_the_persons_real_shapes_in_the_order_the_audio_asks():
    rng = np.random.default_rng(0)
    values = rng.normal(size=(400, 3)).cumsum(0) * 0.1                           # a moving mouth, 100 Hz
    keys = mr.keys(values + 0.01 * rng.normal(size=values.shape))               # what the model predicted for it
    query = mr.keys(values[100:300])                                             # new audio: a stretch of the same
    at = np.arange(mr.STEP, 200 - mr.STEP, mr.STEP)                              # the query's own edges have no context
    nearest = mr.retrieve(query, keys, values, smooth=0.0)
    assert np.all(np.isclose(nearest[at], values[100:300][at]))                  # the very frames
    out = mr.retrieve(query, keys, values)                                       # with continuity: a steadier path
    jumps = lambda y: np.linalg.norm(np.diff(y[at], axis=0), axis=1).sum()
    assert jumps(out) < jumps(nearest)
    assert np.abs(out[at] - values[100:300][at]).mean() < 0.1                    # still near what was asked
    assert all(np.any(np.all(np.isclose(values, row, atol=1e-6), axis=1)) for row in out[at])   # real shapes only
    assert out.shape == (200, 3)


def test_keys_stack_context_with_edges_repeated():
    c = np.arange(10, dtype=np.float32)[:, None]
    k = mr.keys(c, context=1, step=4)
    assert k.shape == (10, 3)
    assert k[0].tolist() == [0, 0, 4] and k[5].tolist() == [1, 5, 9] and k[9].tolist() == [5, 9, 9]
