"""recon.colmap_log: native output (fds 1/2: glog, printf, COLMAP) goes to the log file, Python's to the terminal."""

from __future__ import annotations

import ctypes
import os
from pathlib import Path

from recon.colmap_log import native_output_to, summarise_warnings


def test_native_output_goes_to_the_log_and_python_output_does_not(tmp_path: Path, capfd):
    import pycolmap

    log_path = tmp_path / "logs" / "colmap.log"
    with native_output_to(log_path) as log:
        os.write(1, b"raw fd1 line\n")
        os.write(2, b"raw fd2 line\n")
        ctypes.CDLL(None).printf(b"buffered printf line\n")  # C stdio buffer: flushed before fds are restored
        pycolmap.logging.warning("glog says something odd")
        pycolmap.logging.info("glog chatter")
        print("python progress line")
    out, err = capfd.readouterr()
    text = log_path.read_text()
    for line in ("raw fd1 line", "raw fd2 line", "buffered printf line", "glog says something odd", "glog chatter"):
        assert line in text and line not in out + err
    assert "python progress line" in out and "python progress line" not in text
    assert log.num_bytes == len(text.encode())
    assert len(log.warnings) == 1 and log.warnings[0].startswith("COLMAP warning (")
    assert log.warnings[0].endswith("glog says something odd")
    # fds are back: output after the block reaches the terminal again
    os.write(1, b"after\n")
    assert "after" in capfd.readouterr().out


def test_log_is_appended_and_none_redirects_nothing(tmp_path: Path, capfd):
    log_path = tmp_path / "colmap.log"
    with native_output_to(log_path):
        os.write(2, b"first\n")
    with native_output_to(log_path) as log:
        os.write(2, b"second\n")
    assert log_path.read_text() == "first\nsecond\n" and log.num_bytes == len("second\n")
    with native_output_to(None) as nothing:
        os.write(2, b"visible\n")
    assert nothing is None and "visible" in capfd.readouterr().err


def test_fds_are_restored_after_an_error(tmp_path: Path, capfd):
    try:
        with native_output_to(tmp_path / "x.log"):
            raise RuntimeError("boom")
    except RuntimeError:
        pass
    os.write(2, b"still the terminal\n")
    assert "still the terminal" in capfd.readouterr().err


def test_warning_summary_counts_repeats_and_skips_info():
    text = "\n".join(
        [
            "I20261123 11:34:03.004990 139 incremental_pipeline.cc:873] => Image sees 31 / 82 points",
            "W20261123 11:34:03.1 139 /src/colmap/feature/sift.cc:10] Unable to  read   EXIF",
            "W1123 11:34:03.2 139 /src/colmap/feature/sift.cc:10] Unable to read EXIF",
            "E1123 11:34:03.3 139 mapper.cc:5] No good initial image pair found.",
            "plain text line",
        ]
    )
    assert summarise_warnings(text) == [
        "COLMAP warning (sift.cc): Unable to read EXIF (x2)",
        "COLMAP error (mapper.cc): No good initial image pair found.",
    ]
