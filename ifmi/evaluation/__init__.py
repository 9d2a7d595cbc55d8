"""Errors of an estimate against ground truth: metrics, and the evaluation of trajectory files."""
