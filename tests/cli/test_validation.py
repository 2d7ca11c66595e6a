"""Every argument is checked before work starts (nothing loaded, sampled or written)."""

from __future__ import annotations

from cli_helpers import vt4d


def test_generate_rejects_a_bad_view_before_sampling(capture_dir, tmp_path):
    # --prior names a model that does not exist: each refusal below being about its own flag, not the
    # prior, proves the arguments were checked before anything was loaded (so before sampling)
    out, prior = tmp_path / "gen", ["--prior", str(tmp_path / "no_such_prior")]
    r = vt4d("generate", capture_dir, "--views", "source,spiral", "-o", out, *prior)
    assert r.returncode == 1 and "--views" in r.stderr and "spiral" in r.stderr, r.stderr
    assert not out.exists()  # the old order sampled, wrote gen/scene.vt4d, then failed
    r = vt4d("generate", capture_dir, "--anchor", "orbit:degress=20", "-o", out, *prior)
    assert r.returncode == 1 and "--anchor" in r.stderr and "degress" in r.stderr, r.stderr
    r = vt4d("generate", capture_dir, "--views", "pan:degrees=abc", "-o", out, *prior)
    assert r.returncode == 1 and "'abc' is not a number" in r.stderr, r.stderr
    r = vt4d("generate", capture_dir, "--camera", "cam99", "-o", out, *prior)
    assert r.returncode == 1 and "--camera" in r.stderr and "cam99" in r.stderr, r.stderr
    r = vt4d("generate", capture_dir, "--views", "missing_traj.json", "-o", out, *prior)
    assert r.returncode == 3 and "missing_traj.json" in r.stderr and "no_such_prior" not in r.stderr, r.stderr
    assert not out.exists()
    # and with valid arguments the same command does reach the prior (so the refusals above came first)
    r = vt4d("generate", capture_dir, "-o", out, *prior)
    assert r.returncode != 0 and "no_such_prior" in r.stderr and "--prior" in r.stderr, r.stderr
    assert not out.exists()


def test_decode_checks_trajectories_before_it_looks_for_the_model(scene_file, tmp_path):
    # scene_file names model "m", which does not exist: a trajectory error first proves the order
    r = vt4d("decode", scene_file, "-t", "source", "-t", "interpolate", "-o", tmp_path / "v")
    assert r.returncode == 1 and "interpolate" in r.stderr and "model" not in r.stderr.lower(), r.stderr
    assert not (tmp_path / "v").exists()


def test_encode_checks_outputs_and_camera_before_the_model_loads(capture_dir, tmp_path):
    r = vt4d("encode", capture_dir, "--camera", "cam99", "--model", "no-such-model", "-o", tmp_path / "x.vt4d")
    assert r.returncode == 1 and "--camera" in r.stderr and "cam99" in r.stderr, r.stderr
    r = vt4d("encode", capture_dir, "-o", tmp_path / "x.vt4d", "--archive", tmp_path / "a.vt4da",
             "--model", "no-such-model")
    assert r.returncode == 1 and "not both" in r.stderr, r.stderr
    r = vt4d("encode", capture_dir, "--model", "no-such-model")
    assert r.returncode == 1 and "-o FILE.vt4d" in r.stderr, r.stderr
    assert not list(tmp_path.iterdir())


def test_pack_checks_every_key_before_it_creates_the_archive(scene_file, tmp_path):
    bad = tmp_path / "-bad.vt4d"  # a key must start with a letter, digit or '_'
    bad.write_bytes(scene_file.read_bytes())
    r = vt4d("pack", scene_file, bad, "-o", tmp_path / "a.vt4da")
    assert r.returncode == 1 and "-bad" in r.stderr, r.stderr
    assert not (tmp_path / "a.vt4da").exists()
