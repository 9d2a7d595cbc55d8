"""Find an LLVM that drjit's JIT can use, before drjit or Mitsuba is imported.

drjit 1.5 aborts the whole process inside LLVM 15 (Debian 12's default), so
the library is chosen here and handed to drjit through ``DRJIT_LIBLLVM_PATH``.
Search order: an explicit ``DRJIT_LIBLLVM_PATH`` (if new enough), the
``karellen-llvm-core`` wheel in ``sys.prefix/lib``, then Debian's packages.
"""

from __future__ import annotations

import glob
import importlib
import os
import re
import subprocess
import sys
from pathlib import Path

from ifmi.errors import first_line
from ifmi.runtime.interrupts import interrupts_deferred

__all__ = [
    "BackendError",
    "LlvmNotFoundError",
    "MINIMUM_LLVM_MAJOR",
    "find_llvm",
    "llvm_major_version",
    "ensure_llvm",
    "loaded_llvm",
    "cuda_available",
    "import_mitsuba",
    "main",
]

# drjit 1.5 emits intrinsics (llvm.minimum/maximum) that LLVM 15's x86 backend cannot select.
MINIMUM_LLVM_MAJOR = 16

ENV_VAR = "DRJIT_LIBLLVM_PATH"

FIX_HINT = ("install one with 'pip install karellen-llvm-core' (or 'apt-get install libllvm19'), "
            f"or point {ENV_VAR} at a libLLVM.so of version >= {MINIMUM_LLVM_MAJOR}")


class BackendError(RuntimeError):
    """Mitsuba cannot run the requested variant here; the message is one line saying why."""


class LlvmNotFoundError(BackendError):
    """No LLVM >= 16 was found; the message is one line saying how to fix it."""


def _major_from_name(path: Path) -> int | None:
    """LLVM major version read from a library file name (libLLVM-15.so, libLLVM.so.23.1)."""
    name = path.name
    for pattern in (r"libLLVM-(\d+)", r"libLLVM\.so\.(\d+)", r"llvm-(\d+)"):
        match = re.search(pattern, name)
        if match:
            return int(match.group(1))
    match = re.search(r"/llvm-(\d+)/", str(path))
    return int(match.group(1)) if match else None


# Loads the library in a child process so an incompatible LLVM never enters this one;
# LLVMGetVersion exists from LLVM 16 on, so its absence means "too old".
_PROBE = (
    "import ctypes,sys\n"
    "lib=ctypes.CDLL(sys.argv[1])\n"
    "f=getattr(lib,'LLVMGetVersion',None)\n"
    "if f is None: print(0)\n"
    "else:\n"
    " a,b,c=ctypes.c_uint(),ctypes.c_uint(),ctypes.c_uint()\n"
    " f(ctypes.byref(a),ctypes.byref(b),ctypes.byref(c)); print(a.value)\n"
)


def llvm_major_version(path: str | os.PathLike) -> int | None:
    """Major version of an LLVM shared library, or None if it cannot be loaded.

    The version is read from the file name (after resolving symlinks); a name
    without one is probed in a child process.
    """
    path = Path(path)
    if not path.is_file():
        return None
    for candidate in (path, Path(os.path.realpath(path))):
        major = _major_from_name(candidate)
        if major is not None:
            return major
    try:
        out = subprocess.run([sys.executable, "-c", _PROBE, str(path)], capture_output=True,
                             text=True, timeout=60, check=True).stdout.strip()
        return int(out)
    except (subprocess.SubprocessError, ValueError, OSError):
        return None


# Where Debian's libllvmNN packages install their shared library.
SYSTEM_GLOBS = ("/usr/lib/llvm-*/lib/libLLVM*.so*", "/usr/lib/*-linux-gnu/libLLVM-*.so*")


def _candidates(prefix: str, system_globs) -> list[Path]:
    found: list[Path] = []
    found += sorted(Path(p) for p in glob.glob(os.path.join(prefix, "lib", "libLLVM*.so*")))
    debian = []
    for pattern in system_globs:
        debian += glob.glob(pattern)
    # Newest Debian LLVM first.
    debian_paths = sorted({Path(p) for p in debian},
                          key=lambda p: (_major_from_name(p) or 0, str(p)), reverse=True)
    return found + debian_paths


def find_llvm(*, environ=None, prefix: str | None = None, system_globs=None) -> Path:
    """Path of a usable LLVM (major version >= 16).

    Parameters
    ----------
    environ : mapping, optional, keyword-only
        Environment to read ``DRJIT_LIBLLVM_PATH`` from (default ``os.environ``).
    prefix : str, optional, keyword-only
        Python prefix whose ``lib`` folder is searched (default ``sys.prefix``).
    system_globs : sequence of str, optional, keyword-only
        Glob patterns of system LLVM libraries searched last (default
        :data:`SYSTEM_GLOBS`, read when called).

    Raises
    ------
    LlvmNotFoundError
        When no library qualifies; the message says how to install one.
    """
    environ = os.environ if environ is None else environ
    prefix = sys.prefix if prefix is None else prefix
    system_globs = SYSTEM_GLOBS if system_globs is None else system_globs
    rejected = []
    explicit = environ.get(ENV_VAR)
    if explicit:
        major = llvm_major_version(explicit)
        if major is not None and major >= MINIMUM_LLVM_MAJOR:
            return Path(explicit)
        rejected.append(f"{ENV_VAR}={explicit} is "
                        + ("not a loadable LLVM" if major is None else f"LLVM {major}"))
    for path in _candidates(prefix, system_globs):
        major = llvm_major_version(path)
        if major is not None and major >= MINIMUM_LLVM_MAJOR:
            return path
    found = "; ".join(rejected) if rejected else "no LLVM >= 16 found"
    raise LlvmNotFoundError(f"drjit needs LLVM >= {MINIMUM_LLVM_MAJOR} ({found}): {FIX_HINT}")


def ensure_llvm(*, environ=None, prefix: str | None = None) -> Path:
    """Select a usable LLVM for drjit by setting ``DRJIT_LIBLLVM_PATH``; returns its path."""
    environ = os.environ if environ is None else environ
    path = find_llvm(environ=environ, prefix=prefix)
    environ[ENV_VAR] = str(path)
    return path


def loaded_llvm(maps_text: str | None = None) -> Path | None:
    """The LLVM library already mapped into this process (drjit loads one when it is imported), or None.

    Parameters
    ----------
    maps_text : str, optional
        Text of ``/proc/self/maps`` (read when not given; None where there is no such file).
    """
    if maps_text is None:
        try:
            maps_text = Path("/proc/self/maps").read_text()
        except OSError:
            return None
    for line in maps_text.splitlines():
        fields = line.split()
        if len(fields) >= 6 and re.search(r"/libLLVM[-.]", fields[-1]):
            return Path(fields[-1])
    return None


def _refuse_loaded_old_llvm(maps_text: str | None = None) -> None:
    """Raise when drjit already loaded an LLVM older than 16: choosing another one is too late then."""
    path = loaded_llvm(maps_text)
    major = None if path is None else llvm_major_version(path)
    if major is not None and major < MINIMUM_LLVM_MAJOR:
        raise LlvmNotFoundError(
            f"drjit was imported before omnisim chose its LLVM and loaded {path} (LLVM {major}), which "
            f"aborts the process on its first kernel; call omnisim.llvm.import_mitsuba() (or "
            f"ensure_llvm()) before importing drjit or mitsuba, or set {ENV_VAR} before starting Python")


def cuda_available() -> bool:
    """True when an NVIDIA driver library is present (checked without importing drjit)."""
    import ctypes.util
    if os.environ.get("CUDA_VISIBLE_DEVICES", None) in ("", "-1"):
        return False
    return ctypes.util.find_library("cuda") is not None


def _cuda_works(mi) -> str:
    """Empty when ``cuda_ad_rgb`` is set and a CUDA device computes, else the reason it does not."""
    try:
        mi.set_variant("cuda_ad_rgb")
        import drjit

        probe = drjit.cuda.Float([1.0, 2.0]) * 2.0  # fails without a working device
        drjit.eval(probe)
        return ""
    except (ImportError, AttributeError, RuntimeError) as exc:
        return first_line(exc)


def import_mitsuba(variant: str | None = None):
    """Import Mitsuba with a usable LLVM and set a vectorised variant (see :func:`_import_mitsuba`)."""
    with interrupts_deferred():
        return _import_mitsuba(variant)


def _import_mitsuba(variant: str | None = None):
    """Import Mitsuba with a usable LLVM and set a vectorised variant.

    Parameters
    ----------
    variant : str, optional
        ``llvm_ad_rgb`` or ``cuda_ad_rgb``; default ``cuda_ad_rgb`` where a
        CUDA GPU works, else ``llvm_ad_rgb``.

    Returns
    -------
    module
        The ``mitsuba`` module with the variant set.

    Raises
    ------
    ValueError
        ``variant`` is not one of the two.
    BackendError
        ``cuda_ad_rgb`` without a working CUDA device, or (as
        :class:`LlvmNotFoundError`) no LLVM >= 16 for ``llvm_ad_rgb``, or
        drjit imported earlier with an older LLVM already loaded.
    """
    if variant not in (None, "llvm_ad_rgb", "cuda_ad_rgb"):
        raise ValueError(f"expected the Mitsuba variant llvm_ad_rgb or cuda_ad_rgb, got {variant!r}")
    if variant is None and cuda_available():
        mi = importlib.import_module("mitsuba")
        if not _cuda_works(mi):
            return mi
        variant = "llvm_ad_rgb"
    variant = variant or "llvm_ad_rgb"
    if variant == "cuda_ad_rgb":
        mi = importlib.import_module("mitsuba")
        reason = _cuda_works(mi)
        if reason:
            raise BackendError(f"variant cuda_ad_rgb needs a working CUDA GPU ({reason}); "
                               "use --variant llvm_ad_rgb")
        return mi
    if "drjit" in sys.modules:
        _refuse_loaded_old_llvm()
    ensure_llvm()
    mi = importlib.import_module("mitsuba")
    if mi.variant() != variant:
        mi.set_variant(variant)
    return mi


def main(argv: list[str] | None = None) -> int:
    """Print the LLVM that drjit would use, or a one-line fix; exit status 0 or 1."""
    try:
        path = find_llvm()
    except LlvmNotFoundError as exc:
        print(f"omnisim: error: {exc}", file=sys.stderr)
        return 1
    print(f"{path} (LLVM {llvm_major_version(path)})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
