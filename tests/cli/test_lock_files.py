"""No lock file is left beside a file that is no archive: the commands that take the writer lock check the
file first."""

from __future__ import annotations

import pytest

import vt4dcodec.cli as cli
from vt4dcodec.archive import compact_archive
from vt4dcodec.errors import Vt4dError


def test_compact_of_a_file_that_is_no_archive_leaves_no_lock_file(scene_file, tmp_path):
    with pytest.raises(Vt4dError):
        compact_archive(scene_file)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s.vt4d"]
    text = tmp_path / "notes.txt"
    text.write_text("not an archive")
    for argv in (["compact", str(text)], ["repair", str(text)], ["compact", str(scene_file)]):
        assert cli.main(argv) == 1, argv
    assert sorted(p.name for p in tmp_path.iterdir()) == ["notes.txt", "s.vt4d"]
