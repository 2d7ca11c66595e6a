"""`vt4d generate` prints its summary once and writes its videos at the conditioning capture's frame rate,
which the saved scene records.  The prior, the tokenizer and the renderer are stand-ins: what is tested is
the command's output."""

from __future__ import annotations

import json
import shutil
from fractions import Fraction
from types import SimpleNamespace

import av

from cli_helpers import StandInDecoder, make_scene

import vt4dcodec.cli as cli
import vt4dcodec.cli.generate_commands as generate_commands
from vt4dcodec import load


def _stand_in_prior(monkeypatch):
    import vt4dcodec.model.directories as prior_module  # check_tokenizer's (torch-free) home

    fp = make_scene().fingerprint
    decoder = StandInDecoder(monkeypatch)
    from vt4dcodec.model.directories import DEFAULT_SAMPLER

    monkeypatch.setattr(generate_commands, "load_prior_model", lambda name, **where: SimpleNamespace(
        model_id="p", model_version="1", tokenizer_fingerprint=fp, sampler=DEFAULT_SAMPLER,
        config=SimpleNamespace(cond_dropout=0.0)))
    monkeypatch.setattr(generate_commands, "load_renderer", lambda name, *runtime, **where: SimpleNamespace(decode_steps=1))
    monkeypatch.setattr(prior_module, "check_tokenizer", lambda prior, fingerprint, **_: None)
    monkeypatch.setattr(generate_commands, "model_fingerprint", lambda model: fp)
    monkeypatch.setattr(generate_commands, "generate", lambda *a, metadata=None, **k: make_scene(metadata=metadata))
    monkeypatch.setattr(generate_commands, "SceneDecoder", lambda scene, model: decoder)


def test_generate_prints_its_summary_once_and_keeps_the_frame_rate(small_captures, tmp_path, monkeypatch, capsys):
    capture = tmp_path / "cap"
    shutil.copytree(small_captures / "cap-a", capture)
    manifest = json.loads((capture / "capture.json").read_text())
    (capture / "capture.json").write_text(json.dumps({**manifest, "fps": 24.0}))
    _stand_in_prior(monkeypatch)
    out = tmp_path / "gen"
    assert cli.main(["generate", str(capture), "--views", "source,pan", "-o", str(out)]) == 0
    captured = capsys.readouterr()
    text = captured.out + captured.err
    assert text.count("sampled 1 token state") == 1, text
    assert "rendered 2 views" in captured.out, captured.out
    assert load(out / "scene.vt4d").metadata["capture"] == {"fps": 24.0}
    for video in out.glob("*.mp4"):
        with av.open(str(video)) as container:
            assert Fraction(container.streams.video[0].average_rate) == 24
    assert len(list(out.glob("*.mp4"))) == 2
