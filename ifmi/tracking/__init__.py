"""Sequences: the odometry (frame to frame and keyframes), the front-end registry and the plugin checks."""
