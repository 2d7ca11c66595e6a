"""Issue 52: Ctrl-C (SIGINT) and SIGTERM during a long archive write keep every scene that had finished.

`vt4d pack` runs in a subprocess whose appends are slowed down and announced ("A key" once an append returned);
the test signals it mid-run and counts what survives: every announced scene is committed byte for byte, the
archive verifies with nothing uncommitted after its last commit, and the command says what it kept."""

import os
import signal
import subprocess
import sys

import pytest

from vt4dcodec.archive import ArchiveWriter, open_archive, verify_archive

from .helpers import scene_record

PACK = os.path.join(os.path.dirname(__file__), "pack_slowly.py")
SCENES = 60


def _inputs(tmp_path, n=SCENES, prefix="scene"):
    d = tmp_path / prefix
    d.mkdir()
    for i in range(n):
        (d / f"{prefix}-{i:03d}.vt4d").write_bytes(scene_record(i % 6))
    return d


def _default_sigint():
    """In the child before it starts: SIGINT to its default, so Python turns it into KeyboardInterrupt even where the
    tests run as a background job, whose shell ignores SIGINT for everything it starts (a child inherits that)."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def _pack_and_signal(inputs, out, sig, *extra, after=5):
    """Run `vt4d pack INPUTS -o OUT EXTRA` slowly, send ``sig`` once ``after`` appends returned; (announced keys,
    exit status, stderr)."""
    proc = subprocess.Popen([sys.executable, PACK, "0.05", "pack", str(inputs), "-o", str(out), *extra],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, preexec_fn=_default_sigint)
    announced = []
    try:
        while len(announced) < after:
            line = proc.stdout.readline()
            assert line, proc.stderr.read()
            if line.startswith("A "):
                announced.append(line.split()[1])
        proc.send_signal(sig)
        out_rest, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    announced += [line.split()[1] for line in out_rest.splitlines() if line.startswith("A ")]
    return announced, proc.returncode, err


def _survivors(out, inputs) -> list[str]:
    verify_archive(str(out))  # every record, and nothing torn or uncommitted after the last commit
    with open_archive(out) as reader:
        assert reader.uncommitted_bytes == 0
        for key, data in reader.iter_records():
            if key.startswith(inputs.name):
                assert data == (inputs / f"{key}.vt4d").read_bytes(), key
        return reader.keys()


@pytest.mark.parametrize("sig,status", [(signal.SIGINT, 130), (signal.SIGTERM, 143)])
def test_a_signal_mid_pack_keeps_every_finished_scene(tmp_path, sig, status):
    inputs = _inputs(tmp_path)
    out = tmp_path / "a.vt4da"
    announced, code, err = _pack_and_signal(inputs, out, sig)
    assert code == status, err
    kept = _survivors(out, inputs)
    assert set(announced) <= set(kept), "a scene whose append returned was lost"
    # at most the append the signal stopped between its return and its announcement is there unannounced
    assert len(set(kept) - set(announced)) <= 1
    assert 5 <= len(kept) < SCENES, "the signal did not land mid-run"
    assert kept == [f"scene-{i:03d}" for i in range(len(kept))]  # the first ones, in order
    name = signal.Signals(sig).name
    assert f"interrupted ({name})" in err and f"keeps the {len(kept)} scenes packed before it" in err, err
    assert f"{SCENES - len(kept)} inputs not packed" in err and "Traceback" not in err, err


def test_sigterm_during_pack_append_keeps_the_old_scenes_and_the_finished_new_ones(tmp_path):
    old = _inputs(tmp_path, 3, prefix="old")
    out = tmp_path / "a.vt4da"
    with ArchiveWriter(out, durable=False) as writer:
        for path in sorted(old.iterdir()):
            writer.append(path.name[:-5], path.read_bytes())
    new = _inputs(tmp_path, SCENES, prefix="new")
    announced, code, err = _pack_and_signal(new, out, signal.SIGTERM, "--append", after=4)
    assert code == 143, err
    kept = _survivors(out, new)
    assert {"old-000", "old-001", "old-002"} <= set(kept)
    assert set(announced) <= set(kept) and 4 <= len(kept) - 3 < SCENES


def test_pack_resumed_with_append_completes_the_archive(tmp_path):
    inputs = _inputs(tmp_path, 20)
    out = tmp_path / "a.vt4da"
    _, code, err = _pack_and_signal(inputs, out, signal.SIGINT, after=3)
    assert code == 130
    assert "run the command again with --append -y" in err
    # what the message advises: the same command with --append -y (replacing the scenes already there)
    done = subprocess.run([sys.executable, PACK, "0", "pack", str(inputs), "-o", str(out), "--append", "-y", "-q"],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert _survivors(out, inputs) == [f"scene-{i:03d}" for i in range(20)]


# --- the writer as a context manager, in process -------------------------------------------------
def test_keyboard_interrupt_in_a_writer_block_commits_the_finished_appends(tmp_path):
    out = tmp_path / "a.vt4da"
    with pytest.raises(KeyboardInterrupt):
        with ArchiveWriter(out, "x", durable=False) as writer:
            for i in range(3):
                writer.append(f"s{i}", scene_record(i))
            raise KeyboardInterrupt
    with open_archive(out) as reader:
        assert reader.keys() == ["s0", "s1", "s2"] and reader.uncommitted_bytes == 0


def _tear_next_append(writer, exc):
    """The next frame write stops half way and raises ``exc`` (an interrupt or error inside ``append``)."""
    def torn(data, offset):
        del writer._pwrite_all  # the class's own again, for the commit that follows
        os.pwrite(writer._handle, bytes(data)[: len(data) // 2], offset)
        raise exc
    writer._pwrite_all = torn


def test_an_interrupt_that_tears_a_frame_commits_the_appends_before_it(tmp_path):
    out = tmp_path / "a.vt4da"
    with pytest.raises(KeyboardInterrupt):
        with ArchiveWriter(out, "x", durable=False) as writer:
            writer.append("s0", scene_record(0))
            writer.append("s1", scene_record(1))
            _tear_next_append(writer, KeyboardInterrupt())
            writer.append("s2", scene_record(2))
    verify_archive(str(out))  # the torn half frame was cut off before the commit
    with open_archive(out) as reader:
        assert reader.keys() == ["s0", "s1"] and reader.uncommitted_bytes == 0


def test_an_interrupt_before_any_append_leaves_no_new_archive(tmp_path):
    out = tmp_path / "a.vt4da"
    with pytest.raises(KeyboardInterrupt):
        with ArchiveWriter(out, "x", durable=False) as writer:
            _tear_next_append(writer, KeyboardInterrupt())
            writer.append("s0", scene_record(0))
    assert not out.exists() and not os.path.exists(f"{out}.lock")


def test_an_error_that_tears_a_frame_still_aborts_and_leaves_no_torn_bytes(tmp_path):
    out = tmp_path / "a.vt4da"
    with ArchiveWriter(out, "x", durable=False) as writer:
        writer.append("s0", scene_record(0))
    with pytest.raises(OSError):
        with ArchiveWriter(out, durable=False) as writer:
            writer.append("s1", scene_record(1))
            _tear_next_append(writer, OSError("disk full"))
            writer.append("s2", scene_record(2))
    verify_archive(str(out))
    with open_archive(out) as reader:
        assert reader.keys() == ["s0"] and reader.uncommitted_bytes == 0
