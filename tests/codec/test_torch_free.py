"""The codec without torch (issue 51): with torch, kornia, safetensors and onnx unimportable -- as after
``pip install ".[codec]"`` -- the demo, encoding every camera of a capture, decoding and ``vt4d info`` run on the
exported graphs, generation runs on the prior's exported graphs, no torch module is ever loaded, and what needs
torch (--runtime torch, a prior without graphs) says which extra to install. The install itself (a fresh venv, its size and time) is checked by .ci/run."""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap

import pytest

BLOCK = textwrap.dedent("""
    import importlib.abc, sys
    BLOCKED = {"torch", "kornia", "safetensors", "onnx", "torchvision", "triton", "matplotlib"}

    class NotInstalled(importlib.abc.MetaPathFinder):  # as if the train extra were not installed
        def find_spec(self, name, path=None, target=None):
            if name.split(".")[0] in BLOCKED:
                raise ModuleNotFoundError(f"No module named {name!r}", name=name)
            return None

    sys.meta_path.insert(0, NotInstalled())
""")


def run_without_torch(body: str, tmp_path) -> subprocess.CompletedProcess:
    script = BLOCK + textwrap.dedent(body) + textwrap.dedent("""
        loaded = sorted(m for m in sys.modules if m.split(".")[0] in BLOCKED)
        assert not loaded, loaded[:5]
        print("clean")
    """)
    return subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=600, cwd=tmp_path)


def test_demo_encode_all_cameras_decode_and_info_run_without_torch(tmp_path):
    run = run_without_torch("""
        from vt4dcodec.cli import main
        assert main(["synth", "-n", "1", "--split", "test", "-o", "caps", "--workers", "1"]) == 0
        import pathlib
        cap = str(next(p for p in pathlib.Path("caps").iterdir() if p.is_dir()))
        assert main(["encode", cap, "--cameras", "all", "-o", "all.vt4d"]) == 0
        assert main(["encode", cap, "-o", "one.vt4d", "--device", "auto"]) == 0
        assert main(["decode", "all.vt4d", "-t", "source", "-t", "camera:cam05", "-t", "orbit:degrees=20",
                     "-o", "views", "--format", "npz", "--device", "cpu"]) == 0
        assert main(["decode", "one.vt4d", "-o", "one.mp4"]) == 0
        assert main(["info", "all.vt4d"]) == 0
        assert main(["demo", "-o", "demo_out", "--json"]) == 0
        assert main(["generate", cap, "-o", "gen", "--steps", "2", "--views", "source,orbit:degrees=10"]) == 0
        assert main(["decode", "one.vt4d", "-o", "t.mp4", "--runtime", "torch"]) == 1  # names the extra
    """, tmp_path)
    assert run.returncode == 0, run.stderr[-3000:]
    assert "clean" in run.stdout
    assert run.stderr.count('pip install -e ".[train]"') == 1, run.stderr[-2000:]
    assert len(list((tmp_path / "gen").glob("view_*.mp4"))) == 2 and (tmp_path / "gen" / "scene.vt4d").is_file()
    assert "Traceback" not in run.stderr
    report = json.loads((tmp_path / "demo_out" / "demo_report.json").read_text())
    assert report["views"] and all(v["psnr_db"] > v["flat_mean_colour_psnr_db"] for v in report["views"].values()
                                   if v["kind"] == "source")
    assert len(list((tmp_path / "views").glob("*.npz"))) == 3 and (tmp_path / "one.mp4").is_file()


def test_the_api_without_torch_names_the_train_extra(tmp_path):
    import shutil

    from vt4dcodec.model.directories import PRIOR_META_FILE, model_directory

    shutil.copytree(model_directory("co4dgen-tiny", PRIOR_META_FILE), tmp_path / "bare-prior",
                    ignore=shutil.ignore_patterns("*.onnx"))  # a prior exported before its graphs were
    run = run_without_torch("""
        import numpy as np
        from vt4dcodec import codec, generate
        from vt4dcodec.errors import MissingExtraError
        from vt4dcodec.generate import load_prior_model
        assert not codec.torch_available()
        print(type(load_prior_model()).__name__)
        for call in (lambda: codec.load_model("vt4d-tiny"), lambda: codec.load_encoder("vt4d-tiny", "torch"),
                     lambda: codec.load_encoder("vt4d-tiny", cameras=11), lambda: load_prior_model("bare-prior"),
                     lambda: load_prior_model(runtime="torch")):
            try:
                call()
            except MissingExtraError as exc:
                assert '.[train]' in str(exc), exc
            else:
                raise AssertionError("no MissingExtraError")
        print(type(codec.load_renderer("vt4d-tiny")).__name__)
    """, tmp_path)
    assert run.returncode == 0, run.stderr[-3000:]
    assert "OnnxRenderer" in run.stdout and "OnnxPrior" in run.stdout and "clean" in run.stdout


@pytest.mark.parametrize("extra", ["codec", "train"])
def test_pyproject_extras_keep_torch_out_of_the_codec(extra):
    import tomllib
    from pathlib import Path

    meta = tomllib.loads((Path(__file__).parents[2] / "pyproject.toml").read_text())["project"]
    extras = meta["optional-dependencies"]
    names = {d.split(">")[0].split("[")[0].split("=")[0].strip() for d in extras[extra]}
    if extra == "codec":
        assert not names & {"torch", "kornia", "safetensors", "onnx"} and "onnxruntime" in names
    else:
        assert {"torch", "kornia", "safetensors", "onnx"} <= names and "vt4dcodec[codec]" in extras[extra]
        assert "vt4dcodec[train]" in extras["test"]
