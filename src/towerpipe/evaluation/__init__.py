"""Evaluation: scores against truth, threshold calibration, the real-shape benchmark and the attribute-swap check."""
