# SPDX-License-Identifier: BSD-3-Clause
"""``tripod demo``: for now, decoding the bundled real capture."""

import json

from tripod_processor.cli import main
from tripod_processor.cli.demo_cmd import find_demo_capture


def test_demo_decodes_the_bundled_capture(tmp_path, capsys, velodyne_dir):
    assert find_demo_capture() == velodyne_dir / "veloview-vlp16-20hz.pcap"
    assert main(["demo", "-o", str(tmp_path / "demo")]) == 0
    s = json.loads((tmp_path / "demo" / "summary.json").read_text())
    assert s["frames"] == 52 and len(list((tmp_path / "demo").glob("frame_*.ply"))) == 52
    assert "frames / rotations" in capsys.readouterr().err  # the results table


def test_demo_without_capture_one_line_error(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr("tripod_processor.cli.demo_cmd.find_demo_capture", lambda: None)
    assert main(["demo", "-o", str(tmp_path / "d")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("tripod: error:") and "not found" in err
