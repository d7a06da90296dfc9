"""Whisper tiny.en's encoder in torch (pipeline.audio.whisper_layers): same numbers as CTranslate2, every layer."""
from __future__ import annotations

import struct

import numpy as np
import pytest

from pipeline.audio import front_ends, whisper_encoder as we, whisper_layers as wl
from pipeline.audio.streaming_features import causal_features
from pipeline.errors import ParameterError
from pipeline.params import Whisper
from tests.test_whisper_encoder import speech_like


def test_torch_port_gives_ctranslate2s_final_states():
    mel = we.log_mel(speech_like(4.0), 400)
    ours = wl.encode_layers(mel[None])
    assert ours.shape == (wl.N_LAYERS, 1, 200, we.STATE_DIM)
    ref = we.encode_mel(mel)
    assert np.abs(ours[-1, 0] - ref).max() < 1e-3 * np.abs(ref).max()
    # the layers before the final norm are other numbers, not copies of it
    assert all(np.abs(ours[k, 0] - ref).max() > 0.1 for k in range(wl.N_LAYERS - 1))


def test_reader_takes_every_encoder_variable_and_refuses_old_formats(tmp_path):
    v = wl.read_ct2_variables(we.weights_folder() / "model.bin")
    assert v["conv1/weight"].shape == (384, 80, 3) and v["conv1/weight"].dtype == np.float32
    assert v["position_encodings/encodings"].shape == (1500, 384)
    assert int(v["num_heads"]) == 6
    assert not any(k.startswith("decoder") for k in v)
    old = tmp_path / "model.bin"
    old.write_bytes(struct.pack("<I", 3) + b"\0" * 16)
    with pytest.raises(we.WeightsError, match="format version 3"):
        wl.read_ct2_variables(old)


def test_layers_are_side_by_side_and_the_final_one_matches_the_shipped_front_end():
    x = speech_like(3.0, seed=1)
    final = we.whisper_features(x)
    both = wl.whisper_features(x, layers=[2, 5])
    assert both.shape == (len(final), 2 * we.STATE_DIM)
    assert np.abs(both[:, we.STATE_DIM:] - final).max() < 1e-3 * np.abs(final).max()
    block2 = wl.whisper_features(x, layers=[2])
    np.testing.assert_allclose(block2, both[:, :we.STATE_DIM], atol=1e-5)


def test_streaming_reads_the_models_layers():
    x = speech_like(3.0, seed=2)
    frames = causal_features(x, "whisper", {"layers": [3]})
    assert frames.shape[1] == front_ends.feature_dim("whisper", 1)
    frames = causal_features(x, "whisper", {"layers": [1, 3]})
    assert frames.shape[1] == front_ends.feature_dim("whisper", 2) == 2 * we.STATE_DIM


@pytest.mark.parametrize("layers", [[6], [3, 2], [], [1, 1]])
def test_bad_layer_choice_is_one_clear_error(layers):
    with pytest.raises(ParameterError, match="layers"):
        Whisper(layers=layers).validate()


def test_depth_and_width_are_read_from_the_file():
    v = wl.read_ct2_variables(we.weights_folder() / "model.bin")
    assert wl.blocks_of(v) == wl.N_BLOCKS                      # layer_norm/… is not a block
    model = wl.build(v)
    assert len(model.blocks) == wl.N_BLOCKS and model.conv1.out_channels == we.STATE_DIM


def test_an_encoder_this_project_does_not_pin_is_one_clear_error():
    with pytest.raises(we.WeightsError, match="choose tiny.en or one of base"):
        wl.pinned_bytes("large-v3")


def test_stopping_early_gives_the_same_first_layers():
    mel = we.log_mel(speech_like(2.0, seed=4), 200)[None]
    full = wl.encode_layers(mel)
    first = wl.encode_layers(mel, upto=3)
    assert first.shape[0] == 4
    np.testing.assert_allclose(first, full[:4], atol=1e-5)
