"""omnisim: render catadioptric omni-image sequences with exact ground truth (Mitsuba 3).

Importing this package does not import Mitsuba; :mod:`omnisim.llvm` picks a
usable LLVM first when rendering starts.

* :func:`load_scene` — read and validate a TOML scene file;
* :func:`render` — render it into a dataset folder (images, calibration,
  ground truth, optional depth and normals).
"""

__all__ = ["load_scene", "render", "render_dataset"]


def load_scene(*args, **kwargs):
    """See :func:`omnisim.api.load_scene`."""
    from omnisim.api import load_scene as _load_scene

    return _load_scene(*args, **kwargs)


def render(*args, **kwargs):
    """See :func:`omnisim.api.render`."""
    from omnisim.api import render as _render

    return _render(*args, **kwargs)


def render_dataset(*args, **kwargs):
    """See :func:`omnisim.renderer.render_dataset`."""
    from omnisim.renderer import render_dataset as _render_dataset

    return _render_dataset(*args, **kwargs)
