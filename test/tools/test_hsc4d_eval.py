"""``hsc4d_eval`` on a capture the live pipeline cannot pose: reported as lost, not a crash."""

from __future__ import annotations

import json

import pytest

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


def test_the_refinement_is_held_to_both_live_outputs_on_every_metric_but_the_shape():
    """``refined_shortfalls`` names each metric of the issue where the refinement is worse than the live graph or
    the live optimised body, by how much (unrounded), and leaves out the shape (a diagnostic) and ties."""
    keys = ("ate_m", "vertical_m", "final_m", "checkpoint_m", "contact_m", "sliding_m", "mpjpe_mm", "shape_m")
    live = dict.fromkeys(keys, 0.02)
    refined = live | {"ate_m": 0.01, "vertical_m": 0.0214, "shape_m": 0.05}
    optimised = live | {"mpjpe_mm": 0.0199}
    short = hsc4d_eval.refined_shortfalls({"live": live, "live_optimised": optimised, "refined": refined})
    assert [(key, name) for key, name, _ in short] == [("vertical_m", "live"), ("vertical_m", "live_optimised"),
                                                      ("mpjpe_mm", "live_optimised")]
    assert abs(short[0][2] - 0.0014) < 1e-12 and abs(short[2][2] - 0.0001) < 1e-12
    line = hsc4d_eval._shortfalls_line({"live": live, "live_optimised": optimised, "refined": refined})
    assert "vertical by 0.14 cm (live graph)" in line and "MPJPE by 0.0001 mm (live optimised)" in line
    assert "every metric" in hsc4d_eval._shortfalls_line({"live": live, "live_optimised": live, "refined": live})


def test_a_band_of_information_out_of_order_is_refused_before_any_capture(tmp_path, capsys):
    """``--pinned-information`` / ``--pinned-tilt-information`` take LOW HIGH; one that is not 0 <= LOW < HIGH (nor
    0 0) is a usage error (exit 2), nothing simulated."""
    for option in ("--pinned-information", "--pinned-tilt-information"):
        with pytest.raises(SystemExit) as stop:
            hsc4d_eval.main(["--seeds", "0", option, "0.05", "0.01", "--out", str(tmp_path)])
        assert stop.value.code == 2 and "0 <= LOW < HIGH" in capsys.readouterr().err
    assert not list(tmp_path.iterdir())
