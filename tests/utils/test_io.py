"""File helpers: errors that name the user's path, checked before the work."""

import os

import pytest

from lisa_hand.utils.io import (
    atomic_path,
    check_output_dir,
    check_output_file,
    ensure_writable_dir,
    read_json,
    require_file,
    write_json,
)


def test_require_file_tells_a_folder_from_a_missing_file(tmp_path):
    (tmp_path / "data.json").write_text("{}")
    assert require_file(tmp_path / "data.json") == tmp_path / "data.json"
    with pytest.raises(FileNotFoundError, match=r"missing\.json: no such file"):
        require_file(tmp_path / "missing.json")
    with pytest.raises(IsADirectoryError, match="is a directory, expected a file"):
        require_file(tmp_path)
    with pytest.raises(IsADirectoryError, match="is a directory, expected a file"):
        read_json(tmp_path)


def test_check_output_file_names_the_users_path_and_creates_nothing(tmp_path):
    (tmp_path / "folder").mkdir()
    (tmp_path / "afile").write_text("x")
    before = sorted(p.name for p in tmp_path.iterdir())
    assert check_output_file(tmp_path / "new" / "deeper" / "out.json").name == "out.json"
    assert check_output_file(tmp_path / "afile") == tmp_path / "afile"  # replacing a file: fine
    with pytest.raises(IsADirectoryError, match=r"folder: is a folder, expected a file name"):
        check_output_file(tmp_path / "folder")
    with pytest.raises(NotADirectoryError, match=r"afile/x\.json: cannot write here: .*afile is a "
                                                 "file, not a folder"):
        check_output_file(tmp_path / "afile" / "x.json")
    assert sorted(p.name for p in tmp_path.iterdir()) == before  # nothing created, no probe left


def test_check_output_dir(tmp_path):
    (tmp_path / "afile").write_text("x")
    assert check_output_dir(tmp_path / "new" / "renders") == tmp_path / "new" / "renders"
    assert not (tmp_path / "new").exists()
    with pytest.raises(NotADirectoryError, match=r"afile: is a file, expected a folder"):
        check_output_dir(tmp_path / "afile")
    with pytest.raises(NotADirectoryError, match=r"afile/r: cannot write here"):
        check_output_dir(tmp_path / "afile" / "r")
    with pytest.raises(NotADirectoryError, match=r"afile: is a file, expected a folder"):
        ensure_writable_dir(tmp_path / "afile")


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes into read-only folders")
def test_unwritable_folder_is_named(tmp_path):
    locked = tmp_path / "locked"
    locked.mkdir()
    locked.chmod(0o555)
    try:
        with pytest.raises(PermissionError, match=r"locked/out\.json: cannot write here: .*locked "
                                                  "is not a writable folder"):
            check_output_file(locked / "out.json")
        with pytest.raises(PermissionError, match=r"locked/sub/out\.json: cannot write here"):
            write_json(locked / "sub" / "out.json", {})
    finally:
        locked.chmod(0o755)


def test_atomic_path_errors_name_the_target_not_the_temporary(tmp_path):
    (tmp_path / "folder.json").mkdir()
    (tmp_path / "afile").write_text("x")
    with pytest.raises(IsADirectoryError) as info:
        write_json(tmp_path / "folder.json", {"a": 1})
    assert str(info.value) == f"{tmp_path / 'folder.json'}: is a folder, expected a file name"
    with pytest.raises(NotADirectoryError) as info:
        write_json(tmp_path / "afile" / "x.json", {})
    assert "afile/x.json: cannot write here" in str(info.value) and "/." not in str(info.value)
    # The target turns into a folder while the block runs: the final rename fails, naming it.
    with pytest.raises(OSError) as info:
        with atomic_path(tmp_path / "late.json") as tmp:
            tmp.write_text("{}")
            (tmp_path / "late.json").mkdir()
            (tmp_path / "late.json" / "keep").write_text("x")
    assert str(info.value).startswith(f"{tmp_path / 'late.json'}: cannot write")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["afile", "folder.json", "late.json"]


def test_a_folder_that_refuses_files_is_named(tmp_path, monkeypatch):
    # What a read-only file system (or a folder without write permission) does, even as root.
    import tempfile

    def refuse(*args, **kwargs):
        raise PermissionError(13, "Permission denied")

    monkeypatch.setattr(tempfile, "mkstemp", refuse)
    with pytest.raises(PermissionError) as info:
        check_output_file(tmp_path / "sub" / "mesh.ply")
    assert str(info.value) == (f"{tmp_path / 'sub' / 'mesh.ply'}: cannot write here: {tmp_path} "
                               "is not a writable folder (Permission denied)")
    with pytest.raises(PermissionError, match=r"out\.json: cannot write here \(Permission"):
        write_json(tmp_path / "out.json", {})
