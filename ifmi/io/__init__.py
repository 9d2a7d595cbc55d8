"""File formats: calibration, TUM trajectories, dataset folders, results."""
