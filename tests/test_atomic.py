"""Atomic writes: the target holds the old content or the whole new one, never a part, and
`write_new_json` never replaces a file."""

import json

import pytest

from nerf_transporter import atomic
from nerf_transporter.atomic import (
    unwritable_reason,
    write_file,
    write_json,
    write_new_json,
    write_text,
)


def test_write_json_replaces_with_indented_json(tmp_path):
    path = tmp_path / "deep" / "record.json"
    write_json(path, {"b": 1, "a": [1, 2]})
    write_json(path, {"b": 2, "a": [3]}, sort_keys=True)
    assert path.read_text() == '{\n  "a": [\n    3\n  ],\n  "b": 2\n}\n'
    assert [p.name for p in path.parent.iterdir()] == ["record.json"]  # no temporary left


def test_an_interrupted_write_leaves_the_old_file_and_no_temporary(tmp_path):
    path = write_text(tmp_path / "asset.obj", "old\n")

    def dying(file):
        file.write(b"half of the new")
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        write_file(path, dying)
    assert path.read_text() == "old\n"
    assert [p.name for p in tmp_path.iterdir()] == ["asset.obj"]


def test_a_name_taken_is_never_replaced(tmp_path):
    first = write_new_json(tmp_path, "results-best", {"run": 1})
    second = write_new_json(tmp_path, "results-best", {"run": 2})
    third = write_new_json(tmp_path, "results-best", {"run": 3})
    assert [p.name for p in (first, second, third)] == [
        "results-best.json",
        "results-best-2.json",
        "results-best-3.json",
    ]
    assert json.loads(first.read_text()) == {"run": 1}
    with pytest.raises(FileExistsError):
        write_json(second, {"run": 4}, overwrite=False)
    assert json.loads(second.read_text()) == {"run": 2}
    assert len(list(tmp_path.iterdir())) == 3


def test_written_files_get_the_mode_of_a_plain_open(tmp_path):
    plain = tmp_path / "plain.txt"
    plain.write_text("x")
    written = write_text(tmp_path / "atomic.txt", "x")
    assert written.stat().st_mode == plain.stat().st_mode


def test_an_unwritable_folder_is_named_before_anything_is_written(tmp_path, monkeypatch):
    assert unwritable_reason(tmp_path / "new" / "deeper") is None  # made as needed
    (tmp_path / "file").write_text("")
    assert (
        unwritable_reason(tmp_path / "file" / "results") == f"{tmp_path / 'file'} is not a folder"
    )

    def read_only(*args, **kwargs):  # as a read-only folder answers (root writes anywhere)
        raise PermissionError(13, "Permission denied")

    monkeypatch.setattr(atomic.tempfile, "TemporaryFile", read_only)
    reason = unwritable_reason(tmp_path / "results")
    assert reason == f"no file can be created in {tmp_path} (Permission denied)"
    assert not (tmp_path / "new").exists() and not (tmp_path / "results").exists()
