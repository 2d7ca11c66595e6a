"""A hypothesis state machine drives a writer against a plain dict model.

Rules: append (new or replacing key), commit, reopen (close with/without commit), read (a fresh
reader sees exactly the committed model), and a simulated crash: the writer vanishes without
cleaning up and the file is cut at a random point after the last commit; the next writer recovers
(complete records survive) or discards.
"""

import os
import shutil
import tempfile

from hypothesis import settings, strategies as st
from hypothesis.stateful import RuleBasedStateMachine, invariant, precondition, rule

from vt4dcodec.archive import ArchiveWriter, open_archive, verify_archive

from .helpers import payload_for

KEYS = st.sampled_from([f"k{i}" for i in range(12)] + ["dir/a", "dir/b"])


class ArchiveMachine(RuleBasedStateMachine):
    def __init__(self):
        super().__init__()
        self.dir = tempfile.mkdtemp(prefix="vt4da-state-")
        self.path = os.path.join(self.dir, "s.vt4da")
        self.writer = ArchiveWriter(self.path, durable=False)
        self.committed: dict[str, bytes] = {}
        self.pending: list[tuple[str, bytes, int]] = []  # (key, bytes, end offset of its frame), in file order
        self.version = 0

    def teardown(self):
        if self.writer is not None:
            self.writer.close(commit=False)
        shutil.rmtree(self.dir, ignore_errors=True)

    @rule(key=KEYS, size=st.integers(0, 300))
    def append(self, key, size):
        self.version += 1
        data = payload_for(f"{key}-{self.version}", size)
        exists = key in self.committed or any(k == key for k, _, _ in self.pending)
        entry = self.writer.append(key, data, validate=False, replace=exists)
        self.pending.append((key, data, entry.offset + entry.length))

    @rule()
    def commit(self):
        self.writer.commit()
        self.committed.update({k: v for k, v, _ in self.pending})
        self.pending.clear()

    @rule(commit=st.booleans())
    def reopen(self, commit):
        self.writer.close(commit=commit)
        if commit:
            self.committed.update({k: v for k, v, _ in self.pending})
        self.pending.clear()
        self.writer = ArchiveWriter(self.path, durable=False)

    @precondition(lambda self: self.pending)
    @rule(cut=st.floats(0, 1), recover=st.booleans())
    def crash(self, cut, recover):
        w = self.writer
        os.close(w._fd)  # vanish: no abort, no commit, lock dropped like a dead process
        w._fd = None
        w._lock.release()
        self.writer = None
        committed_end = w._commit.end
        size = os.path.getsize(self.path)
        cut_at = committed_end + int(cut * (size - committed_end))
        os.truncate(self.path, cut_at)
        with open_archive(self.path) as ar:  # readable at the last commit without repair
            assert dict(ar.iter_records()) == self.committed
        if recover:
            # every complete frame survives; a later frame of the same key wins
            self.committed.update({k: v for k, v, end in self.pending if end <= cut_at})
        self.pending.clear()
        self.writer = ArchiveWriter(self.path, durable=False, on_uncommitted="recover" if recover else "discard")

    @rule()
    def read(self):
        with open_archive(self.path) as ar:
            assert dict(ar.iter_records()) == self.committed
            if not self.pending:
                assert ar.uncommitted_bytes == 0

    @invariant()
    def verifies(self):
        if self.writer is not None and not self.pending:
            verify_archive(self.path, records=False)


ArchiveMachine.TestCase.settings = settings(max_examples=40, stateful_step_count=25, deadline=None)
TestArchiveMachine = ArchiveMachine.TestCase
