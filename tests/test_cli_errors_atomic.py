"""All-or-nothing outputs (core.io.atomic.output_transaction) and early output-path checks."""

from __future__ import annotations

import os

import pytest

from core.errors import InputFileError
from core.io.atomic import (
    atomic_path,
    check_output_dir,
    check_output_file,
    output_transaction,
    remove_output,
    write_text_atomic,
)


def test_transaction_commits_every_file_at_the_end(tmp_path) -> None:
    (tmp_path / "stale.json").write_text("old")
    with output_transaction():
        write_text_atomic(tmp_path / "a.txt", "A")
        write_text_atomic(tmp_path / "sub" / "b.txt", "B")
        remove_output(tmp_path / "stale.json")
        assert not (tmp_path / "a.txt").exists()  # nothing visible before the end
        assert (tmp_path / "stale.json").exists()
    assert (tmp_path / "a.txt").read_text() == "A" and (tmp_path / "sub" / "b.txt").read_text() == "B"
    assert not (tmp_path / "stale.json").exists()
    assert sorted(p.name for p in tmp_path.rglob("*")) == ["a.txt", "b.txt", "sub"]  # no temporary left


@pytest.mark.parametrize("exc", [RuntimeError("boom"), KeyboardInterrupt()])
def test_transaction_rolls_back_everything(tmp_path, exc) -> None:
    (tmp_path / "keep.txt").write_text("previous")
    with pytest.raises(type(exc)), output_transaction():
        write_text_atomic(tmp_path / "keep.txt", "new")
        write_text_atomic(tmp_path / "new" / "deep" / "c.txt", "C")
        remove_output(tmp_path / "keep.txt")
        raise exc
    assert (tmp_path / "keep.txt").read_text() == "previous"
    assert sorted(p.name for p in tmp_path.rglob("*")) == ["keep.txt"]  # created folders removed too


def test_commit_refuses_a_target_that_became_a_folder(tmp_path) -> None:
    with pytest.raises(InputFileError, match="a.txt"), output_transaction():
        write_text_atomic(tmp_path / "a.txt", "A")
        write_text_atomic(tmp_path / "b.txt", "B")
        (tmp_path / "a.txt").mkdir()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.txt"] and (tmp_path / "a.txt").is_dir()


def test_atomic_path_names_the_target(tmp_path) -> None:
    (tmp_path / "d.ply").mkdir()
    with pytest.raises(InputFileError, match="d.ply: is a folder"), atomic_path(tmp_path / "d.ply"):
        pass
    (tmp_path / "f").write_text("x")
    with pytest.raises(InputFileError, match="cannot create the output folder"), atomic_path(tmp_path / "f" / "x.ply"):
        pass


def test_output_checks(tmp_path) -> None:
    (tmp_path / "dir.ply").mkdir()
    (tmp_path / "file").write_text("x")
    with pytest.raises(InputFileError, match="is a folder"):
        check_output_file(tmp_path / "dir.ply")
    with pytest.raises(InputFileError, match="needs a folder"):
        check_output_file(tmp_path / "file" / "sub" / "x.ply")
    with pytest.raises(InputFileError, match="expected an output folder"):
        check_output_dir(tmp_path / "file")
    assert check_output_file(tmp_path / "new" / "x.ply") == tmp_path / "new" / "x.ply"
    assert check_output_dir(tmp_path / "renders") == tmp_path / "renders"
    if os.geteuid() != 0:  # root may write anywhere
        ro = tmp_path / "ro"
        ro.mkdir(mode=0o500)
        with pytest.raises(InputFileError, match="not writable"):
            check_output_file(ro / "x.ply")
