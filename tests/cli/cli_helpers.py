"""Helpers of the command-line tests: the `vt4d` command run as a new user runs it (a subprocess), a
torch-free scene, and a small random model saved as a model directory.

The CLI's contract (flags, messages, exit codes, JSON, round trips) does not depend on trained weights,
so the codec commands here run a reduced random model; the shipped weights are exercised in
tests/codec/test_shipped.py.
"""

from __future__ import annotations

import contextlib
import json
import os
import subprocess
import sys
import threading
from functools import partial
from http.server import SimpleHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from types import SimpleNamespace
from typing import Iterator

import numpy as np

from vt4dcodec import ModelFingerprint, Provenance, Scene
from vt4dcodec.cameras import Trajectory

ROOT = Path(__file__).resolve().parents[2]


def vt4d(*args, cwd=None, env=None, timeout=300) -> subprocess.CompletedProcess:
    """Run `python -m vt4dcodec ARGS` from the repository root (so this tree's vt4dcodec is imported)."""
    full_env = {**os.environ, "OMP_NUM_THREADS": "1", "PYTHONPATH": str(ROOT), **(env or {})}
    return subprocess.run([sys.executable, "-m", "vt4dcodec", *map(str, args)], capture_output=True, text=True,
                          cwd=cwd or ROOT, env=full_env, timeout=timeout)


def vt4d_json(*args, **kwargs):
    r = vt4d(*args, "--json", **kwargs)
    assert r.returncode == 0, r.stderr
    return json.loads(r.stdout)


def make_scene(*, kind: str | None = None, capture: str | None = None, metadata=None) -> Scene:
    fp = ModelFingerprint("m", "1", "a" * 64, "b" * 64, (4, 8), (2, 8))
    cams = Trajectory(np.array([[9.0, 0, 2], [0, 9.0, 2], [0, 0, 1]]), np.tile(np.eye(4), (3, 1, 1)), 4, 4)
    rng = np.random.default_rng(0)
    return Scene(rng.normal(size=(4, 8)).astype(np.float32), rng.normal(size=(2, 8)).astype(np.float32), cams, fp,
                 metadata=metadata or {}, provenance=None if kind is None else Provenance.now(capture, kind))


class StandInCodec:
    """codec.encode's stand-in for tests of the command's bookkeeping (no model): a small scene per call,
    Ctrl-C (KeyboardInterrupt) at call ``interrupt_at``; ``on_call(n)`` runs at the n-th call."""

    def __init__(self, monkeypatch, interrupt_at=None, on_call=None):
        from vt4dcodec import codec

        self.calls: list[str] = []
        self.interrupt_at, self.on_call, self.loaded = interrupt_at, on_call, False
        fp = make_scene().fingerprint
        monkeypatch.setattr(codec, "load_encoder", self.load_encoder)
        monkeypatch.setattr(codec, "model_fingerprint", lambda model: fp)
        monkeypatch.setattr(codec, "encode", self.encode)

    def load_encoder(self, *args, **kwargs):
        self.loaded = True
        return SimpleNamespace(config=SimpleNamespace(frames=8))

    def encode(self, cap, model=None, encoding=None, *, start=0, **options):
        self.calls.append(cap.capture_id)
        if self.on_call is not None:
            self.on_call(len(self.calls))
        if len(self.calls) == self.interrupt_at:
            raise KeyboardInterrupt
        return make_scene(kind="encoded", metadata={**(options.get("metadata") or {}), "vt4d": {
            "source_camera": cap.camera_names[0], "clip_start": start}})


class StandInDecoder:
    """SceneDecoder's stand-in for tests of `vt4d decode`'s outputs (no model): every trajectory renders
    ``frames`` grey 16x16 frames; ``opened`` holds the scenes it was opened on."""

    def __init__(self, monkeypatch, frames: int = 3):
        import vt4dcodec.cli.codec_commands as commands

        self.frames, self.opened, self.batches = frames, [], []  # batches: the size of each render_many call
        self.model = SimpleNamespace(decode_steps=1)
        fp = make_scene().fingerprint
        monkeypatch.setattr(commands.SceneDecoder, "open", self.open)
        monkeypatch.setattr(commands, "model_fingerprint", lambda model: fp)

    def open(self, scene, **options):
        self.opened.append(scene)
        return self

    def trajectory(self, spec, capture=None):
        return make_scene().cameras

    def render(self, trajectory, **options):
        return np.full((self.frames, 16, 16, 3), 128, np.uint8)

    def render_many(self, trajectories, **options):
        self.batches.append(len(trajectories))
        return [self.render(t, **options) for t in trajectories]


SMALL = dict(width=64, heads=2, renderer_layers=1, spatial_layers=1, static_query_layers=1, track_layers=1,
             dynamic_spatial_layers=1, n_tracks=16)


def save_small_model(directory: Path, seed: int = 0) -> Path:
    """A random reduced vt4d model saved as model directory ``directory/cli-test`` (id cli-test, version 0):
    two seeds give the same id and shapes but different weights, hence different fingerprints."""
    import torch

    from vt4dcodec.model import VideoTok4D, get_config, save_pretrained

    torch.manual_seed(seed)
    return save_pretrained(VideoTok4D(get_config("tiny", **SMALL)), directory / "cli-test", model_id="cli-test",
                           model_version="0")


class _QuietHandler(SimpleHTTPRequestHandler):
    def log_message(self, *args):
        pass


@contextlib.contextmanager
def serve_folder(folder: Path) -> Iterator[str]:
    """Serve ``folder`` over HTTP on 127.0.0.1 with Python's plain file server, which ignores Range
    requests (as many servers do); yields the root URL ending in '/'."""
    server = ThreadingHTTPServer(("127.0.0.1", 0), partial(_QuietHandler, directory=str(folder)))
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        yield f"http://127.0.0.1:{server.server_address[1]}/"
    finally:
        server.shutdown()
        server.server_close()
        thread.join()
