"""Long commands show progress on a terminal (stderr), none off a terminal or with -q.

The commands run under a pseudo-terminal, as in a shell."""

from __future__ import annotations

import fcntl
import os
import pty
import struct
import subprocess
import sys
import termios

from cli_helpers import ROOT

import vt4dcodec.cli as cli


def _on_a_terminal(*args, timeout=300) -> tuple[int, str, str]:
    """Run `vt4d ARGS` with stderr on a pseudo-terminal; returns (exit code, stdout, terminal output)."""
    leader, follower = pty.openpty()
    fcntl.ioctl(follower, termios.TIOCSWINSZ, struct.pack("HHHH", 24, 100, 0, 0))  # 24 x 100, like a window
    env = {**os.environ, "OMP_NUM_THREADS": "1", "PYTHONPATH": str(ROOT), "COLUMNS": "100"}
    proc = subprocess.Popen([sys.executable, "-m", "vt4dcodec", *map(str, args)], stdout=subprocess.PIPE,
                            stderr=follower, cwd=ROOT, env=env)
    os.close(follower)
    chunks = []
    while True:
        try:
            data = os.read(leader, 4096)
        except OSError:  # EIO: the child closed the terminal
            break
        if not data:
            break
        chunks.append(data)
    out = proc.stdout.read().decode()
    code = proc.wait(timeout=timeout)
    os.close(leader)
    return code, out, b"".join(chunks).decode(errors="replace")


def test_decode_and_encode_show_progress_on_a_terminal_only(small_model, capture_dir, tmp_path):
    code, _, tty = _on_a_terminal("encode", capture_dir, "--model", small_model, "-o", tmp_path / "s.vt4d")
    assert code == 0, tty
    assert "loading" in tty and "done in" in tty and "encode: 100%" in tty, tty
    code, _, tty = _on_a_terminal("decode", tmp_path / "s.vt4d", "--model", small_model, "--steps", "1",
                                  "-t", "source", "-t", "pan", "-o", tmp_path / "v")
    assert code == 0 and "decode: 100%" in tty and "2/2" in tty, tty
    code, _, tty = _on_a_terminal("decode", tmp_path / "s.vt4d", "--model", small_model, "--steps", "1",
                                  "-o", tmp_path / "v", "-q")
    assert code == 0 and tty == "", tty
    r = subprocess.run([sys.executable, "-m", "vt4dcodec", "decode", tmp_path / "s.vt4d", "--model", small_model,
                        "--steps", "1", "-o", tmp_path / "v"], capture_output=True, text=True, cwd=ROOT,
                       env={**os.environ, "OMP_NUM_THREADS": "1", "PYTHONPATH": str(ROOT)})
    assert r.returncode == 0 and "100%" not in r.stderr and "loading" not in r.stderr  # a pipe, not a terminal


def test_archive_commands_show_progress_on_a_terminal(scene_file, tmp_path):
    code, _, tty = _on_a_terminal("pack", scene_file, "-o", tmp_path / "a.vt4da")
    assert code == 0 and "pack: 100%" in tty, tty
    code, _, tty = _on_a_terminal("extract", tmp_path / "a.vt4da", "-o", tmp_path / "x")
    assert code == 0 and "extract: 100%" in tty, tty
    # repair and compact have no steps to count: a running clock, ended with the time taken
    code, _, tty = _on_a_terminal("repair", tmp_path / "a.vt4da")
    assert code == 0 and "repairing" in tty and "done in" in tty, tty
    code, _, tty = _on_a_terminal("compact", tmp_path / "a.vt4da")
    assert code == 0 and "compacting" in tty and "done in" in tty, tty
    code, _, tty = _on_a_terminal("compact", tmp_path / "a.vt4da", "-q")
    assert code == 0 and tty == "", tty


def test_working_shows_a_running_clock(monkeypatch, capsys):
    import argparse

    monkeypatch.setattr(cli, "show_progress", lambda args: True)
    with cli.working(argparse.Namespace(quiet=False), "sampling the prior", interval=0.05):
        import time

        time.sleep(0.3)
    err = capsys.readouterr().err
    assert "sampling the prior ... 0 s" in err and "sampling the prior ... done in 0." in err
