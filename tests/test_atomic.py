"""Atomic writes: a reader never sees a half-written file, and files get normal permissions."""

import os
import stat

import pytest

from ltmap_cli.io.atomic import atomic_path, write_text_atomic


def test_written_file_has_umask_permissions(tmp_path):
    old = os.umask(0o022)
    try:
        write_text_atomic(tmp_path / "a.yaml", "x: 1\n")
    finally:
        os.umask(old)
    assert stat.S_IMODE((tmp_path / "a.yaml").stat().st_mode) == 0o644


def test_failure_leaves_the_old_file_and_no_temp_file(tmp_path):
    target = tmp_path / "map.yaml"
    target.write_text("old\n")
    with pytest.raises(RuntimeError), atomic_path(target) as tmp:
        tmp.write_text("half")
        raise RuntimeError("disk full")
    assert target.read_text() == "old\n"
    assert [p.name for p in tmp_path.iterdir()] == ["map.yaml"]


def test_a_folder_in_the_way_is_named_as_given(tmp_path):
    (tmp_path / "out.png").mkdir()
    with pytest.raises(IsADirectoryError) as info, atomic_path(tmp_path / "out.png") as tmp:
        tmp.write_text("x")
    assert info.value.filename == str(tmp_path / "out.png")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.png"] and not any(
        (tmp_path / "out.png").iterdir()
    )
