"""Evaluation of LIP on held-out rig captures: metrics, the end-to-end evaluation, reports, ``lip_eval``."""
