"""Quality levels end to end: a model with an entropy model encodes at each level (learned-rans, format 1.6),
the file says its level, fewer bytes at lower levels, it decodes with the model directory that made it (found
by id under $VT4D_MODEL_PATH, or given), and a model without levels refuses --quality by name."""

import numpy as np
import pytest
import torch

from vt4dcodec import codec, errors
from vt4dcodec.format import dumps, open_scene


@pytest.fixture(scope="module")
def levels_model_dir(tmp_path_factory, small_config):
    import dataclasses

    from vt4dcodec.model import VideoTok4D, save_pretrained

    torch.manual_seed(0)
    model = VideoTok4D(dataclasses.replace(small_config, entropy_levels=3))
    model.update_entropy()
    return save_pretrained(model, tmp_path_factory.mktemp("levels") / "levels-model", model_id="levels-model",
                           model_version="0.0")


def test_levels_are_stored_and_cost_what_they_should(synth_scene, levels_model_dir, monkeypatch):
    monkeypatch.setenv("VT4D_MODEL_PATH", str(levels_model_dir.parent))
    assert codec.quality_levels(levels_model_dir) == (1, 2, 3)
    sizes = []
    for quality in (1, 2, 3):
        scene = codec.encode(synth_scene.capture, model=levels_model_dir, quality=quality, seed=0)
        data = dumps(scene)
        f = open_scene(data)
        assert f.encoding == "learned-rans" and f.quality == quality and f.version == (1, 6)
        sizes.append(len(data))
        frames = codec.decode(data, "source")  # tables found by the file's fingerprint
        assert frames.shape[0] == scene.cameras.num_frames and frames.dtype == np.uint8
    assert sizes[0] < sizes[1] < sizes[2]


def test_a_model_directory_given_to_the_decoder_serves_its_tables(synth_scene, levels_model_dir, monkeypatch):
    monkeypatch.delenv("VT4D_MODEL_PATH", raising=False)
    from vt4dcodec.format import learned

    data = dumps(codec.encode(synth_scene.capture, model=levels_model_dir, quality=2, seed=0))
    monkeypatch.setattr(learned, "_registered", {})  # a fresh process: only the file and the directory given
    with pytest.raises(errors.EntropyTablesError):
        codec.SceneDecoder.open(data)  # not installed, no model given
    decoder = codec.SceneDecoder.open(data, model=levels_model_dir)
    assert decoder.scene.quality == 2
    loaded = codec.load_model(levels_model_dir)
    assert codec.SceneDecoder.open(data, model=loaded).scene.quality == 2


def test_quality_on_a_model_without_levels_names_the_flag(synth_scene, model_dir):
    assert codec.quality_levels(model_dir) == ()
    with pytest.raises(errors.ModelError, match="--quality"):
        codec.encode(synth_scene.capture, model=model_dir, quality=1)
    with pytest.raises(errors.ModelError, match="--quality"):
        codec.encode(synth_scene.capture, model=model_dir, quality=9)


def test_codec_quality_levels_are_the_default_models():
    assert codec.QUALITY_LEVELS == codec.quality_levels(codec.DEFAULT_MODEL)


def test_a_models_default_level_is_what_encode_stores_when_nothing_is_asked(synth_scene, levels_model_dir, tmp_path,
                                                                            monkeypatch, small_config):
    """A model directory may record a default quality level (ship --default-quality): encode without an
    encoding or a level stores at it; an explicit encoding or level wins; a model without levels keeps int4."""
    import dataclasses
    import json

    from vt4dcodec.model import VideoTok4D, from_pretrained, save_pretrained

    monkeypatch.setenv("VT4D_MODEL_PATH", str(levels_model_dir.parent))
    assert codec.default_quality(levels_model_dir) is None  # none recorded: int4 as before
    assert codec.encode(synth_scene.capture, model=levels_model_dir, seed=0).encoding == codec.DEFAULT_ENCODING
    model = from_pretrained(levels_model_dir)
    with_default = save_pretrained(model, tmp_path / "with-default", model_id="levels-default", model_version="0.0",
                                   default_quality=2)
    assert json.loads((with_default / "config.json").read_text())["default_quality"] == 2
    assert codec.default_quality(with_default) == 2 and from_pretrained(with_default).default_quality == 2
    scene = codec.encode(synth_scene.capture, model=with_default, seed=0)
    assert (scene.encoding, scene.quality) == ("learned-rans", 2)
    assert codec.encode(synth_scene.capture, model=with_default, encoding="int8", seed=0).encoding == "int8"
    assert codec.encode(synth_scene.capture, model=with_default, quality=3, seed=0).quality == 3
    with pytest.raises(errors.ModelError, match="default_quality"):
        save_pretrained(model, tmp_path / "bad", model_id="x", model_version="0", default_quality=4)
    plain = VideoTok4D(dataclasses.replace(small_config, entropy_levels=0))
    with pytest.raises(errors.ModelError, match="quality levels"):
        save_pretrained(plain, tmp_path / "plain", model_id="x", model_version="0", default_quality=1)


def test_vt4d_encode_without_flags_uses_the_models_default_level(synth_scene, levels_model_dir, tmp_path, monkeypatch,
                                                                   capsys):
    import json

    from vt4dcodec.capture.io import write_capture
    from vt4dcodec.cli import main
    from vt4dcodec.model import from_pretrained, save_pretrained

    monkeypatch.setenv("VT4D_MODEL_PATH", str(tmp_path))
    model = save_pretrained(from_pretrained(levels_model_dir), tmp_path / "levels-default", model_id="levels-default",
                            model_version="0.0", default_quality=2)
    write_capture(synth_scene.capture, tmp_path / "cap")
    for extra, want in (([], ("learned-rans", 2)), (["--encoding", "int8"], ("int8", None)),
                        (["--quality", "1"], ("learned-rans", 1))):
        out = tmp_path / f"s{len(extra)}{want[1]}.vt4d"
        assert main(["encode", str(tmp_path / "cap"), "--model", str(model), "-o", str(out), "--json", *extra]) == 0
        summary = json.loads(capsys.readouterr().out)
        assert (summary["encoding"], summary["quality"]) == want
        assert (open_scene(out.read_bytes()).encoding, open_scene(out.read_bytes()).quality) == want
