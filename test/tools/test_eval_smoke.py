"""Train a tiny LIP model for a few steps, then evaluate it with ``lip_eval`` on a short held-out capture:
the whole chain runs and the report has every field, finite."""

from __future__ import annotations

import json
import math

import pytest

from lip_ros.lip.evaluation.captures import heldout_configs, make_heldout_set
from lip_ros.lip.evaluation.evaluate import MODES, POSE_ERRORS, TRANSLATION_METHODS
from lip_ros.lip.evaluation.report import OURS, VARIANTS
from lip_ros.tools import lip_eval as eval_cli
from lip_ros.tools import lip_train as train_cli

SUMMARY_NUMBERS = (*POSE_ERRORS, "jitter_m_s3", "jitter_true_m_s3")


pytestmark = pytest.mark.usefixtures("one_torch_thread")


def test_train_then_evaluate(tmp_path, capsys):
    weights = tmp_path / "weights" / "tiny"
    assert train_cli.main(["--data-dir", str(tmp_path / "rigdata"), "--out", str(tmp_path / "run"), "--config", "tiny",
                           "--train-seqs", "2", "--val-seqs", "1", "--seconds", "5", "--steps", "3", "--batch", "2",
                           "--window", "16", "--val-every", "3", "--export", str(weights)]) == 0
    capsys.readouterr()
    # one held-out capture: calibration poses then a few seconds of motion, 512 columns to keep it short
    bags = make_heldout_set(tmp_path / "heldout", heldout_configs(1, seconds=13.0, columns=512), progress=False)
    out = tmp_path / "report"
    # the variant flag's plumbing, with the same tiny weights standing in for a trained ablation
    assert eval_cli.main(["run", str(bags[0]), "--weights", str(weights), "--variant", f"lidar_only={weights}",
                          "--out", str(out)]) == 0
    markdown = capsys.readouterr().out
    report = json.loads((out / "report.json").read_text())
    assert (out / "report.md").read_text() + "\n" == markdown
    assert {p.name for p in out.glob("*.png")} == {"eval_per_joint_error.png", "eval_trajectories.png"}
    assert report["command"].startswith("lip_eval run") and len(report["load_average"]) == 3
    assert set(report["results"]) == {OURS, "lidar_only"}
    for mode in MODES:
        s = report["results"][OURS][mode]["summary"]
        assert s["frames"] == 130 and 0 < s["posed_frames"] <= s["scored_frames"] < s["frames"]
        assert all(math.isfinite(s[k]) for k in SUMMARY_NUMBERS), s
        assert len(s["per_joint_mm"]) == 24 and all(math.isfinite(v) for v in s["per_joint_mm"])
        for method in (*TRANSLATION_METHODS, "truth"):
            assert all(math.isfinite(v) for v in s["translation"][method].values())
        assert s["stamp_diff_ms"]["max_abs"] < 1.0
        assert len(report["results"][OURS][mode]["per_capture"]) == 1
    assert report["results"][OURS]["oracle"]["summary"]["outcomes"].get("calibration/calibrating", 0) == 0
    untrained = [c for c in report["targets"] if c["pass"] is None]
    assert len(untrained) == len(VARIANTS) - 1
    table_cells = [line for line in markdown.splitlines() if line.startswith("| ") and "| not trained |" in line]
    assert len(table_cells) == len(VARIANTS) - 1
    assert any(line.startswith(f"| {VARIANTS['lidar_only']} | ") for line in markdown.splitlines())
