"""omnisim: render catadioptric omni-image sequences with exact ground truth (Mitsuba 3).

Importing this package does not import Mitsuba; :mod:`omnisim.llvm` picks a
usable LLVM first when rendering starts.
"""

__all__ = ["render_dataset"]


def render_dataset(*args, **kwargs):
    """See :func:`omnisim.render.render_dataset`."""
    from .render import render_dataset as _render_dataset

    return _render_dataset(*args, **kwargs)
