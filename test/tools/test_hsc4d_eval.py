"""``hsc4d_eval`` on a capture the live pipeline cannot pose: reported as lost, not a crash."""

from __future__ import annotations

import json

from lip_ros.tools import hsc4d_eval


def test_a_lost_capture_is_reported_and_the_exit_status_says_so(tmp_path, capsys):
    """The rig variant with the hip LiDAR tilted 15 deg (the method is told 30) on seed 0: the jump sync, whose
    sweep heights are levelled through the nominal mounting, comes out a second off and no sweep gets the suit's
    data (docs/hsc4d/trajectory.md, "Rig variants"; if the method learns to follow this variant, this test needs
    another capture it loses). The tool says so, writes the reason to metrics.json and exits 1."""
    assert hsc4d_eval.main(["--seeds", "0", "--seconds", "14", "--mount-tilt-up", "15", "--out", str(tmp_path)]) == 1
    out = capsys.readouterr().out
    assert "seed 0: LOST: capture 0:" in out and "every capture lost" in out
    report = json.loads((tmp_path / "metrics.json").read_text())
    assert list(report) == ["0"] and report["0"]["lost"].startswith("capture 0:")
