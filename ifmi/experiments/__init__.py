"""Sweeps of the tiling parameters, reports and their plots."""
