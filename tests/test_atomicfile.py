"""latentune.atomicfile.write_atomic: the file is written whole or not at all, and an error
names the file the caller writes, not the temporary file beside it."""
from __future__ import annotations

import errno

import pytest

from latentune.atomicfile import write_atomic


def test_a_full_disk_names_the_target_and_leaves_the_old_file(tmp_path, full_disk):
    """A full disk mid-write raised OSError without a file name (or with the temporary
    file's, '.best.json.x8f.tmp', which the user never wrote), so the command's one line named
    no file the user knows; it names the target, which keeps its old text."""
    target = tmp_path / "best.json"
    target.write_text("old")
    full_disk()
    with pytest.raises(OSError) as e:
        write_atomic(target, "new text")
    assert (e.value.errno, e.value.filename) == (errno.ENOSPC, str(target))
    assert target.read_text() == "old"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["best.json"]


def test_a_missing_directory_names_the_target(tmp_path):
    target = tmp_path / "gone" / "summary.json"
    with pytest.raises(FileNotFoundError) as e:
        write_atomic(target, "x")
    assert e.value.filename == str(target)
