"""The codec install runs the codec with torch absent (issue 51).

Run by .ci/run in a fresh venv holding `pip install -e ".[codec]"` alone: torch must not be installed, and the
demo, encoding every camera of a capture, decoding, `vt4d info` and generation must run (on the exported ONNX
graphs) without importing it. Exits non-zero, with the reason, if anything fails.
"""

import importlib.util
import os
import sys
import tempfile
from pathlib import Path

from vt4dcodec.cli import main

TRAIN_ONLY = ("torch", "kornia", "safetensors", "onnx", "matplotlib")


def run(argv: list[str]) -> None:
    code = main(argv)
    assert code == 0, (argv, code)


def check() -> None:
    installed = [name for name in TRAIN_ONLY if importlib.util.find_spec(name) is not None]
    assert not installed, f"the codec extra installed {installed}: they belong to the train extra"
    with tempfile.TemporaryDirectory() as tmp:
        os.chdir(tmp)
        run(["synth", "-n", "1", "--split", "test", "-o", "caps", "--workers", "1", "-q"])
        capture = str(next(p for p in Path("caps").iterdir() if p.is_dir()))
        run(["encode", capture, "--cameras", "all", "-o", "all.vt4d", "-q"])
        run(["decode", "all.vt4d", "-t", "source", "-t", "camera:cam05", "-o", "views", "-q"])
        run(["info", "all.vt4d"])
        from vt4dcodec import codec, open_scene

        stored = open_scene("all.vt4d")
        level = codec.default_quality("vt4d-tiny")
        assert (stored.encoding, stored.quality) == (("learned-rans", level) if level else ("int4", None)), \
            f"the torch-free encode stored {stored.encoding} at {stored.quality}, not the model's default level {level}"
        run(["demo", "-o", "demo_out", "-q"])
        run(["generate", capture, "-o", "gen", "--steps", "2", "-q"])
        assert len(list(Path("views").glob("*.mp4"))) == 2 and Path("demo_out/demo_report.json").is_file()
    loaded = sorted(m for m in sys.modules if m.split(".")[0] in TRAIN_ONLY)
    assert not loaded, f"the codec imported {loaded[:5]}"
    print("codec install OK: no torch; demo, encode of all cameras, decode, info and generate ran")


if __name__ == "__main__":
    check()
