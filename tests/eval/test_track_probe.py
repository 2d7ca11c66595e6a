"""Table 3's track probe: identical decoders, exact at t0, metrics and the command end to end (tiny sizes)."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from vt4dcodec.errors import Vt4dError
from vt4dcodec.eval.protocol import EvaluationError
from vt4dcodec.eval.track_probe import (DECODERS, KIND_DYNAMIC, KIND_PAD, KIND_STATIC, ProbeSettings, TrackData,
                                        TrackProbe, evaluate, format_orderings, format_table, main,
                                        orderings, predict,
                                        sample_queries, save_figure, still_prediction, summarize, train_probe)

T, S = 4, 16


def _fake_data(sets: int = 6, P: int = 8, seed: int = 0) -> TrackData:
    """Random tokens, static cameras and straight-line tracks (enough to exercise every code path)."""
    rng = np.random.default_rng(seed)
    K = np.tile(np.array([[20.0, 0, (S - 1) / 2], [0, 20.0, (S - 1) / 2], [0, 0, 1]], np.float32), (sets, T, 1, 1))
    w2c = np.tile(np.eye(4, dtype=np.float32), (sets, T, 1, 1))
    w2c[..., 2, 3] = 4.0
    q = np.stack([rng.integers(0, S, (sets, P)), rng.integers(0, S, (sets, P)), rng.integers(0, T, (sets, P))], -1)
    kind = np.where(np.arange(P) < P // 2, KIND_STATIC, KIND_DYNAMIC).astype(np.int8)[None].repeat(sets, 0)
    kind[0, -1] = KIND_PAD
    vel = rng.normal(0, 0.5, (sets, P, 1, 2)) * (kind == KIND_DYNAMIC)[..., None, None]
    xy = (q[:, :, None, :2] + vel * (np.arange(T)[None, None, :, None] - q[:, :, None, 2:3])).astype(np.float32)
    visible = np.ones((sets, P, T), bool) & (kind != KIND_PAD)[..., None]
    return TrackData(z_s=rng.uniform(-1, 1, (sets, 10, 8)).astype(np.float32),
                     z_d=rng.uniform(-1, 1, (sets, 3, 8)).astype(np.float32), K=K, w2c=w2c, queries=q, kind=kind,
                     xy=xy, visible=visible, scene=np.arange(sets) // 2, camera=np.arange(sets) % 2, image_size=S,
                     frames=rng.integers(0, 256, (sets, T, S, S, 3), dtype=np.uint8))


SETTINGS = ProbeSettings(train_scenes=1, test_scenes=1, steps=3, batch_sets=2, queries_per_set=4, width=16, heads=2,
                         blocks=1, fourier=2)


def test_decoders_are_identical_but_for_what_they_read():
    nets = {}
    for reads in DECODERS:
        torch.manual_seed(0)
        nets[reads] = TrackProbe(reads, token_dim=8, frames=T, image_size=S, width=16, heads=2, blocks=2, fourier=2)
    states = [net.state_dict() for net in nets.values()]
    for other in states[1:]:
        assert other.keys() == states[0].keys()
        assert all(torch.equal(other[k], states[0][k]) for k in other)
    data = _fake_data()
    b = (torch.from_numpy(data.z_s[:2]), torch.from_numpy(data.z_d[:2]))
    sizes = {reads: net.memory(*b).shape[1] for reads, net in nets.items()}
    assert sizes == {"static": 11, "dynamic": 4, "both": 14, "none": 1}


def test_prediction_is_the_query_at_t0_and_starts_as_no_motion():
    data = _fake_data()
    torch.manual_seed(1)
    net = TrackProbe("both", token_dim=8, frames=T, image_size=S, width=16, heads=2, blocks=1, fourier=2)
    pred = predict(net, data)
    assert pred.shape == data.xy.shape
    np.testing.assert_allclose(pred, still_prediction(data))             # zero-initialised head
    with torch.no_grad():
        net.head[-1].bias.normal_()
    pred = predict(net, data)
    rows, cols = np.indices(data.kind.shape)
    assert np.array_equal(pred[rows, cols, data.queries[..., 2]], data.queries[..., :2].astype(np.float32))


def test_training_is_deterministic_and_metrics_are_exact():
    data = _fake_data()
    net_a, loss_a = train_probe("static", data, SETTINGS)
    net_b, loss_b = train_probe("static", data, SETTINGS)
    assert loss_a == loss_b and len(loss_a) == 1
    ev = evaluate(data, {"still": still_prediction(data), "static": predict(net_a, data), "truth": data.xy})
    assert all(v == 0.0 for v in ev["scene_epe"]["mixed"]["truth"])
    assert ev["scene_epe"]["static"]["still"] == [0.0, 0.0, 0.0]          # static fake tracks do not move
    assert all(v > 0 for v in ev["scene_epe"]["dynamic"]["still"])
    assert ev["pairs"]["mixed"] == ev["pairs"]["static"] + ev["pairs"]["dynamic"]


def test_summary_orderings_table_and_figure(tmp_path):
    data = _fake_data()
    preds = {"still": still_prediction(data)}
    offset = {"static": 0.5, "dynamic": 1.0, "both": 0.2, "none": 2.0}
    for k, d in offset.items():           # known errors: static tracks off by `d`, dynamic by `2 d`
        p = data.xy.copy()
        p[..., 0] += np.where(data.kind == KIND_DYNAMIC, 2 * d, d)[..., None]
        preds[k] = p
    summary = summarize(evaluate(data, preds))
    assert summary["static"]["epe"]["static"]["mean"] == pytest.approx(0.5)
    assert summary["dynamic"]["paired"]["Z_s - Z_d"]["mean"] == pytest.approx(-1.0)
    assert summary["mixed"]["best_single"] == "Z_s"
    checks = orderings(summary)
    assert checks["Z_s better on static tracks"]["holds"] and not checks["Z_d better on dynamic tracks"]["holds"]
    assert checks["both best on mixed tracks"]["holds"]
    # a constant offset on the static set: zero spread over scenes, no standard error, no call either way
    assert checks["Z_s better on static tracks"]["verdict"] == "tie (within noise)"
    assert checks["both best on mixed tracks"]["verdict"] == "holds"
    assert "sign against the paper" in format_orderings(checks)
    results = {"summary": summary, "decoders": list(DECODERS), "orderings": checks,
               "settings": {"model": "fake", "test_scenes": 3}}
    table = format_table(results)
    assert "| static" in table and "Z_s - Z_d" in table and "0.50" in table
    path = save_figure(tmp_path / "f.png", results, data, preds)
    assert path.stat().st_size > 1000


def test_sample_queries_kinds_and_padding():
    ids = np.zeros((2, 4, 5), np.int16)
    ids[1, 2, 3] = 1
    q, kind = sample_queries(ids, ids > 0, 3, np.random.default_rng(0))
    assert q.shape == (6, 3) and kind.tolist() == [0, 0, 0, 1, -1, -1]
    assert q[3].tolist() == [3, 2, 1]
    assert all(ids[t, v, u] == 0 for u, v, t in q[:3])


@pytest.mark.parametrize("kwargs", [{"steps": 0}, {"width": 10, "heads": 4}, {"lr": -1.0}, {"queries": True}])
def test_bad_settings_raise_evaluation_error(kwargs):
    with pytest.raises(EvaluationError) as info:
        ProbeSettings(**kwargs)
    assert isinstance(info.value, Vt4dError)
    with pytest.raises(EvaluationError, match="reads"):
        TrackProbe("everything", token_dim=8, frames=T, image_size=S)


def test_command_end_to_end(tmp_path, capsys):
    """The shipped tokenizer on 1 train + 1 test scene of 2 cameras, 2 steps per decoder."""
    out = tmp_path / "t3.json"
    args = ["--train-scenes", "1", "--test-scenes", "1", "--cameras", "2", "--queries", "4", "--steps", "2",
            "--batch-sets", "2", "--queries-per-set", "4", "--width", "16", "--train-cache", str(tmp_path / "train"),
            "--test-cache", str(tmp_path / "test"), "--token-cache", str(tmp_path / "tok"), "--out", str(out),
            "--figure", str(tmp_path / "t3.png"), "--quiet"]
    assert main(args) == 0
    results = json.loads(out.read_text())
    assert results["decoders"] == list(DECODERS) and set(results["summary"]) == {"static", "dynamic", "mixed"}
    assert results["summary"]["static"]["epe"]["still"]["n"] == 1
    assert (tmp_path / "t3.png").stat().st_size > 1000
    printed = capsys.readouterr().out
    assert "| track set" in printed and "Z_s better on static tracks" in printed
    assert main(["--table", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "| static" in printed and "both best on mixed tracks" in printed
    # the cached tokens are reused: a second run reads them back (same numbers, no tokenizer pass needed)
    assert main(args) == 0
    assert json.loads(out.read_text())["summary"] == results["summary"]
    assert main(args[:-1] + ["--decoders", "static,bogus"]) == 2
