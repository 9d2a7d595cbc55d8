"""The Python API of the simulator: read a scene file, render it into a dataset folder.

Re-exported by :mod:`omnisim` (``omnisim.load_scene``, ``omnisim.render``);
``omnisim render`` calls :func:`render`. Importing this module does not import
Mitsuba: rendering does, when it starts.
"""

from __future__ import annotations

__all__ = ["load_scene", "render"]


def load_scene(path, *, spp: int | None = None, resolution=None, frames: int | None = None):
    """Read and validate a TOML scene file.

    Parameters
    ----------
    path : path
        Scene file (``scenes/office.toml``); the keys are listed in the
        documentation's scene reference (``omnisim generators`` lists the
        ``[[objects]]`` generators).
    spp : int, optional, keyword-only
        Overrides ``[render] spp`` (samples per pixel).
    resolution : int or (height, width), optional, keyword-only
        Overrides ``[render] resolution`` (pixels); the calibration is scaled to it.
    frames : int, optional, keyword-only
        Overrides ``[trajectory] frames``.

    Returns
    -------
    omnisim.config.SceneConfig
        Frozen settings of every table (``render``, ``camera``, ``trajectory``,
        ``capture``, ``effects``, ``objects``, ...).

    Raises
    ------
    ifmi.errors.InputError
        One line naming the file, the table and the key of the first problem.
    """
    from omnisim.config import load_scene_config

    return load_scene_config(path, spp=spp, resolution=resolution, frames=frames)


def render(scene, out, *, frames: int | None = None, seed: int | None = None, spp: int | None = None,
           resolution=None, aovs=(), progress: bool = False, variant: str | None = None,
           workers: int | None = None, scheduler: str | None = None,
           connect_timeout_s: float | None = None):
    """Render a scene file into a dataset folder with exact ground truth.

    The folder holds ``images/000000.png`` ..., the calibration
    (``calib_results.txt`` or ``camera.yaml``), ``groundtruth.txt`` (TUM,
    ``R_0k``), ``meta.json`` and, when asked, ``depth/`` and ``normal/``. A
    folder left by an interrupted render of the same settings is resumed.

    Parameters
    ----------
    scene : path
        TOML scene file.
    out : path
        Dataset folder to write.
    frames, seed, spp : int, optional, keyword-only
        Override the scene's frame count, sequence seed (motion, sampling,
        effects) and samples per pixel.
    resolution : int or (height, width), optional, keyword-only
        Image size in pixels; the calibration is scaled to it.
    aovs : str or sequence of str, keyword-only
        Per-pixel ground truth to write: ``"depth"``, ``"normal"``.
    progress : bool, keyword-only
        Show a progress bar.
    variant : str, optional, keyword-only
        Mitsuba variant (default: ``cuda_ad_rgb`` with a GPU, else ``llvm_ad_rgb``).
    workers : int, optional, keyword-only
        Render on a local Dask cluster of this many processes.
    scheduler : str, optional, keyword-only
        Render on the Dask cluster at this address.
    connect_timeout_s : float, optional, keyword-only
        Seconds ``scheduler`` has to accept the connection and answer (> 0);
        default :data:`ifmi.runtime.local_workers.DEFAULT_CONNECT_TIMEOUT_S`.

    Returns
    -------
    omnisim.renderer.DatasetResult
        ``out_dir``, ``frames``, ``rendered`` (frames rendered by this call)
        and ``seconds_per_frame``.

    Raises
    ------
    ifmi.errors.InputError
        A bad scene file or option.
    ifmi.errors.OutputError
        The folder cannot be written, or holds another render.
    """
    from omnisim.renderer import render_dataset

    timeout = {} if connect_timeout_s is None else {"connect_timeout_s": connect_timeout_s}
    return render_dataset(scene, out, frames=frames, seed=seed, spp=spp, resolution=resolution,
                          progress=progress, variant=variant, aovs=aovs, workers=workers,
                          scheduler=scheduler, **timeout)
