"""One-line display of warnings, shared by the ``ifmi`` and ``omnisim`` command lines.

Python's default display prints the source file and line that raised a
warning, and the source line itself; for a user's input problem (a skipped
file, a fallback) only the message matters. Inside
:func:`input_warnings_as_lines` these are printed as
``PROGRAM COMMAND: warning: MESSAGE`` on standard error:

* :class:`~ifmi.errors.InputWarning`, and a plain ``UserWarning`` (or
  subclass) raised by the project's own packages (``ifmi``, ``omnisim``):
  these are messages for the user, e.g. the mirror band fallback of
  :func:`ifmi.spectral.panorama.radius_band`; each message once (a message raised for
  every frame of a folder, e.g. the bit depth of its 16-bit images, is
  printed the first time);
* a ``RuntimeWarning`` (e.g. NumPy's ``invalid value encountered in
  divide``, ``Mean of empty slice``) as ``MESSAGE (at PACKAGE/MODULE.py:LINE)``,
  naming the innermost line of the project that led to it (NumPy's own
  file otherwise), so nothing is hidden; once per message and place.

Other warnings (third-party ``UserWarning``, ``DeprecationWarning``, ...)
keep Python's default display.
"""

from __future__ import annotations

import os
import sys
import warnings
from contextlib import contextmanager
from typing import Callable, Iterator

from ifmi.errors import InputWarning

__all__ = ["input_warnings_as_lines"]

# Top-level packages whose UserWarnings are messages for the user (names only: ifmi
# never imports omnisim).
_OWN_PACKAGES = ("ifmi", "omnisim")


def _package_dirs() -> list[str]:
    """Folders of the imported ``_OWN_PACKAGES``, each ending with a separator."""
    dirs = []
    for name in _OWN_PACKAGES:
        module = sys.modules.get(name)
        if module is not None and getattr(module, "__file__", None):
            dirs.append(os.path.join(os.path.dirname(os.path.abspath(module.__file__)), ""))
    return dirs


def _in_own_package(filename: str, dirs: list[str]) -> bool:
    return os.path.abspath(filename).startswith(tuple(dirs)) if dirs else False


def _own_caller(dirs: list[str]) -> str | None:
    """``package/module.py:LINE`` of the innermost frame of the project on the current stack."""
    frame = sys._getframe(1)
    here = os.path.abspath(__file__)
    while frame is not None:
        filename = os.path.abspath(frame.f_code.co_filename)
        if filename != here and _in_own_package(filename, dirs):
            root = next(d for d in dirs if filename.startswith(d))
            package = os.path.basename(os.path.dirname(root))
            return f"{package}/{os.path.relpath(filename, root)}:{frame.f_lineno}"
        frame = frame.f_back
    return None


def _print_line(text: str) -> None:
    """Print ``text`` on stderr on a line of its own, also while a progress bar is drawn there."""
    from tqdm import tqdm

    tqdm.write(text, file=sys.stderr)


@contextmanager
def input_warnings_as_lines(prefix: Callable[[], str]) -> Iterator[None]:
    """Print input warnings, the project's UserWarnings and RuntimeWarnings as one line each.

    Parameters
    ----------
    prefix : callable () -> str
        Returns the line's prefix, e.g. ``"omnisim degrade"``; called when a
        warning is shown, so it may name a command parsed after entry.
    """
    shown_runtime: set[tuple[str, str]] = set()
    shown_input: set[str] = set()
    with warnings.catch_warnings():
        default_show = warnings.showwarning

        def show_warning(message, category, filename, lineno, file=None, line=None):
            dirs = _package_dirs()
            if issubclass(category, InputWarning) or (
                    issubclass(category, UserWarning) and _in_own_package(filename, dirs)):
                if str(message) not in shown_input:
                    shown_input.add(str(message))
                    _print_line(f"{prefix()}: warning: {message}")
            elif issubclass(category, RuntimeWarning):
                where = _own_caller(dirs) or f"{os.path.basename(filename)}:{lineno}"
                if (str(message), where) not in shown_runtime:
                    shown_runtime.add((str(message), where))
                    _print_line(f"{prefix()}: warning: {message} (at {where})")
            else:
                default_show(message, category, filename, lineno, file, line)

        warnings.showwarning = show_warning
        warnings.simplefilter("always", InputWarning)
        yield
