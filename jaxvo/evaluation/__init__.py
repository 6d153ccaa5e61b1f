"""Evaluation as the field does it: ATE, RPE and segmentation scores (``metrics``),
the scores of one run (``scores``)."""
