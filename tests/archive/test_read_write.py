"""Write real scenes, read them back byte-for-byte, with a constant number of reads."""

import os

import numpy as np
import pytest

from vt4dcodec.archive import (ARCHIVE_MAGIC, ArchiveWriter, DuplicateKeyError, open_archive, verify_archive)
from vt4dcodec.archive.layout import FOOTER_SIZE, HEADER_SIZE
from vt4dcodec.errors import ArchiveError, FormatError, SceneNotFoundError
from vt4dcodec.format import loads

from .helpers import payload_for, scene_record


def test_scene_records_round_trip_byte_for_byte(tmp_path):
    path = tmp_path / "a.vt4da"
    records = {f"scene-{i}": scene_record(i) for i in range(4)}
    with ArchiveWriter(path) as w:
        for k, v in records.items():
            w.append(k, v)
    with open_archive(path) as ar:
        assert ar.keys() == sorted(records)
        for k, v in records.items():
            assert ar.read_bytes(k) == v
            s = ar.summary(k)
            assert s["bytes"] == len(v) and s["static_shape"] == [16, 8] and s["frames"] == 2
            assert s["fingerprint"]["model_id"] == "vt4d-example"
            scene = ar.load(k)
            np.testing.assert_array_equal(scene.static_tokens, loads(v).static_tokens)
    verify_archive(path)
    assert path.read_bytes().startswith(ARCHIVE_MAGIC)


def test_scene_objects_are_accepted(tmp_path):
    from vt4dcodec.archive.examples import example_scene

    scene = example_scene(3, static_shape=(8, 4), dynamic_shape=(4, 4), frames=2)
    with ArchiveWriter(tmp_path / "a.vt4da") as w:
        w.append("s", scene)
    with open_archive(tmp_path / "a.vt4da") as ar:
        assert ar.open_scene("s").static_shape == (8, 4)


def test_a_scene_with_extra_cameras_survives_append_and_read(tmp_path):
    """Format 1.4 scene bytes (an XCAM section) are stored and read back as they are, summary as before."""
    from vt4dcodec.archive.examples import example_scene
    from vt4dcodec.cameras import Trajectory
    from vt4dcodec.format import Scene, dumps

    base = example_scene(5, static_shape=(8, 4), dynamic_shape=(4, 4), frames=3)
    extras = []
    for k in range(3):
        w2c = base.cameras.w2c.copy()
        w2c[:, 0, 3] += 0.5 * (k + 1)
        extras.append(Trajectory(base.cameras.K, w2c, base.cameras.width, base.cameras.height))
    scene = Scene(base.static_tokens, base.dynamic_tokens, base.cameras, base.fingerprint, base.metadata,
                  base.provenance, "float32", extra_cameras=extras)
    data = dumps(scene, cameras="exact")
    with ArchiveWriter(tmp_path / "a.vt4da") as w:
        w.append("rig", scene)
        w.append("rig-bytes", data)
    verify_archive(tmp_path / "a.vt4da")
    with open_archive(tmp_path / "a.vt4da") as ar:
        assert ar.open_scene("rig").num_extra_cameras == 3 and ar.summary("rig")["frames"] == 3
        assert ar.read_bytes("rig-bytes") == data and ar.load("rig-bytes") == scene
        back = ar.load("rig")  # the writer's default compact cameras: within 0.01 px, as CAMS
        assert len(back.extra_cameras) == 3 and back.static_tokens.tobytes() == scene.static_tokens.tobytes()


def test_invalid_record_is_refused(tmp_path):
    with ArchiveWriter(tmp_path / "a.vt4da") as w:
        with pytest.raises(FormatError):
            w.append("bad", b"not a vt4d file")
        with pytest.raises(ArchiveError):
            w.append("bad", 12345)


@pytest.mark.parametrize("n", [1, 30, 300])
def test_open_and_get_cost_constant_reads(tmp_path, n):
    path = tmp_path / "a.vt4da"
    with ArchiveWriter(path, durable=False) as w:
        for i in range(n):
            w.append(f"k{i:05d}", payload_for(f"k{i}"), validate=False)
    with open_archive(path) as ar:
        # header (preamble checked, slots checked for a cut-off commit) + footer + index: 3 reads, any n
        assert (ar.source.reads, ar.source.bytes_read) == (
            3, HEADER_SIZE + FOOTER_SIZE + ar.commit.index_length + ar.commit.tail_length)  # a light commit's tail too
        before = ar.source.bytes_read
        key = f"k{n // 2:05d}"
        assert ar.read_bytes(key) == payload_for(f"k{n // 2}")
        assert ar.source.reads == 4
        assert ar.source.bytes_read - before == len(payload_for(f"k{n // 2}"))


def test_duplicate_replace_abort_and_generations(tmp_path):
    path = tmp_path / "a.vt4da"
    with ArchiveWriter(path) as w:
        assert w.generation == 0
        w.append("a", b"1", validate=False)
        with pytest.raises(DuplicateKeyError):
            w.append("a", b"2", validate=False)
        assert w.commit() == 1
        with pytest.raises(DuplicateKeyError):
            w.append("a", b"2", validate=False)
        w.append("a", b"22", validate=False, replace=True)
        w.append("b", b"3", validate=False)
        assert w.commit() == 2
        w.append("c", b"4", validate=False)
        size_with_pending = os.path.getsize(path)
        w.abort()
        assert os.path.getsize(path) < size_with_pending
        assert w.commit() == 2  # nothing pending
    with open_archive(path) as ar:
        assert dict(ar.iter_records()) == {"a": b"22", "b": b"3"}
        assert ar.generation == 2
    verify_archive(path, records=False)


def test_exception_in_context_aborts(tmp_path):
    path = tmp_path / "a.vt4da"
    with ArchiveWriter(path) as w:
        w.append("a", b"1", validate=False)
    with pytest.raises(RuntimeError):
        with ArchiveWriter(path) as w:
            w.append("b", b"2", validate=False)
            raise RuntimeError("boom")
    with open_archive(path) as ar:
        assert ar.keys() == ["a"] and ar.uncommitted_bytes == 0


def test_missing_key_and_modes(tmp_path):
    path = tmp_path / "a.vt4da"
    with ArchiveWriter(path, "x") as w:
        w.append("a", b"1", validate=False)
    with pytest.raises(FileExistsError):
        ArchiveWriter(path, "x")
    with open_archive(path) as ar:
        with pytest.raises(SceneNotFoundError):
            ar.read_bytes("nope")
        assert "a" in ar and "nope" not in ar and 5 not in ar
    with ArchiveWriter(path, "w") as w:
        assert len(w) == 0
    with open_archive(path) as ar:
        assert len(ar) == 0


def test_reader_remeasures_size_when_slots_point_past_its_snapshot(tmp_path):
    """Regression: a writer committed between the reader's size() and its header read, so every slot
    named a commit past the stale size and the reader raised NoCommitError mid-append."""
    from vt4dcodec.archive.source import BytesSource

    path = tmp_path / "a.vt4da"
    w = ArchiveWriter(path, durable=False, version=(1, 1))  # (the stale size below cuts into its last commit)
    w.append("a", b"1", validate=False)
    w.commit()
    w.append("b", b"2", validate=False)  # uncommitted tail: the file does not end with a footer
    data = path.read_bytes()
    w.close(commit=False)

    class Stale(BytesSource):
        calls = 0

        def size(self):
            self.calls += 1
            return super().size() - 200 if self.calls == 1 else super().size()

    with open_archive(Stale(data)) as ar:
        assert dict(ar.iter_records()) == {"a": b"1"}


def test_compact_container_records_archive_beside_older_ones(tmp_path):
    """Format 1.3 scenes (the writer's default) and 1.0/1.2 ones live in one archive: summaries, loads,
    extraction byte for byte and verification read each layout."""
    from vt4dcodec.archive.examples import example_scene
    from vt4dcodec.format import dumps, open_scene

    scene = example_scene(5, static_shape=(8, 4), dynamic_shape=(4, 4), frames=3)
    records = {"v1.3": dumps(scene), "v1.2": dumps(scene, header="legacy"),
               "v1.0": dumps(scene, header="legacy", cameras="legacy")}
    assert [open_scene(v).version for v in records.values()] == [(1, 3), (1, 2), (1, 0)]
    path = tmp_path / "mixed.vt4da"
    with ArchiveWriter(path) as w:
        for k, v in records.items():
            w.append(k, v)
        w.append("object", scene)  # a Scene object is written in the default (1.3) layout
    verify_archive(path)
    with open_archive(path) as ar:
        for k, v in records.items():
            assert ar.read_bytes(k) == v and ar.open_scene(k).version == open_scene(v).version
            assert ar.summary(k)["bytes"] == len(v) and ar.summary(k)["frames"] == 3
            np.testing.assert_array_equal(ar.load(k).static_tokens, loads(v).static_tokens)
            assert ar.load(k).fingerprint == scene.fingerprint
        assert ar.open_scene("object").version == (1, 3) and ar.read_bytes("object") == records["v1.3"]
