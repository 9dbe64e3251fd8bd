"""The in-distribution / out-of-distribution comparison of two ``lip_eval run`` reports."""

from __future__ import annotations

import json

import pytest

from lip_ros.lip.evaluation.transfer import MAX_RATIO, METRICS, OUT_TARGETS, compare, to_markdown
from lip_ros.tools import lip_eval


def _report(weights: str, families: dict[str, float]) -> dict:
    """A run report whose errors per family are ``scale`` times a base set."""
    base = {"mpjpe_mm": 10.0, "pa_mpjpe_mm": 8.0, "angle19_deg": 2.0, "trans_cm": 1.5}
    per_family = {f: {"captures": 1, "scored_frames": 100, "posed_frames": 100, **{k: v * scale for k, v in
                                                                                    base.items()}}
                  for f, scale in families.items()}
    return {"command": "lip_eval run ...", "weights": {"ours": weights},
            "results": {"ours": {"end_to_end": {"per_family": per_family}}}}


def test_ratios_and_targets_per_family(tmp_path, capsys):
    ours = _report("w", {"all": 1.0, "walk": 1.0, "martial": 1.0})
    shifted = _report("w", {"all": 1.2, "walk": 1.1, "martial": 2.5, "dance": 1.0})
    c = compare(ours, shifted, held_out=("martial",))
    rows = {r["family"]: r for r in c["families"]}
    assert [r["family"] for r in c["families"]] == ["all", "dance", "martial", "walk"]
    assert rows["martial"]["held_out_family"] and not rows["walk"]["held_out_family"]
    assert rows["walk"]["ratio"]["mpjpe_mm"] == pytest.approx(1.1) and rows["dance"]["ratio"] is None
    checks = {t["target"]: t["pass"] for t in c["targets"]}
    assert len(checks) == len(OUT_TARGETS) + len(METRICS) and all(checks.values())  # 1.2x of values under target
    worse = compare(ours, _report("w", {"all": 1.3 * 1.01}))
    failed = [t["target"] for t in worse["targets"] if not t["pass"]]
    assert failed == [f"out / in {label} <=" for label in METRICS.values()] and MAX_RATIO == 1.3
    markdown = to_markdown(c)
    assert "| martial (held out of training) | 100 / 100 | 10.0 / 25.0 / 2.50 |" in markdown
    assert "| dance | 0 / 100 | - / 10.0 / - |" in markdown

    # the command line writes both files
    paths = []
    for name, report in (("in", ours), ("out", shifted)):
        paths.append(tmp_path / f"{name}.json")
        paths[-1].write_text(json.dumps(report))
    assert lip_eval.main(["transfer", *map(str, paths), "--out", str(tmp_path / "t"), "--held-out", "martial"]) == 0
    assert json.loads((tmp_path / "t" / "transfer.json").read_text())["families"][0]["family"] == "all"
    assert (tmp_path / "t" / "transfer.md").read_text() == capsys.readouterr().out.rstrip("\n") + "\n"
    # a report without per-family results (an older lip_eval) is a clear error
    paths[0].write_text(json.dumps({"weights": {}, "results": {"ours": {"end_to_end": {}}}}))
    assert lip_eval.main(["transfer", *map(str, paths)]) == 2
