"""Hostile inputs (tofd_testing/hostile_inputs.py) cost little and are refused or ledgered with one line:
recordings whose chunks, records or header claim what no camera sends, dataset .npz bombs, configs out of every
bound."""

from __future__ import annotations

import resource
import subprocess
import sys
from pathlib import Path

import pytest

from tofd.drivers.recording.reader import read_recording_info
from tofd.drivers.recording.replay import ReplaySource
from tofd.drivers.source import DriverError
from tofd.lab.dataset import DatasetError, DatasetFile, load_dataset
from tofd_testing.hostile_inputs import CONFIG_CASES, DATASET_CASES, RECORDING_CASES, npz_bomb

ROOT = Path(__file__).resolve().parents[2]
CHUNK_CASES = [name for name in RECORDING_CASES if not name.startswith(("header_", "attachment_50", "deep_json"))]
HEADER_CASES = [name for name in RECORDING_CASES if name not in CHUNK_CASES]
EXPECTED = {"zstd_bomb": "more than a frame of this recording can need", "chunk_flood": "more than a frame",
            "lz4_chunk": "chunk compression 'lz4': tofd writes only zstd",
            "uncompressed_chunk": "chunk compression 'none': tofd writes only zstd",
            "record_flood": "more than 64 records", "absurd_record_length": "claims 1099511627776 bytes",
            "metadata_flood": "more than tofd writes (65536)", "attachment_flood": "more than tofd writes",
            "header_4000x4000": "image size 4000 x 4000: larger than any time-of-flight camera sends",
            "header_100000x100000": "image size 100000 x 100000", "header_width_0": "image size 0 x 144",
            "header_fx_nan": "fx", "header_fx_tiny": "fx: expected a finite focal length",
            "header_cx_huge": "cx: expected a finite principal point", "attachment_50mb": "more than tofd writes",
            "deep_json_config": "recursion"}


def _peak_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


@pytest.mark.parametrize("case", [c for c in CHUNK_CASES if c != "zstd_bomb"])
def test_a_hostile_chunk_is_ledgered_as_damage_and_every_frame_replays(tmp_path, case):
    path = RECORDING_CASES[case][0](tmp_path)
    with ReplaySource(path) as source:
        counters = [frame.frame_counter for frame in source]
        rejected = source.take_rejected()
    assert counters == [0, 1, 2, 3] and source.stopped_reason == "end"
    assert rejected == [] and source.counters["corrupt_tail"] == 0
    assert len(source.damage) == 1 and EXPECTED[case] in source.damage[0].detail, source.damage


def test_a_zstd_bomb_is_refused_without_decompressing_it(tmp_path):
    path = RECORDING_CASES["zstd_bomb"][0](tmp_path)
    before = _peak_rss_mb()
    with ReplaySource(path) as source:
        counters = [frame.frame_counter for frame in source]
    assert counters == [0, 1, 2, 3]
    assert len(source.damage) == 1 and EXPECTED["zstd_bomb"] in source.damage[0].detail
    assert _peak_rss_mb() - before < 200  # 1 GiB if it were decompressed


@pytest.mark.parametrize("case", HEADER_CASES)
def test_a_hostile_header_is_a_one_line_data_error(tmp_path, case):
    path = RECORDING_CASES[case][0](tmp_path)
    with pytest.raises(DriverError) as err:
        read_recording_info(path)
    assert "damaged recording header" in str(err.value) and EXPECTED[case] in str(err.value).lower() or \
        EXPECTED[case] in str(err.value)
    proc = subprocess.run([sys.executable, "-m", "tofd", "replay", str(path), "--out", str(tmp_path / "out"),
                           "--rerun", "none"], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2 and len(proc.stderr.strip().splitlines()) == 1, proc.stderr
    assert str(path) in proc.stderr and not (tmp_path / "out").exists()


@pytest.mark.parametrize("case", list(DATASET_CASES))
def test_a_dataset_bomb_is_refused_from_its_headers(tmp_path, monkeypatch, case):
    monkeypatch.setattr("tofd.lab.npz.MAX_LOADED_BYTES", 64 << 20)  # a bomb of 96 MiB is quick to make
    path = npz_bomb(tmp_path, 96 << 20) if case == "npz_bomb" else DATASET_CASES[case][0](tmp_path)
    before = _peak_rss_mb()
    with pytest.raises(DatasetError, match="key 'range'"):
        load_dataset(path)
    with pytest.raises(DatasetError, match="key 'range'|missing key"):
        DatasetFile(str(path))
    assert _peak_rss_mb() - before < 50


@pytest.mark.parametrize("case", list(CONFIG_CASES))
def test_a_hostile_config_is_a_one_line_config_error_exit_2(tmp_path, case):
    text, key = CONFIG_CASES[case]
    config = tmp_path / "tofd.toml"
    config.write_text(text)
    proc = subprocess.run([sys.executable, "-m", "tofd", "replay", str(ROOT / "tests" / "data" / "v1_first3.mcap"),
                           "--config", str(config), "--out", str(tmp_path / "out"), "--rerun", "none"],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2 and len(proc.stderr.strip().splitlines()) == 1, proc.stderr
    assert proc.stderr.startswith("tofd replay: config error: ") and key in proc.stderr, proc.stderr
