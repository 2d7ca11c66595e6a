"""The shipped vt4d-tiny through the public API and the `vt4d` command, as a new user would use it."""

import json
import subprocess
import sys

import numpy as np
import pytest

import vt4dcodec
from vt4dcodec import codec
from vt4dcodec.eval.protocol import HEALTH_THRESHOLDS
from vt4dcodec.media import mp4_codec_name, psnr, read_mp4
from vt4dcodec.synth import SynthConfig, generate_scene


def vt4d(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "vt4dcodec", *map(str, args)], capture_output=True, text=True,
                          cwd=cwd, timeout=600)


@pytest.fixture(scope="module")
def scene():
    return generate_scene(11, split="test", config=SynthConfig(num_cameras=3))


def test_from_pretrained_loads_the_shipped_model():
    from vt4dcodec.model import from_pretrained, shipped_model_ids

    assert "vt4d-tiny" in shipped_model_ids()
    model = from_pretrained("vt4d-tiny")
    assert model.model_id == "vt4d-tiny" and model.config.frames == 8 and model.config.image_size == 64


def test_encode_save_load_decode_with_shipped_weights(tmp_path, scene):
    cap = scene.capture
    encoded = vt4dcodec.encode(cap, camera=cap.camera_names[0])
    path = tmp_path / "scene.vt4d"
    nbytes = vt4dcodec.save(encoded, path)
    loaded = vt4dcodec.load(path)
    # a model with quality levels stores its default level (vt4d-tiny 2.0.0: q9 of 9), else the default encoding
    assert (loaded.encoding, loaded.quality) == (("learned-rans", codec.default_quality()) if codec.default_quality()
                                                 else (codec.DEFAULT_ENCODING, None))
    # tokens + cameras + fingerprint: 2.0.0 at q9 about 5.2 KB; 1.0.0's int4 6.7 KB, 0.13.0 and 0.12.0 5.6-6.7 KB
    # (0.11.0 int4-rans 5.1-5.7 KB; 0.9.0's repeated copies: about 2.8 KB); float16 would be 22 KB
    assert nbytes < 8192
    frames = vt4dcodec.decode(path, "source", steps=4, seed=0)
    assert frames.shape == cap.frames[cap.camera_names[0]].shape
    # a trained model reproduces the source view far better than a constant grey image does
    grey = np.full_like(frames, 128)
    gt = cap.frames[cap.camera_names[0]]
    assert psnr(frames, gt) > psnr(grey, gt) + 3.0
    again = vt4dcodec.decode(path, "source", steps=4, seed=0)
    assert np.array_equal(frames, again)


def test_cli_encode_info_verify_decode_on_a_capture(tmp_path, scene):
    from vt4dcodec.capture.io import write_capture

    cap_dir = tmp_path / "capture"
    write_capture(scene.capture, cap_dir)
    out = tmp_path / "s.vt4d"
    r = vt4d("encode", cap_dir, "-o", out, "--json", "--quiet")
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout)["scenes"][0]["bytes"] == out.stat().st_size
    r = vt4d("info", out, "--json")
    assert r.returncode == 0, r.stderr
    r = vt4d("verify", out)
    assert r.returncode == 0, r.stderr
    r = vt4d("decode", out, "-t", "source", "-t", "orbit:degrees=15", "-o", tmp_path / "views", "--steps", "2",
             "--json", "--quiet")
    assert r.returncode == 0, r.stderr
    outputs = json.loads(r.stdout)["outputs"]
    assert len(outputs) == 2 and all((tmp_path / "views").joinpath(o["path"].split("/")[-1]).exists() for o in outputs)
    # archives: encode into one, decode by key
    r = vt4d("encode", cap_dir, "--archive", tmp_path / "a.vt4da", "--json", "--quiet")
    assert r.returncode == 0, r.stderr
    key = json.loads(r.stdout)["scenes"][0]["key"]
    r = vt4d("decode", tmp_path / "a.vt4da", "--key", key, "--format", "npz", "--steps", "1", "-o", tmp_path / "v2")
    assert r.returncode == 0, r.stderr
    assert vt4d("verify", tmp_path / "a.vt4da").returncode == 0


def test_cli_errors_have_meaningful_exit_codes(tmp_path):
    bad = tmp_path / "bad.vt4d"
    bad.write_bytes(b"not a scene at all")
    r = vt4d("decode", bad, "-o", tmp_path / "x")
    assert r.returncode == 1 and "error" in r.stderr
    r = vt4d("decode", tmp_path / "missing.vt4d", "-o", tmp_path / "x")
    assert r.returncode == 3
    r = vt4d("encode", tmp_path, "-o", tmp_path / "y.vt4d")
    assert r.returncode == 1 and "capture" in r.stderr
    assert vt4d("decode").returncode == 2


def test_demo_writes_videos_picture_and_reports(tmp_path):
    r = vt4d("demo", "-o", tmp_path / "demo", "--steps", "2", "--json")
    assert r.returncode == 0, r.stderr
    report = json.loads(r.stdout)
    assert (tmp_path / "demo" / "contact_sheet.png").stat().st_size > 1000
    assert len(report["views"]) == 3 and all(v["psnr_db"] > 8 for v in report["views"].values())
    videos = sorted((tmp_path / "demo").glob("*.mp4"))  # per view: decoded, ground truth, side by side
    assert len(videos) == 9 and {mp4_codec_name(v) for v in videos} == {"h264"}
    both = read_mp4(report["views"][next(iter(report["views"]))]["side_by_side_video"])
    assert both.shape[1:] == (256, 2 * 256 + 2, 3)  # x4 for viewing: truth | decoded
    assert report["scene_bytes"] == (tmp_path / "demo" / "scene.vt4d").stat().st_size
    # the demo stores what `vt4d encode` stores: the model's default level (it wrote int4 after 2.0.0 shipped)
    assert (report["encoding"], report["quality"]) == ("learned-rans", codec.default_quality())


def test_cluster_ranks_encode_disjoint_shares_into_their_own_shards(tmp_path):
    """The torchrun path: each rank (RANK/WORLD_SIZE set by torchrun) encodes its share into its shard."""
    import os

    from vt4dcodec.archive import open_archive
    from vt4dcodec.capture.io import write_capture

    root = tmp_path / "captures"
    for seed in (21, 22, 23):
        write_capture(generate_scene(seed, split="test", config=SynthConfig(num_cameras=2)).capture,
                      root / f"c{seed}")
    keys = []
    for rank in (0, 1):
        env = {**os.environ, "RANK": str(rank), "WORLD_SIZE": "2"}
        r = subprocess.run([sys.executable, "-m", "vt4dcodec", "encode", str(root), "--archive",
                            str(tmp_path / "shards" / "train.vt4da"), "--quiet", "--json"],
                           capture_output=True, text=True, env=env, timeout=600)
        assert r.returncode == 0, r.stderr
        shard = tmp_path / "shards" / f"train-rank{rank:05d}-of-00002.vt4da"
        assert json.loads(r.stdout)["archive"] == str(shard)
        with open_archive(shard) as ar:
            keys += ar.keys()
    assert len(keys) == 3 and len(set(keys)) == 3  # every capture encoded exactly once across ranks


def test_every_shipped_prior_is_bound_to_a_shipped_tokenizer_and_records_its_sampler():
    """A prior is retrained whenever its tokenizer's tokens change: the shipped prior's recorded tokenizer is the
    tokenizer shipped beside it, one with exactly its networks (the shipped one adds an entropy model: same
    tokens, digests computed from the weights on load), or one the shipped tokenizer reads (``ship --reads``: a
    renderer replaced, or render feedback added, whose first pass is then exactly the recorded tokenizer's encode,
    what ``generate.conditioning_tokens`` conditions on); and it records the sampler setting measured for it."""
    from vt4dcodec.model.directories import (CONFIG_FILE, PRIOR_META_FILE, meta_fingerprint, meta_networks,
                                             meta_token_sources, model_directory, read_model_meta, read_prior_meta,
                                             same_networks, shipped_prior_ids)

    priors = shipped_prior_ids()
    assert "co4dgen-tiny" in priors
    for prior in priors:
        meta = read_prior_meta(model_directory(prior, PRIOR_META_FILE))
        tokenizer_meta = read_model_meta(model_directory(meta["tokenizer"].model_id, CONFIG_FILE))
        tokenizer = meta_fingerprint(tokenizer_meta)
        recorded, sources = meta["tokenizer"], meta_token_sources(tokenizer_meta)
        assert tokenizer.matches(recorded) or same_networks(meta_networks(tokenizer_meta), tokenizer, recorded,
                                                            sources), (prior, tokenizer.short(), recorded.short())
        if (recorded.config_sha256, recorded.weights_sha256) in sources:  # its encoder's first pass, or the same
            config = tokenizer_meta["config"]
            assert recorded.config_sha256 in (*config.first_pass_sha256s(), tokenizer.config_sha256,
                                              config.networks().sha256()), prior
        model = codec.load_model(meta["tokenizer"].model_id)
        assert tokenizer == codec.model_fingerprint(model)
        assert model.network_digests == meta_networks(tokenizer_meta)  # from_pretrained computes them
        assert isinstance(meta["extra"].get("sampler"), dict) and meta["extra"]["sampler"].get("measured"), prior


@pytest.mark.parametrize("cameras", [None, "all"])
def test_the_exported_encoder_stores_the_default_quality_level_like_the_torch_one(scene, cameras):
    """Regression: `vt4d encode` on onnxruntime (the torch-free install) stored int4 where the torch encoder
    stored the model's default level (learned-rans q9 for vt4d-tiny 2.0.0): the exported encoder did not read
    default_quality from config.json."""
    from vt4dcodec.model.onnx_encoder import OnnxEncoder

    assert OnnxEncoder.open("vt4d-tiny").default_quality == codec.default_quality("vt4d-tiny") == 9
    cap = scene.capture
    kw = {"cameras": cameras} if cameras else {"camera": cap.camera_names[0]}
    stored = {rt: codec.encode(cap, runtime=rt, **kw) for rt in ("onnx", "torch")}
    assert {(s.encoding, s.quality) for s in stored.values()} == {("learned-rans", 9)}


def test_cli_encode_on_onnxruntime_stores_the_default_quality_level(tmp_path):
    """The same through `vt4d encode --runtime onnx`, which hands the codec a loaded exported encoder (the CI's
    torch-free install check wrote int4 here)."""
    assert vt4d("synth", "-n", "1", "--split", "test", "--seed", "5", "-o", tmp_path / "caps").returncode == 0
    (capture,) = [p for p in (tmp_path / "caps").iterdir() if p.is_dir()]
    for cameras in ("cam00", "all"):
        out = tmp_path / f"{cameras}.vt4d"
        r = vt4d("encode", capture, "--cameras", cameras, "-o", out, "--runtime", "onnx", "-q")
        assert r.returncode == 0, r.stderr
        info = vt4dcodec.open_scene(out)
        assert (info.encoding, info.quality) == ("learned-rans", 9), cameras


def test_files_of_the_same_networks_without_the_entropy_model_decode_and_others_are_refused(scene):
    """vt4d-tiny 2.0.0 is 1.0.0's networks with an entropy model: a scene stored by a model with exactly these
    networks (the fingerprint 1.0.0 wrote: the networks' own digests, another version) decodes without --force,
    to the same frames; one whose weights differ is refused. Regression: 2.0.0 refused every 1.0.0 file."""
    import dataclasses

    from vt4dcodec.errors import ModelMismatchError
    from vt4dcodec.model.directories import meta_networks, model_directory, read_model_meta

    cap = scene.capture
    encoded = vt4dcodec.encode(cap, camera=cap.camera_names[0], encoding="int8")
    networks = meta_networks(read_model_meta(model_directory("vt4d-tiny")))
    assert networks is not None
    older = dataclasses.replace(encoded, fingerprint=dataclasses.replace(
        encoded.fingerprint, model_version="1.0.0", config_sha256=networks[0], weights_sha256=networks[1]))
    a = codec.SceneDecoder.open(encoded).render("source")
    b = codec.SceneDecoder.open(older).render("source")
    assert np.array_equal(a, b)
    other = dataclasses.replace(older, fingerprint=dataclasses.replace(older.fingerprint, weights_sha256="0" * 64))
    with pytest.raises(ModelMismatchError, match="--force"):
        codec.SceneDecoder.open(other)


def test_files_of_the_models_the_shipped_tokenizer_reads_decode_with_their_tables(scene):
    """vt4d-tiny 2.1.0 is 2.0.0 with render feedback in the encoder (``ship --reads``): a learned-rans file 2.0.0
    wrote (its fingerprint, config without feedback) finds its entropy tables in 2.1.0 and decodes without --force
    to the frames of the same tokens. Regression: the tables were looked up only under an equal config hash."""
    import dataclasses

    from vt4dcodec.format import dumps, loads
    from vt4dcodec.model.directories import meta_token_sources, model_directory, read_model_meta

    meta = read_model_meta(model_directory("vt4d-tiny"))
    sources = meta_token_sources(meta)
    if not sources:
        pytest.skip("the shipped vt4d-tiny reads no earlier model's files")
    cap = scene.capture
    encoded = vt4dcodec.encode(cap, camera=cap.camera_names[0])
    assert encoded.encoding == "learned-rans"
    for config_sha256, weights_sha256 in sources[:1]:  # the model it replaced (the others: its networks)
        older = dataclasses.replace(encoded, fingerprint=dataclasses.replace(
            encoded.fingerprint, model_version="earlier", config_sha256=config_sha256, weights_sha256=weights_sha256))
        stored, own = loads(dumps(older)), loads(dumps(encoded))
        assert stored.fingerprint == older.fingerprint
        assert np.array_equal(stored.static_tokens, own.static_tokens)
        assert np.array_equal(stored.dynamic_tokens, own.dynamic_tokens)
        assert np.array_equal(codec.SceneDecoder.open(stored).render("source"),
                              codec.SceneDecoder.open(own).render("source"))


def test_generate_with_the_shipped_prior(tmp_path, scene):
    """`vt4d generate` from a capture with co4dgen-tiny + vt4d-tiny: one sample, several views."""
    from vt4dcodec.capture.io import write_capture

    cap_dir = tmp_path / "capture"
    write_capture(scene.capture, cap_dir)
    r = vt4d("generate", cap_dir, "--anchor", "orbit:degrees=20", "--views", "source,pan:degrees=10",
             "-o", tmp_path / "gen", "--render-steps", "2")
    assert r.returncode == 0, r.stderr
    generated = vt4dcodec.load(tmp_path / "gen" / "scene.vt4d")
    assert generated.provenance.kind == "generated"
    assert generated.fingerprint.model_id == "vt4d-tiny"
    videos = list((tmp_path / "gen").glob("*.mp4"))
    assert len(videos) == 2 and {mp4_codec_name(v) for v in videos} == {"h264"}


# The shipped vt4d-tiny on four held-out scenes through the public encode/decode path (default
# encoding). Token health is asserted at the issue-12 thresholds (slot spread >= 0.2 in both groups,
# token-swap drop >= 5 dB on the source view: vt4dcodec.eval.protocol.HEALTH_THRESHOLDS), which 1.0.0 meets;
# the source-view line is a regression guard at the level reached (1.0.0 meets issue 12's 25 dB on the
# 50-scene evaluation, 27.22 dB; four scenes are too few for an absolute bound). vt4d-tiny 1.0.0 on these four
# scenes (the test's own computation, int4): source view +7.54 dB over the flat mean-colour image, swap drop
# 12.81 dB, slot spread Z_s 0.835 / Z_d 0.491 (the guard holds by 0.04 dB: 1.0.0's source view is about 1 dB
# below 0.13.0's). Earlier models, source view over flat: 0.13.0 +8.38, 0.12.0 +8.38, 0.11.0 +8.14, 0.10.0
# +8.31, 0.9.0 +6.14, 0.8.0 +5.51, 0.7.0 +4.41, 0.6.0 +3.81, 0.5.0 +2.57, 0.4.0 +1.93, 0.3.0 +0.69, 0.2.0 +0.5;
# swap drop 13.56, 13.37, 13.08, 13.27, 11.06, 10.41, 9.38, 8.69, 7.43, 6.62, 5.31, 3.1; slot spread Z_s / Z_d
# 0.825 / 0.321, 0.814 / 0.307, 0.812 / 0.312, 0.814 / 0.301, 0.799 / 0.287, 0.781 / 0.291, 0.670 / 0.249,
# 0.656 / 0.248, 0.502 / 0.221, 0.516 / 0.257, 0.237 / -, 0.002 / -; each in its default encoding (1.0.0,
# 0.13.0, 0.12.0, 0.10.0 and 0.9.0 int4, 0.8.0 and 0.6.0 int5-rans, the others int4-rans).
GUARD_SOURCE_OVER_FLAT_DB = 7.5


@pytest.fixture(scope="module")
def held_out_tokens():
    """Camera 0 of four held-out 10-camera scenes: encoded (default encoding), decoded from the bytes."""
    out = []
    for seed in range(4):
        sc = generate_scene(seed, split="test", config=SynthConfig(num_cameras=10))
        cam = sc.capture.camera_names[0]
        blob = vt4dcodec.format.dumps(codec.encode(sc.capture, "vt4d-tiny", camera=cam))
        out.append((sc.capture, cam, codec.SceneDecoder.open(blob)))
    return out


def test_shipped_tokens_carry_the_scene(held_out_tokens):
    import torch

    from vt4dcodec.model.diagnostics import slot_spread

    own, flat, swapped = [], [], []
    for i, (cap, cam, decoder) in enumerate(held_out_tokens):
        truth = cap.frames[cam]
        own.append(psnr(decoder.render("source"), truth))
        flat.append(psnr(np.broadcast_to(truth.reshape(-1, 3).mean(0).round().astype(np.uint8), truth.shape), truth))
        other = held_out_tokens[(i + 1) % len(held_out_tokens)][2]  # another scene's tokens, this camera
        swap = codec.SceneDecoder(scene=other.scene, model=decoder.model)
        swapped.append(psnr(swap.render(cap.cameras[cam]), truth))
    z_s = torch.stack([torch.from_numpy(np.asarray(d.scene.static_tokens, np.float32)) for _, _, d in held_out_tokens])
    z_d = torch.stack([torch.from_numpy(np.asarray(d.scene.dynamic_tokens, np.float32)) for _, _, d in held_out_tokens])
    assert np.mean(own) - np.mean(flat) >= GUARD_SOURCE_OVER_FLAT_DB
    assert np.mean(own) - np.mean(swapped) >= HEALTH_THRESHOLDS["swap_drop_min_db"]
    assert slot_spread(z_s) >= HEALTH_THRESHOLDS["spread_min"]
    assert slot_spread(z_d) >= HEALTH_THRESHOLDS["spread_min"]


# Renders at other cameras must use the target pose, not repeat the source view (vt4d-tiny 0.5.0's grid
# locality bias did: on these four scenes its renders at the 9 other cameras were 35.1 dB from its
# source-view render and beat pasting that render by only 0.35 dB; 0.6.0, whose renderer projects the
# anchored tokens into the target camera: 21.4 dB and +2.34 dB; 0.7.0: 20.4 dB and +2.58 dB; 0.8.0: 19.8 dB
# and +2.66 dB; 0.9.0: 19.2 dB and +2.80 dB; 0.10.0: 19.0 dB and +2.97 dB; 0.11.0: 19.0 dB and +3.14 dB;
# 0.12.0: 19.0 dB and +3.18 dB; 0.13.0: 18.8 dB and +3.22 dB; 1.0.0: 19.0 dB and +3.14 dB).
GUARD_RENDER_VS_SOURCE_RENDER_MAX_DB = 28.0
GUARD_POSE_GAIN_MIN_DB = 1.5


def test_shipped_renders_follow_the_target_camera(held_out_tokens):
    same, gain = [], []
    for cap, cam, decoder in held_out_tokens:
        source = decoder.render("source")
        for other in cap.camera_names:
            if other == cam:
                continue
            render, truth = decoder.render(cap.cameras[other]), cap.frames[other]
            same.append(psnr(render, source))
            gain.append(psnr(render, truth) - psnr(source, truth))
    assert np.mean(same) <= GUARD_RENDER_VS_SOURCE_RENDER_MAX_DB
    assert np.mean(gain) >= GUARD_POSE_GAIN_MIN_DB


# Several encoded cameras: each places its share of the static tokens (config anchor_views). 0.6.0 placed
# every token with the first camera, so the other encoded cameras rendered as novel views (20.6 dB on the
# 50-scene multi-enc set, no better than held-out cameras). On two of these scenes, five cameras encoded,
# the five rendered from the stored bytes: vt4d-tiny 1.0.0 25.70 dB with every encoded camera placing its
# tokens, 20.09 dB with the same tokens placed by the first camera alone (+5.61 dB; 0.13.0: 26.24 / 19.56,
# +6.68, every camera gains: +4.82 .. +11.08; 0.12.0: 26.27 / 19.55, +6.72; 0.11.0: 25.60 / 19.60, +6.00; 0.10.0: 25.75 / 19.32, +6.43; 0.9.0: 25.12 / 20.36, +4.76;
# 0.8.0: 21.97 / 20.23, +1.73; 0.7.0: 21.92 / 20.17, +1.74; the test's own computation).
GUARD_MULTI_OVER_FIRST_ONLY_DB = 5.0


def test_shipped_multi_camera_encode_places_tokens_in_every_encoded_camera(held_out_tokens):
    import dataclasses

    gain = []
    for cap, _, _ in held_out_tokens[:2]:
        encoded = cap.camera_names[0::2]
        scene = vt4dcodec.format.loads(vt4dcodec.format.dumps(codec.encode(cap, "vt4d-tiny", cameras=encoded)))
        assert len(scene.extra_cameras) == len(encoded) - 1
        every = codec.SceneDecoder.open(scene)
        first_only = codec.SceneDecoder(scene=dataclasses.replace(scene, extra_cameras=()), model=every.model)
        for name in encoded:
            truth = cap.frames[name]
            gain.append(psnr(every.render(f"camera:{name}"), truth) - psnr(first_only.render(cap.cameras[name]), truth))
    assert np.mean(gain) >= GUARD_MULTI_OVER_FIRST_ONLY_DB


# Four encoded cameras: with token i in camera i mod 4 and cell i mod 64 each camera's 80 tokens sat on the
# same 16 cells, so the real 4-camera caliscope encode rendered each camera as a 4x4 mosaic (vt4d-tiny
# 0.10.0: 17.28 / 13.86 / 17.30 / 14.52 dB). spread_views gives each camera 64 distinct cells. vt4d-tiny
# 1.0.0 on two held-out 8-camera scenes, cameras 0, 2, 4, 6 encoded (default encoding), the four rendered:
# 25.82 dB, 23.01 dB with the same weights in the old layout (+2.81 dB; 0.13.0: 26.37 / 23.65, +2.72; 0.12.0: 26.53 / 23.93, +2.60; 0.11.0: 26.16 / 23.87, +2.29; the
# test's own computation).
GUARD_SPREAD_OVER_PLAIN_DB = 1.5


def test_shipped_four_camera_encode_gives_each_camera_distinct_cells():
    from vt4dcodec.model.train.ship import reconfigure

    model = codec.load_model("vt4d-tiny")
    assert model.config.spread_views
    plain = reconfigure(model, {"spread_views": False})
    spread, same_cells = [], []
    for seed in range(2):
        cap = generate_scene(seed, split="test", config=SynthConfig(num_cameras=8)).capture
        encoded = cap.camera_names[0::2]
        for net, scores in ((model, spread), (plain, same_cells)):
            decoder = codec.SceneDecoder(scene=codec.encode(cap, net, cameras=encoded), model=net)
            scores.extend(psnr(decoder.render(cap.cameras[name]), cap.frames[name]) for name in encoded)
    assert np.mean(spread) - np.mean(same_cells) >= GUARD_SPREAD_OVER_PLAIN_DB


def test_demo_runs_twice_into_the_same_directory_and_guards_foreign_captures(tmp_path):
    """The README's first command must work when run twice; a capture the demo did not write is never
    replaced without --overwrite, and the error names that flag."""
    out = tmp_path / "demo"
    for _ in range(2):
        r = vt4d("demo", "-o", out, "--json")
        assert r.returncode == 0, r.stderr
    assert json.loads((out / "demo_report.json").read_text())["scene_bytes"] > 0
    (out / "demo_report.json").unlink()  # now the capture there is nobody's the demo knows
    r = vt4d("demo", "-o", out)
    assert r.returncode == 1 and "--overwrite" in r.stderr
    r = vt4d("demo", "-o", out, "--overwrite")
    assert r.returncode == 0, r.stderr


# The shipped prior on three held-out 10-camera scenes, as `vt4d generate` is used by default: camera 0's video, the
# anchor at camera 0, one sample (the recorded sampler, seed 0) rendered at all 10 cameras, scored between a flat
# image of the video's mean colour and the tokenizer's own encode of the video. Guards below the level reached,
# by this test's own computation (the 64-event measurement is docs/co4dgen.md's): co4dgen-tiny 1.2.0 closes
# 1.015 / 0.880 / 0.996 of the gap with own-view SSIM 0.002 / 0.004 / 0.001 below the encode's (issue 50 asks 0.7 and
# within 0.1); the prior shipped before it, 1.0.0 (its recorded one-step sampler), fails both on all three:
# -0.11 / -0.27 / 0.47 of the gap, own-view SSIM 0.33 / 0.27 / 0.44 below the encode's.
GUARD_PRIOR_GAP_CLOSED = 0.8
GUARD_PRIOR_OWN_SSIM_BELOW_ENCODE = 0.05


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_shipped_prior_draws_the_scene(seed):
    from vt4dcodec.generate import generate
    from vt4dcodec.model.diagnostics import video_quality

    capture = generate_scene(seed, split="test", config=SynthConfig(num_cameras=10)).capture
    names = capture.camera_names
    cam = names[0]
    sample = codec.SceneDecoder.open(generate(capture.frames[cam], capture.cameras[cam], "source", seed=0))
    encode = codec.SceneDecoder.open(codec.encode(capture, "vt4d-tiny", camera=cam))
    specs = [capture.cameras[n] for n in names]
    got, ceiling = sample.render_many(specs, seed=0), encode.render_many(specs, seed=0)
    truth = [capture.frames[n][: got[0].shape[0]] for n in names]
    flat = capture.frames[cam][: got[0].shape[0]].reshape(-1, 3).mean(0).round().astype(np.uint8)

    def mean_psnr(videos):
        return float(np.mean([video_quality(v, t)[0] for v, t in zip(videos, truth)]))

    floor_db = mean_psnr([np.broadcast_to(flat, t.shape) for t in truth])
    closed = (mean_psnr(got) - floor_db) / (mean_psnr(ceiling) - floor_db)
    own, own_encode = video_quality(got[0], truth[0])[1], video_quality(ceiling[0], truth[0])[1]
    print(f"seed {seed}: gap closed {closed:.3f}, own-view SSIM {own:.3f} vs encode {own_encode:.3f}")
    assert closed >= GUARD_PRIOR_GAP_CLOSED
    assert own >= own_encode - GUARD_PRIOR_OWN_SSIM_BELOW_ENCODE
