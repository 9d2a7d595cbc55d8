"""Shared by the video tests: a gray frame sequence written as a video file with OpenCV."""

from __future__ import annotations

import cv2
import pytest


def write_gray_video(path, images, *, fps: float, fourcc: str = "MJPG"):
    """Write ``images`` ((H, W) uint8 each, one size) to ``path``; skip the test if OpenCV cannot."""
    height, width = images[0].shape
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*fourcc), fps, (width, height), isColor=True)
    if not writer.isOpened():
        pytest.skip(f"this OpenCV cannot write {fourcc} video")
    for image in images:
        writer.write(cv2.cvtColor(image, cv2.COLOR_GRAY2BGR))
    writer.release()
