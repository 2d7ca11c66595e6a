"""The core install reads and writes scenes and archives with torch absent.

Run by .ci/run in a fresh venv holding `pip install .` alone (numpy, msgpack, zstandard, filelock), and by
tests/cli/test_packaging.py in the test interpreter with the codec's packages made unimportable.  Exits
non-zero, with the reason, if anything fails.
"""

import json
import os
import sys
import tempfile
from contextlib import redirect_stdout
from io import StringIO

import numpy as np

import vt4dcodec
from vt4dcodec import ArchiveWriter, ModelFingerprint, Scene, load, open_archive, open_scene, save, verify_archive
from vt4dcodec.cameras import Trajectory
from vt4dcodec.cli import main

CODEC_ONLY = ("torch", "kornia", "cv2", "safetensors", "skimage", "matplotlib")


def run(argv: list[str]) -> str:
    out = StringIO()
    with redirect_stdout(out):
        code = main(argv)
    assert code == 0, (argv, code)
    return out.getvalue()


def check(folder: str) -> None:
    fp = ModelFingerprint("m", "1", "a" * 64, "b" * 64, (4, 8), (2, 8))
    cams = Trajectory(np.array([[9.0, 0, 2], [0, 9.0, 2], [0, 0, 1]]), np.tile(np.eye(4), (3, 1, 1)), 4, 4)
    rng = np.random.default_rng(0)
    scene = Scene(rng.normal(size=(4, 8)).astype(np.float32), rng.normal(size=(2, 8)).astype(np.float32), cams, fp,
                  encoding="int4-rans")
    path = os.path.join(folder, "a.vt4d")
    save(scene, path)
    back = load(path)
    assert back.encoding == "int4-rans" and back.static_tokens.shape == (4, 8), back
    assert open_scene(path).summary()["frames"] == 3
    archive = os.path.join(folder, "a.vt4da")
    with ArchiveWriter(archive) as w:
        w.append("cap-1/cam00/000000", open(path, "rb").read())
        w.commit()
    verify_archive(archive)
    with open_archive(archive) as ar:
        assert ar.keys() == ["cap-1/cam00/000000"] and ar.load("cap-1/cam00/000000").encoding == "int4-rans"
    # the torch-free commands, through the command line's own entry point
    assert json.loads(run(["info", path, "--json"]))["encoding"] == "int4-rans"
    run(["verify", path, archive, "-q"])
    run(["extract", archive, "-o", os.path.join(folder, "out"), "-q"])
    run(["pack", os.path.join(folder, "out"), "-o", os.path.join(folder, "b.vt4da"), "-q"])
    assert [e["key"] for e in json.loads(run(["ls", os.path.join(folder, "b.vt4da"), "--json"]))["entries"]] == [
        "cap-1/cam00/000000"]
    # a learned-rans file (format 1.6) whose model is not installed: verified, its level read, tokens refused
    learned = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "spec", "vectors", "valid",
                           "learned_rans_one_camera.vt4d")
    scene = vt4dcodec.open_scene(learned)
    scene.verify()
    assert scene.quality == 1 and json.loads(run(["info", learned, "--json"]))["quality"] == 1
    try:
        scene.static_tokens()
        raise AssertionError("learned-rans tokens decoded without their model's tables")
    except vt4dcodec.EntropyTablesError:
        pass
    loaded = sorted(m for m in sys.modules if m.split(".")[0] in CODEC_ONLY)
    assert not loaded, f"the core imported {loaded}"


if __name__ == "__main__":
    with tempfile.TemporaryDirectory() as tmp:
        check(tmp)
    print(f"core install OK: vt4dcodec {vt4dcodec.__version__} read and wrote a scene and an archive without torch")
