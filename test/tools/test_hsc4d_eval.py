"""``hsc4d_eval`` on a capture the live pipeline cannot pose: reported as lost, not a crash."""

from __future__ import annotations

import json

from lip_ros.rig.site_capture import SiteCapture
from lip_ros.tools import hsc4d_eval


def test_a_lost_capture_is_reported_and_the_exit_status_says_so(tmp_path, capsys, monkeypatch):
    """Seed 0 with the suit's pelvis IMU silent (its stream left out of the capture: the sensor's side of the
    boundary): the jump is never seen by the suit, so no sweep gets the suit's clock. The tool says so, writes the
    reason to metrics.json and exits 1. (This test used the hip LiDAR tilted 15 deg, which the jump sync lost
    until the ground's search cone was widened: docs/hsc4d/trajectory.md, "Rig variants".)"""
    streams = SiteCapture.suit_streams
    monkeypatch.setattr(SiteCapture, "suit_streams",
                        lambda self: {k: v for k, v in streams(self).items() if k != "pelvis"})
    assert hsc4d_eval.main(["--seeds", "0", "--seconds", "14", "--out", str(tmp_path)]) == 1
    out = capsys.readouterr().out
    assert "seed 0: LOST: capture 0: no trajectory (waiting for the jump" in out and "every capture lost" in out
    report = json.loads((tmp_path / "metrics.json").read_text())
    assert list(report) == ["0"] and report["0"]["lost"].startswith("capture 0:")
