"""Deterministic synthetic street scenes with exact ground truth."""
