"""BLAS runs on one thread while a sequence is estimated, and the process's setting comes back after."""

from __future__ import annotations

import numpy as np
import pytest
from threadpoolctl import threadpool_info, threadpool_limits

import ifmi.pipeline as pipeline
from ifmi.runtime.blas_threads import single_blas_thread
from ifmi.synthetic import environment_texture, example_band_px, example_omni_model, omni_from_environment

pytest.importorskip("skimage")


def _blas_threads() -> list[int]:
    return [pool["num_threads"] for pool in threadpool_info() if pool["user_api"] == "blas"]


def test_single_blas_thread_limits_and_restores():
    if not _blas_threads():
        pytest.skip("no BLAS library loaded that threadpoolctl can control")
    with threadpool_limits(limits=2, user_api="blas"):
        before = _blas_threads()
        with single_blas_thread():
            assert set(_blas_threads()) == {1}
        assert _blas_threads() == before
        with pytest.raises(RuntimeError):  # restored on an error too
            with single_blas_thread():
                raise RuntimeError("inside")
        assert _blas_threads() == before


def test_estimate_sequence_tracks_with_one_blas_thread(monkeypatch):
    if not _blas_threads():
        pytest.skip("no BLAS library loaded that threadpoolctl can control")
    seen = []
    create = pipeline.create_front_end

    def recording_front_end(method, model, config):
        front_end = create(method, model, config)
        prepare = front_end.prepare

        def recorded(image):
            seen.append(_blas_threads())
            return prepare(image)

        front_end.prepare = recorded
        return front_end

    monkeypatch.setattr(pipeline, "create_front_end", recording_front_end)
    model = example_omni_model(256)
    texture = environment_texture(height=256, seed=3)
    images = [omni_from_environment(texture, model, np.eye(3), band_px=example_band_px(model))] * 3
    with threadpool_limits(limits=2, user_api="blas"):
        before = _blas_threads()
        estimate = pipeline.estimate_sequence(images, model, method="orb")
        assert _blas_threads() == before
    assert len(estimate.frames) == 3 and len(seen) == 3
    assert all(set(threads) == {1} for threads in seen)
