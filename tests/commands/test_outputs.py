"""Atomic outputs (tofd.outputs) and the config file rules: temp file + rename, planted symlinks replaced, not
followed; relative model paths from the config file's directory."""

from __future__ import annotations

import os

import pytest

from tofd.config import load_config
from tofd.outputs import AtomicFile, OutputError, check_output_dir, check_output_file, prepare_output_dir, write_text


def test_a_planted_symlink_is_replaced_not_followed(tmp_path):
    victim = tmp_path / "victim"
    victim.write_text("precious\n")
    out = tmp_path / "summary.json"
    out.symlink_to(victim)
    write_text(out, "{}\n")
    assert victim.read_text() == "precious\n"
    assert not out.is_symlink() and out.read_text() == "{}\n"


def test_a_failed_write_leaves_the_old_file_and_no_temp_file(tmp_path):
    out = tmp_path / "results.jsonl"
    out.write_text("old\n")
    with pytest.raises(RuntimeError), AtomicFile(out) as fh:
        fh.write("half")
        raise RuntimeError("killed mid-way")
    assert out.read_text() == "old\n" and os.listdir(tmp_path) == ["results.jsonl"]
    with AtomicFile(out) as fh:
        fh.write("new\n")
        assert out.read_text() == "old\n"  # readers see the old file until the rename
    assert out.read_text() == "new\n" and oct(out.stat().st_mode & 0o777) == oct(0o666 & ~_umask())


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def test_output_paths_are_checked_before_work(tmp_path):
    (tmp_path / "file").write_text("x")
    with pytest.raises(OutputError, match="exists and is not a directory"):
        prepare_output_dir(tmp_path / "file")
    with pytest.raises(OutputError, match="cannot create"):
        prepare_output_dir(tmp_path / "file" / "sub")
    with pytest.raises(OutputError, match="does not exist"):
        check_output_file(tmp_path / "missing" / "m.json")
    with pytest.raises(OutputError, match="is a directory"):
        check_output_file(tmp_path)
    with pytest.raises(OutputError, match="cannot create"):
        check_output_dir(tmp_path / "file" / "sub")
    assert check_output_dir(tmp_path / "c" / "d") == tmp_path / "c" / "d" and not (tmp_path / "c").exists()
    assert prepare_output_dir(tmp_path / "a" / "b").is_dir()


def test_relative_model_path_is_taken_from_the_config_files_directory(tmp_path, monkeypatch):
    cfg_dir = tmp_path / "etc"
    cfg_dir.mkdir()
    (cfg_dir / "tofd.toml").write_text('[detector]\nmodel_path = "models/nose.json"\n')
    monkeypatch.chdir(tmp_path)
    cfg = load_config(cfg_dir / "tofd.toml")
    assert cfg.detector.model_path == str(cfg_dir / "models" / "nose.json")
