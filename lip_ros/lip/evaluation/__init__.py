"""Evaluation of LIP on held-out rig captures: the captures, the end-to-end evaluation, reports (``lip_eval``)."""
