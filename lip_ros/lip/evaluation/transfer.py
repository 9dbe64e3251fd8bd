"""In distribution against out of distribution: two ``lip_eval run`` reports side by side, per motion family.

The in-distribution report comes from captures of the STANDARD rig domain, the out-of-distribution one from the
SHIFTED domain (:mod:`lip_ros.rig.domain`, docs/lip/transfer.md); both list their errors per motion family
(``per_family``, ``all`` for the whole set). Each metric is given in both, with the ratio out / in, and checked
against the transfer targets: out of distribution at most :data:`OUT_TARGETS`, and every ratio at most
:data:`MAX_RATIO`.
"""

from __future__ import annotations

import math

__all__ = ["METRICS", "OUT_TARGETS", "MAX_RATIO", "compare", "to_markdown"]

#: Metric key -> column label.
METRICS = {"mpjpe_mm": "MPJPE mm", "pa_mpjpe_mm": "PA-MPJPE mm", "angle19_deg": "Ang (19) deg", "trans_cm": "Trans cm"}
#: Out of distribution, the whole set: at most these.
OUT_TARGETS = {"mpjpe_mm": 30.0, "pa_mpjpe_mm": 22.0, "angle19_deg": 8.0, "trans_cm": 3.0}
#: Out / in distribution, the whole set, every metric: at most this.
MAX_RATIO = 1.3


def _ratio(out: float, ref: float) -> float:
    return out / ref if ref > 0 and math.isfinite(out) and math.isfinite(ref) else float("nan")


def compare(in_report: dict, out_report: dict, mode: str = "end_to_end", model: str = "ours",
            held_out: tuple[str, ...] = ()) -> dict:
    """Per family (``all`` first): both sets' errors and the ratios; and the targets, on ``all``. ``held_out``:
    the motion families the weights were trained without (marked in the table)."""
    fam_in = in_report["results"][model][mode]["per_family"]
    fam_out = out_report["results"][model][mode]["per_family"]
    families = ["all", *sorted((set(fam_in) | set(fam_out)) - {"all"})]
    rows = []
    for f in families:
        a, b = fam_in.get(f), fam_out.get(f)
        rows.append({"family": f, "held_out_family": f in held_out, "in": a, "out": b,
                     "ratio": {k: _ratio(b[k], a[k]) for k in METRICS} if a and b else None})
    whole = rows[0]
    targets = [{"target": f"out of distribution {METRICS[k]} <=", "value": whole["out"][k], "reference": v,
                "pass": whole["out"][k] <= v} for k, v in OUT_TARGETS.items()]
    targets += [{"target": f"out / in {METRICS[k]} <=", "value": whole["ratio"][k], "reference": MAX_RATIO,
                 "pass": whole["ratio"][k] <= MAX_RATIO} for k in METRICS]
    weights = (in_report["weights"].get(model), out_report["weights"].get(model))
    return {"mode": mode, "model": model, "weights": weights,
            "in_command": in_report.get("command"), "out_command": out_report.get("command"),
            "families": rows, "targets": targets}


def _f(value: float | None, digits: int = 1) -> str:
    return "-" if value is None or not math.isfinite(value) else f"{value:.{digits}f}"


def to_markdown(c: dict) -> str:
    """The comparison as markdown: one row per family, in / out / ratio for each metric, then the targets."""
    header = ["family", "posed in / out"] + [f"{label} in / out / ratio" for label in METRICS.values()]
    lines = [f"In distribution (STANDARD) against out of distribution (SHIFTED), {c['mode']}; weights "
             f"`{c['weights'][0]}`" + ("" if c["weights"][0] == c["weights"][1] else f" / `{c['weights'][1]}`") + ".",
             "", "| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for r in c["families"]:
        a, b, q = r["in"] or {}, r["out"] or {}, r["ratio"] or {}
        name = r["family"] + (" (held out of training)" if r["held_out_family"] else "")
        cells = [name, f"{a.get('posed_frames', 0)} / {b.get('posed_frames', 0)}"]
        cells += [f"{_f(a.get(k))} / {_f(b.get(k))} / {_f(q.get(k), 2)}" for k in METRICS]
        lines.append("| " + " | ".join(cells) + " |")
    lines += ["", "Targets (all families):", ""]
    lines += [f"- {t['target']} {t['reference']}: {_f(t['value'], 2)} -> {'pass' if t['pass'] else 'FAIL'}"
              for t in c["targets"]]
    return "\n".join(lines) + "\n"
