"""Camera models, rotations, trajectories and calibration fitting: pure geometry, no I/O."""
