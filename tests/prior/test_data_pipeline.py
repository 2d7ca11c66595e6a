"""Tokenized shards + clip sidecars, the pair dataset over them, and the training entry point."""

from __future__ import annotations

import io

import numpy as np
import pytest
import torch
from hypothesis import given
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from co4dgen_helpers import CAMERAS, EVENTS
from vt4dcodec.archive import open_archive
from vt4dcodec.data.archive_dataset import ArchiveDataset
from vt4dcodec.errors import ArchiveError
from vt4dcodec.model import from_pretrained
from vt4dcodec.model.weights_io import load_prior
from vt4dcodec.model.train.data import ScenePool
from vt4dcodec.model.train.prior import PriorPairDataset, collate_prior
from vt4dcodec.model.train.tokenize_scenes import clip_path, pack_clip, tokenize_event, unpack_clip


def test_shards_hold_anchor_tokens_of_every_camera_readable_by_the_storage_library(shards, tokenizer_dir):
    ds = ArchiveDataset(shards)
    assert len(ds) == EVENTS * CAMERAS and len(ds.shards) == EVENTS  # per_shard=1
    keys = sorted(k for _, k in ds.keys)
    assert keys == sorted(f"train-{s:06d}/cam{c}" for s in range(EVENTS) for c in range(CAMERAS))
    tok = from_pretrained(tokenizer_dir)
    pool = ScenePool.for_config(tok.config, shards.parent / "cache", CAMERAS)
    direct = tokenize_event(tok, pool, 1)
    for i, (_, key) in enumerate(ds.keys):
        sample = ds[i]
        meta = sample["metadata"]["user"]["co4dgen"]
        assert key == f"{meta['event']}/cam{meta['camera']}" and meta["num_cameras"] == CAMERAS
        assert sample["metadata"]["fingerprint"]["model_id"] == "tok-test"
        if meta["seed"] == 1:  # the stored tokens are the tokenizer's, to float16 precision
            z_s, z_d = direct[meta["camera"]]
            np.testing.assert_allclose(sample["static_tokens"].numpy(), z_s, atol=1e-3)
            np.testing.assert_allclose(sample["dynamic_tokens"].numpy(), z_d, atol=1e-3)
            np.testing.assert_allclose(sample["w2c"].numpy(), pool.scene(1)["w2c"][meta["camera"]], atol=1e-5)
    with open_archive(clip_path(ds.shards[1])) as reader:
        clip = unpack_clip(reader.read_bytes("train-000001/cam2"))
    assert np.array_equal(clip["frames"], pool.scene(1)["frames"][2])


def test_pair_dataset_enumerates_ordered_pairs_of_distinct_cameras_of_one_event(shards):
    ds = PriorPairDataset(shards)
    assert len(ds) == EVENTS * CAMERAS * (CAMERAS - 1)
    seen = set()
    for i in range(len(ds)):
        item = ds[i]
        a_event, _, a = item["anchor_key"].rpartition("/cam")
        c_event, _, c = item["clip_key"].rpartition("/cam")
        assert a_event == c_event and a != c
        seen.add((item["anchor_key"], item["clip_key"]))
    assert len(seen) == len(ds)
    batch = collate_prior([ds[0], ds[3]])
    assert batch.z_s.shape == (2, 8, 8) and batch.cond.frames.shape == (2, 4, 3, 32, 32)
    assert 0.0 <= batch.cond.frames.min() and batch.cond.frames.max() <= 1.0


def test_training_reads_the_shards_and_binds_the_prior_to_their_tokenizer(trained_prior, tokenizer_dir):
    import json

    prior = load_prior(trained_prior / "prior")
    tok = from_pretrained(tokenizer_dir)
    fp = tok.fingerprint("tok-test", "0")
    assert prior.tokenizer_fingerprint == fp
    log = [json.loads(line) for line in (trained_prior / "log.jsonl").read_text().splitlines()]
    assert [r["step"] for r in log] == [2, 4, 6] and all(np.isfinite(r["loss"]) for r in log)
    assert (trained_prior / "loss.png").stat().st_size > 1000
    card = (trained_prior / "prior" / "MODEL_CARD.md").read_text()
    assert fp.weights_sha256 in card and "6 steps" in card
    assert not torch.equal(prior.static_std, torch.ones_like(prior.static_std))  # data statistics were set


@given(arrays(np.uint8, st.tuples(st.integers(1, 3), st.integers(1, 5), st.integers(1, 5), st.just(3))),
       st.floats(-100, 100))
def test_clip_records_round_trip(frames, value):
    T = frames.shape[0]
    K = np.full((T, 3, 3), value, np.float32)
    w2c = np.tile(np.eye(4, dtype=np.float32), (T, 1, 1))
    out = unpack_clip(pack_clip(frames, K, w2c))
    assert np.array_equal(out["frames"], frames) and np.array_equal(out["K"], K)


@given(st.binary(max_size=200))
def test_garbage_clip_records_raise_archive_error(data):
    with pytest.raises(ArchiveError):
        unpack_clip(data)


def test_clip_records_with_wrong_content_raise_archive_error():
    good = dict(frames=np.zeros((2, 4, 4, 3), np.uint8), K=np.zeros((2, 3, 3), np.float32),
                w2c=np.zeros((2, 4, 4), np.float32))
    for bad in ({**good, "frames": good["frames"].astype(np.float32)}, {**good, "K": np.zeros((3, 3, 3))},
                {**good, "extra": np.zeros(1)}, {**good, "w2c": np.full((2, 4, 4), np.nan, np.float32)}):
        buf = io.BytesIO()
        np.savez(buf, **bad)
        with pytest.raises(ArchiveError):
            unpack_clip(buf.getvalue())
    buf = io.BytesIO()
    np.savez(buf, frames=np.array([object()], dtype=object), K=good["K"], w2c=good["w2c"])  # pickled object array
    with pytest.raises(ArchiveError):
        unpack_clip(buf.getvalue())
