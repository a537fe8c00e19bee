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


def test_mvs_sends_undistortion_and_fusion_output_to_the_log(tmp_path: Path, capfd):
    from test_recon_scene import make_scene, write_scene

    from recon.mvs import MvsBackend, MvsOptions, run_mvs
    from recon.mvs_cpu import CpuMvsOptions

    write_scene(make_scene(num_views=6, width=80, height=60), tmp_path, num_points=300)
    capfd.readouterr()
    small = MvsOptions(
        backend=MvsBackend.CPU, max_image_size=80, cpu=CpuMvsOptions(coarse_size=40, geom_min_consistent=1)
    )
    log = tmp_path / "logs" / "mvs.log"
    seen: list[tuple[str, int, int]] = []
    report = run_mvs(
        tmp_path / "sparse" / "0", tmp_path / "images", tmp_path / "dense", small, lambda *a: seen.append(a), log
    )
    out, err = capfd.readouterr()
    text = log.read_text()
    assert report.num_points > 0 and seen[-1][0] == "geometric"
    assert "Undistort" in text or "undistort" in text  # pycolmap.undistort_images' chatter
    assert "Fusing" in text or "fusion" in text.lower()  # pycolmap.stereo_fusion's chatter
    assert "] " not in out + err  # no glog line reached the terminal
