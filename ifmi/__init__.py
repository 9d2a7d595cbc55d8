"""ifmi: extended improved Fourier-Mellin invariant rotation estimation for omni images.

The top-level functions are imported on first use, so ``import ifmi`` stays
light (no OpenCV, no Mitsuba):

* :func:`estimate` — the orientation of every frame of a dataset folder, a
  video or a list of images (:class:`Estimate`);
* :func:`evaluate` — its errors against ground truth (:class:`Evaluation`,
  ``ate_rad`` and the per-axis figures);
* :func:`read_calibration` — an OCamCalib or Kalibr calibration file;
* :class:`EstimateConfig` and :class:`EvaluateOptions` — every option.
"""

__version__ = "0.1.0"

__all__ = ["estimate", "evaluate", "read_calibration", "Estimate", "Evaluation", "EstimateConfig",
           "EvaluateOptions", "__version__"]

# Public name -> module that defines it (imported when the name is first used).
_LAZY = {
    "estimate": "ifmi.api", "evaluate": "ifmi.api", "read_calibration": "ifmi.api",
    "Estimate": "ifmi.api", "Evaluation": "ifmi.api",
    "EstimateConfig": "ifmi.pipeline", "EvaluateOptions": "ifmi.evaluation.trajectory_files",
}


def __getattr__(name: str):
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'ifmi' has no attribute {name!r}")
    import importlib

    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__():
    return sorted(set(globals()) | set(__all__))
