"""Issue 52, bounded reading: a decoded-size budget (FORMAT.md I.7) for `load`, `open_scene`, `verify` and archive
reads.  The 16.9 KB bomb (two zstd sections of zeros within the limits, 1 GiB decoded) made `load()` peak at
1,072 MB and `vt4d verify` at 1.10 GB; now it is refused under 100 MB, and no bomb within the default budget
makes a reader exceed 300 MB.  Peak memory is measured in a fresh interpreter (its peak resident set, VmHWM, as
``ru_maxrss`` counts it), the memory the operating system saw, not tracemalloc's view of Python allocations."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from bombs import camera_bomb, rows_within, the_issue_bomb, token_bomb
from format_strategies import camera, rig_scene, simple_scene
from vt4dcodec.archive import ArchiveWriter, open_archive, verify_archive
from vt4dcodec.errors import LimitExceededError
from vt4dcodec.format import Scene, dumps, load, loads, open_scene, verify
from vt4dcodec.format.sections import DECODED_CAMERA_BYTES_PER_FRAME, DEFAULT_MAX_DECODED_BYTES

MB = 1 << 20

# One reading operation in a fresh interpreter; prints {"peak": peak RSS bytes, "error": class or null}.
PROBE = r"""
import json, resource, sys
mode, path = sys.argv[1], sys.argv[2]
from vt4dcodec.archive import open_archive, verify_archive
from vt4dcodec.cli import main
from vt4dcodec.format import load, open_scene, verify
error = None
try:
    if mode == "load":
        load(path)
    elif mode == "verify":
        verify(path)
    elif mode == "open_scene":
        f = open_scene(path)
        f.tokens(), f.cameras, f.extra_cameras
    elif mode == "archive_load":
        with open_archive(path) as reader:
            reader.load("bomb")
    elif mode == "archive_verify":
        verify_archive(path)
    elif mode == "cli_verify":
        error = None if main(["verify", path]) == 0 else "exit status"
except Exception as exc:
    error = type(exc).__name__
try:  # this interpreter's own high-water mark: ru_maxrss would also count the forked pytest process's
    with open("/proc/self/status") as status:
        peak = next(int(line.split()[1]) for line in status if line.startswith("VmHWM:")) * 1024
except OSError:
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
print(json.dumps({"peak": peak, "error": error}))
"""


def _probe(mode: str, path) -> tuple[int, str | None]:
    out = subprocess.run([sys.executable, "-c", PROBE, mode, str(path)], capture_output=True, text=True,
                         timeout=300, check=True)
    result = json.loads(out.stdout.strip().splitlines()[-1])
    return result["peak"], result["error"]


def _archive_of(tmp_path, payload: bytes):
    path = tmp_path / "bomb.vt4da"
    with ArchiveWriter(path, "x", durable=False) as writer:
        writer.append("bomb", payload, validate=False)
    return path


def test_the_issue_bomb_is_a_small_valid_file_that_decodes_to_a_gigabyte():
    data = the_issue_bomb()
    assert len(data) < 17_500  # the issue's 16.9 KB
    f = open_scene(data)  # header and table are valid: shapes and raw lengths within every limit
    assert f.encoding == "float32" and f.static_shape == f.dynamic_shape == (1 << 16, 1 << 10)
    assert sum(e.raw_length for e in f.sections) > 512 * MB
    with pytest.raises(LimitExceededError, match="max_decoded_bytes"):
        f.tokens()


@pytest.mark.parametrize("mode", ["load", "verify", "open_scene", "cli_verify"])
def test_the_issue_bomb_is_refused_under_100_mb(tmp_path, mode):
    path = tmp_path / "bomb.vt4d"
    path.write_bytes(the_issue_bomb())
    peak, error = _probe(mode, path)
    assert error == ("exit status" if mode == "cli_verify" else "LimitExceededError")
    assert peak < 100 * MB, peak / MB


@pytest.mark.parametrize("mode", ["archive_load", "archive_verify"])
def test_the_issue_bomb_as_an_archive_record_is_refused_under_100_mb(tmp_path, mode):
    peak, error = _probe(mode, _archive_of(tmp_path, the_issue_bomb()))
    assert error == "LimitExceededError"
    assert peak < 100 * MB, peak / MB


@pytest.mark.parametrize("encoding", ["float32", "float16", "int8", "int4"])
def test_bombs_just_within_the_default_budget_stay_under_300_mb(tmp_path, encoding):
    """The worst a small file can do within the budget: every byte it may decode is decoded (zeros are valid
    tokens), and the reader's own copies and temporaries come on top.  Done-when of issue 52: no input under
    100 KB makes any reader exceed 300 MB."""
    data = token_bomb(encoding, rows_within(encoding, DEFAULT_MAX_DECODED_BYTES))
    assert len(data) < 100_000
    path = tmp_path / "near.vt4d"
    path.write_bytes(data)
    for mode in ("load", "verify"):
        peak, error = _probe(mode, path)
        assert error is None, (mode, error)  # within the budget the scene is read
        assert peak < 300 * MB, (mode, peak / MB)
    peak, error = _probe("archive_load", _archive_of(tmp_path, data))
    assert error is None and peak < 300 * MB, (error, peak / MB)


def test_a_camera_bomb_within_the_limits_stays_under_300_mb(tmp_path):
    """65,536 frames of one pose (13 MB of float64) in a 2 KB file: within the budget, read and bounded."""
    data = camera_bomb()
    assert len(data) < 4096
    path = tmp_path / "cams.vt4d"
    path.write_bytes(data)
    peak, error = _probe("load", path)
    assert error is None and peak < 300 * MB, (error, peak / MB)


def test_the_budget_is_raisable_and_none_reads_anything():
    data = dumps(simple_scene(ns=64, nd=32, d=16, frames=4, encoding="int8"))
    f = open_scene(data)
    size = f._decoded_bytes
    assert size == (sum(e.raw_length for e in f.sections) + 4 * (64 + 32) * 16
                    + DECODED_CAMERA_BYTES_PER_FRAME * 4)
    for reader in (load, verify, lambda d, **kw: open_scene(d, **kw).tokens(), loads):
        with pytest.raises(LimitExceededError, match=f"max_decoded_bytes={size}"):
            reader(data, max_decoded_bytes=size - 1)
        reader(data, max_decoded_bytes=size)
        reader(data, max_decoded_bytes=None)
    # refused before any section is touched: the lazy parts (header, shapes, summary) still read
    small = open_scene(data, max_decoded_bytes=0)
    assert small.summary()["static_shape"] == [64, 16]
    with pytest.raises(LimitExceededError):
        small.cameras


@pytest.mark.parametrize("bad", [-1, 1.5, "64", True])
def test_the_budget_must_be_a_non_negative_int_or_none(bad):
    with pytest.raises(ValueError, match="max_decoded_bytes"):
        open_scene(dumps(simple_scene()), max_decoded_bytes=bad)


def test_extra_cameras_count_once_xcam_says_how_many():
    """A rig of 63 static extra cameras stores each in a few bytes and decodes each to 208 B a frame: the
    budget is checked again with XCAM's count before any record is decoded."""
    frames = 256
    base = simple_scene(frames=frames)
    rig = Scene(base.static_tokens, base.dynamic_tokens, base.cameras, base.fingerprint,
                extra_cameras=[camera(np.random.default_rng(0), frames, static=True)] * 63)
    data = dumps(rig)
    assert len(data) < 4096
    f = open_scene(data)
    extras = 63 * DECODED_CAMERA_BYTES_PER_FRAME * frames
    budget = f._decoded_bytes + extras - 1
    g = open_scene(data, max_decoded_bytes=budget)
    assert g.cameras.num_frames == frames  # the first camera fits
    with pytest.raises(LimitExceededError, match="max_decoded_bytes"):
        g.extra_cameras
    with pytest.raises(LimitExceededError):
        g.extra_camera(0)
    assert len(open_scene(data, max_decoded_bytes=budget + 1).extra_cameras) == 63
    assert len(loads(data, max_decoded_bytes=budget + 1).extra_cameras) == 63


def test_every_scene_of_the_test_suites_builders_fits_the_default_budget_with_a_large_margin():
    """The default is ~80 times a paper-size float32 scene (1,024 + 512 tokens of 64 values, 32 frames)."""
    paper = open_scene(dumps(simple_scene(ns=1024, nd=512, d=64, frames=32), compression_level=None))
    assert paper._decoded_bytes * 80 < DEFAULT_MAX_DECODED_BYTES
    rig = rig_scene(3, frames=32, encoding="int8")
    assert open_scene(dumps(rig))._decoded_bytes * 1000 < DEFAULT_MAX_DECODED_BYTES


def test_archive_reads_take_the_budget(tmp_path):
    data = dumps(simple_scene(ns=64, nd=32, d=16, encoding="int8"))
    size = open_scene(data)._decoded_bytes
    path = tmp_path / "a.vt4da"
    with ArchiveWriter(path, "x", durable=False) as writer:
        writer.append("s", data)
        with pytest.raises(LimitExceededError):  # a validated append verifies within the budget too
            writer.append("t", data, max_decoded_bytes=size - 1)
    with open_archive(path, max_decoded_bytes=size - 1) as reader:
        with pytest.raises(LimitExceededError):
            reader.load("s")
        with pytest.raises(LimitExceededError):
            reader.open_scene("s").tokens()
        reader.max_decoded_bytes = size  # raised later
        reader.load("s")
    with pytest.raises(LimitExceededError):
        verify_archive(path, max_decoded_bytes=size - 1)
    verify_archive(path, max_decoded_bytes=size)
    verify_archive(path)
