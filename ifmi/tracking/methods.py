"""Estimation methods by name: the built-in front ends, installed plugins and ``module:factory``.

A method is a factory ``factory(model, config) -> FrontEnd``
(:mod:`ifmi.front_end`). ``--method`` (of ``ifmi estimate`` and ``ifmi
sweep``) names one of

* a built-in method: :data:`BUILTIN_METHODS` is the one list of them (name,
  factory, one-line summary, colour in figures);
* a method an installed package registers under the entry-point group
  ``ifmi.tracking.methods`` (``[project.entry-points."ifmi.tracking.methods"] sift =
  "my_package.sift:front_end"`` in its ``pyproject.toml``);
* any importable factory, written ``package.module:factory``.

Every method name, known or not, gets a place in report tables
(:func:`method_sort_key`) and a colour in figures (:func:`method_colors`).
"""

from __future__ import annotations

import importlib
import sys
import warnings
from dataclasses import dataclass
from functools import lru_cache
from importlib import metadata
from typing import Any, Callable, Iterable

from ifmi.errors import InputError, InputWarning, one_line

__all__ = [
    "ENTRY_POINT_GROUP",
    "MethodInfo",
    "BUILTIN_METHODS",
    "builtin_method_names",
    "ignores_tiling",
    "plugin_methods",
    "available_methods",
    "method_names",
    "warn_shadowing_plugins",
    "load_factory",
    "create_front_end",
    "method_sort_key",
    "method_colors",
    "ifmi_front_end",
]

# Entry-point group under which installed packages register methods.
ENTRY_POINT_GROUP = "ifmi.tracking.methods"


@dataclass(frozen=True)
class MethodInfo:
    """A named method.

    Attributes
    ----------
    name : str
        What ``--method`` accepts.
    target : str
        Its factory, ``package.module:attribute``.
    summary : str
        One line saying what it does (a plugin's: the first line of its
        factory's docstring, read when listed).
    source : str
        ``"built-in"`` or ``"plugin <distribution>"``.
    color : str or None
        Matplotlib colour of a built-in method in figures.
    uses_tiling : bool or None
        Whether its front end reads the iFMI tiling (tile size and overlap,
        what ``ifmi sweep`` varies); None when unknown (a plugin's).
    """

    name: str
    target: str
    summary: str
    source: str
    color: str | None = None
    uses_tiling: bool | None = None


def ifmi_front_end(model, config):
    """The extended iFMI front end: per-tile Fourier-Mellin registration on the panorama."""
    from ifmi.spectral.ifmi_front_end import IfmiFrontEnd

    return IfmiFrontEnd(model, config.ifmi)


# The built-in methods, in report order, with their colours in every figure.
BUILTIN_METHODS = (
    MethodInfo("ifmi", "ifmi.tracking.methods:ifmi_front_end",
               "extended iFMI: per-tile Fourier-Mellin registration on the panorama, "
               "flow rays", "built-in", "tab:red", uses_tiling=True),
    MethodInfo("orb", "ifmi.features:orb_front_end",
               "ORB keypoints in the mirror band, Hamming ratio-test matching", "built-in",
               "tab:blue", uses_tiling=False),
    MethodInfo("akaze", "ifmi.features:akaze_front_end",
               "AKAZE keypoints in the mirror band, Hamming ratio-test matching", "built-in",
               "tab:green", uses_tiling=False),
)
# Colours given to other methods, in turn (none of them a built-in method's colour).
OTHER_COLORS = ("tab:orange", "tab:purple", "tab:brown", "tab:pink", "tab:olive", "tab:cyan",
                "tab:gray")


def ignores_tiling(method: str) -> bool:
    """Whether ``method`` is known not to read the iFMI tiling (a built-in keypoint method)."""
    return any(m.name == method and m.uses_tiling is False for m in BUILTIN_METHODS)


def builtin_method_names() -> tuple[str, ...]:
    """Names of the built-in methods, in report order."""
    return tuple(m.name for m in BUILTIN_METHODS)


def _first_doc_line(obj) -> str:
    doc = (getattr(obj, "__doc__", None) or "").strip()
    return doc.splitlines()[0].strip() if doc else "(no description)"


@lru_cache(maxsize=8)
def _installed_entry_points(search_path: tuple[str, ...]) -> tuple:
    """The entry points of :data:`ENTRY_POINT_GROUP` of the distributions on ``search_path`` (``sys.path``),
    read once per search path: reading every distribution's metadata took about 7 ms, and every run
    of a built-in method looks for plugins of its name. A distribution installed into a folder
    already on the path while the process runs is seen by the next process."""
    return tuple(metadata.entry_points(group=ENTRY_POINT_GROUP))


def _entry_points() -> tuple:
    """:func:`_installed_entry_points` of the current ``sys.path``."""
    return _installed_entry_points(tuple(sys.path))


def plugin_methods(*, with_summary: bool = False) -> tuple[MethodInfo, ...]:
    """Methods registered by installed packages under :data:`ENTRY_POINT_GROUP`.

    Parameters
    ----------
    with_summary : bool, keyword-only
        Import each factory to read its docstring's first line (a factory
        that cannot be loaded says why instead).

    Returns
    -------
    tuple of MethodInfo
        Sorted by name; names of built-in methods are left out (the
        built-in method wins; see :func:`warn_shadowing_plugins`).
    """
    builtin = set(builtin_method_names())
    found = {}
    for ep in _entry_points():
        if ep.name in builtin or ep.name in found:
            continue
        dist = _distribution_name(ep)
        summary = ""
        if with_summary:
            try:
                summary = _first_doc_line(_load_target(ep.value, method=ep.name))
            except InputError as exc:
                summary = f"(cannot be loaded: {exc.problem})"
        found[ep.name] = MethodInfo(ep.name, ep.value, summary, f"plugin {dist}")
    return tuple(found[name] for name in sorted(found))


def _distribution_name(ep) -> str:
    """The name of the installed distribution that registers the entry point ``ep``."""
    return getattr(getattr(ep, "dist", None), "name", None) or "unknown distribution"


def warn_shadowing_plugins(names: Iterable[str] | None = None) -> None:
    """Warn, one line each, of installed plugin methods that a built-in method's name hides.

    Parameters
    ----------
    names : iterable of str, optional
        Only these method names (default: every built-in name).

    Warns
    -----
    InputWarning
        ``method orb: the plugin pkg.mod:factory of DIST has the name of a
        built-in method and is not used ...``, naming how to run it.
    """
    wanted = set(builtin_method_names()) if names is None else set(names) & set(builtin_method_names())
    for ep in _entry_points():
        if ep.name in wanted:
            warnings.warn(f"method {ep.name}: the plugin {ep.value} of {_distribution_name(ep)} has the name of a "
                          f"built-in method and is not used (the built-in {ep.name} is); run it as --method "
                          f"{ep.value}, or register it under another name", InputWarning, stacklevel=2)


def available_methods(*, with_summary: bool = False) -> tuple[MethodInfo, ...]:
    """Built-in methods, then installed plugins (see :func:`plugin_methods`)."""
    return BUILTIN_METHODS + plugin_methods(with_summary=with_summary)


def method_names() -> tuple[str, ...]:
    """Names ``--method`` accepts as they are (``package.module:factory`` is accepted too)."""
    return tuple(m.name for m in available_methods())


def _load_target(target: str, *, method: str) -> Callable:
    """The callable named ``package.module:attribute``; :class:`InputError` naming what is wrong."""
    where = f"method {method}"
    module_name, sep, attribute = target.partition(":")
    if not sep or not module_name or not attribute:
        raise InputError(where, f"expected a method name or package.module:factory, got {target!r}")
    try:
        module = importlib.import_module(module_name)
    except ModuleNotFoundError as exc:
        if exc.name and (module_name == exc.name or module_name.startswith(exc.name + ".")):
            raise InputError(where, f"module {module_name} not found") from None
        raise InputError(where, f"importing {module_name} failed: {type(exc).__name__}: "
                                f"{exc}") from None
    except Exception as exc:  # any error of a third-party module's import, reported in one line
        raise InputError(where, f"importing {module_name} failed: {type(exc).__name__}: "
                                f"{exc}") from None
    except SystemExit as exc:  # sys.exit(0) at import would end the run with status 0 and no output
        raise InputError(where, f"importing {module_name} called sys.exit({exc.code!r}); a method's "
                                "module must import without exiting") from None
    obj: Any = module
    for part in attribute.split("."):
        if not hasattr(obj, part):
            raise InputError(where, f"module {module_name} has no attribute {attribute}")
        obj = getattr(obj, part)
    if not callable(obj):
        raise InputError(where, f"{target} is not callable (got {type(obj).__name__})")
    return obj


def load_factory(method: str) -> Callable:
    """The factory ``factory(model, config) -> FrontEnd`` that ``method`` names.

    Parameters
    ----------
    method : str
        A built-in name, an installed plugin's name, or ``package.module:factory``.

    Returns
    -------
    callable

    Raises
    ------
    InputError
        Unknown name, module not found, no such attribute, or not callable.
    """
    for info in BUILTIN_METHODS:
        if info.name == method:
            warn_shadowing_plugins((method,))
            return _load_target(info.target, method=method)
    if ":" not in method:
        for info in plugin_methods():
            if info.name == method:
                return _load_target(info.target, method=method)
        raise InputError(f"method {method}", f"unknown method; expected one of "
                                             f"{', '.join(method_names())} or package.module:factory")
    return _load_target(method, method=method)


def create_front_end(method: str, model, config):
    """Front end of ``method`` for the camera ``model`` and an ``EstimateConfig``.

    A third-party factory that raises, exits, or returns a class or
    something without ``prepare`` and ``correspondences``, is reported as
    an :class:`InputError` naming the method (built-in factories' errors
    pass unchanged). A third-party front end comes back wrapped in
    :class:`~ifmi.tracking.checked_front_end.CheckedFrontEnd`, which holds what it
    returns to the contract (its rays checked against ``model``).

    Returns
    -------
    FrontEnd
    """
    from ifmi.tracking.checked_front_end import CheckedFrontEnd

    factory = load_factory(method)
    if method in builtin_method_names():
        return factory(model, config)
    where = f"method {method}"
    try:
        front_end = factory(model, config)
    except InputError:
        raise
    except SystemExit as exc:
        raise InputError(where, f"factory called sys.exit({exc.code!r}); a factory must return a front "
                                "end or raise") from None
    except Exception as exc:  # a plugin's failure, reported in one line with its method
        raise InputError(where, f"factory raised {one_line(exc)}") from None
    if isinstance(front_end, type):
        raise InputError(where, f"factory returned the class {front_end.__name__}; expected an instance "
                                f"(call it: {front_end.__name__}(...))")
    missing = [name for name in ("prepare", "correspondences")
               if not callable(getattr(front_end, name, None))]
    if missing:
        raise InputError(where, f"factory returned an object without "
                                f"{'() and '.join(missing)}(); expected prepare() and "
                                f"correspondences(), got {type(front_end).__name__}")
    return CheckedFrontEnd(front_end, method, model)


def method_sort_key(method: str) -> tuple[int, str]:
    """Report order: the built-in methods in their order, then any other name alphabetically."""
    names = builtin_method_names()
    return (names.index(method) if method in names else len(names), method)


def method_colors(methods: Iterable[str]) -> dict[str, str]:
    """Colour of each of ``methods`` in a figure.

    Built-in methods keep their fixed colours; the others take
    :data:`OTHER_COLORS` in turn, in :func:`method_sort_key` order (cycling
    when there are more of them), so the same set of methods is drawn alike
    in every figure.
    """
    fixed = {m.name: m.color for m in BUILTIN_METHODS}
    others = sorted({m for m in methods if m not in fixed}, key=method_sort_key)
    colors = {m: OTHER_COLORS[i % len(OTHER_COLORS)] for i, m in enumerate(others)}
    return {m: fixed.get(m) or colors[m] for m in methods}
