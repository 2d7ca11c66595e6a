"""SIGKILL a writer subprocess at random moments; nothing committed is ever lost.

Each round starts a writer (which recovers or discards what the killed one left), waits for it to
be ready, lets it append and commit for a random 0-120 ms, and kills it with SIGKILL; one round in
four kills blindly 50-800 ms after the start, which also lands inside a writer's open/recovery.  The writer
prints every key after its commit() returns; after each kill every such key must read back exactly,
first without any repair (the archive is readable at its last commit), and in the end after
`repair`.  Default run: 20 kills; `pytest -m slow`: 200 kills.
"""

import os
import random
import signal
import subprocess
import sys
import threading
import time

import pytest

from vt4dcodec.archive import ArchiveWriter, open_archive, repair_archive, verify_archive
from vt4dcodec.errors import ArchiveLockedError

from .helpers import payload_for

WRITER = os.path.join(os.path.dirname(__file__), "crash_writer.py")


def _start(path, seed, *extra):
    return subprocess.Popen([sys.executable, WRITER, str(path), str(seed), *map(str, extra)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def _check(path, committed: set[str]) -> int:
    with open_archive(path) as ar:
        keys = set(ar.keys())
        missing = committed - keys
        assert not missing, f"committed scenes lost: {sorted(missing)[:5]}"
        for key, data in ar.iter_records():
            assert data == payload_for(key), key
        return len(keys)


def _kill_loop(tmp_path, kills: int, seed: int):
    path = tmp_path / "crash.vt4da"
    ArchiveWriter(path).close()
    rng = random.Random(seed)
    committed: set[str] = set()
    killed_mid_write = 0
    for round_ in range(kills):
        proc = _start(path, seed * 100000 + round_)
        if rng.random() < 0.25:  # blind kill: may land in start-up or in the open/recovery commit
            time.sleep(rng.uniform(0.05, 0.8))
        else:
            assert proc.stdout.readline().strip() == "ready", proc.stderr.read()
            time.sleep(rng.uniform(0, 0.12))
        proc.send_signal(signal.SIGKILL)
        out, err = proc.communicate()
        assert proc.returncode in (-signal.SIGKILL, 0), err
        for line in out.splitlines(keepends=True):
            if line.startswith("C ") and line.endswith("\n"):
                committed.update(line.split()[1:])
        with open_archive(path) as ar:
            killed_mid_write += bool(ar.uncommitted_bytes)
        _check(path, committed)  # no repair needed to read the last commit
        if round_ % 5 == 4:
            repair_archive(str(path))
            _check(path, committed)
    repair_archive(str(path))
    verify_archive(str(path), records=False)
    n = _check(path, committed)
    assert len(committed) > kills // 2, "the writer barely committed anything; the test proves little"
    return n, killed_mid_write


def test_sigkill_20_times_loses_nothing_committed(tmp_path):
    _kill_loop(tmp_path, 20, seed=1)


@pytest.mark.slow
def test_sigkill_200_times_loses_nothing_committed(tmp_path):
    _, mid_write = _kill_loop(tmp_path, 200, seed=2)
    assert mid_write > 20  # many kills really landed between an append and its commit


def test_second_writer_gets_a_clear_lock_error(tmp_path):
    path = tmp_path / "l.vt4da"
    with ArchiveWriter(path):
        with pytest.raises(ArchiveLockedError, match=f"pid {os.getpid()}"):
            ArchiveWriter(path)
    with ArchiveWriter(path):  # released on close
        pass


def test_readers_see_committed_states_while_a_writer_appends(tmp_path):
    path = tmp_path / "c.vt4da"
    ArchiveWriter(path).close()
    proc = _start(path, 7, 150, 0.003)  # >= 0.45 s of commits even where fsync is nearly free
    assert proc.stdout.readline().strip() == "ready"
    lines: list[str] = []
    pump = threading.Thread(target=lambda: lines.extend(proc.stdout), daemon=True)
    pump.start()
    seen, opens, via_slot = 0, 0, 0
    while proc.poll() is None or opens == 0:
        committed_before = {k for line in list(lines) for k in line.split()[1:]}
        with open_archive(path) as ar:
            keys = ar.keys()
            via_slot += not ar.committed_at_tail
            for key, data in ar.iter_records():
                assert data == payload_for(key)
        assert committed_before <= set(keys)  # everything reported committed is visible
        assert len(keys) >= seen  # commits only grow
        seen, opens = len(keys), opens + 1
    pump.join()
    assert proc.returncode == 0, proc.stderr.read()
    assert opens > 3
    _check(path, {k for line in lines for k in line.split()[1:]})
