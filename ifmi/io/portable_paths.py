"""Machine paths made portable in the files a report keeps (its ``report.json`` and ``data/``).

An evaluation records the absolute paths of its dataset, ground truth and
estimate, and a sweep the resolved dataset folder of every cell; copied into
a report that is committed or shared, they would name folders of one
machine. A :class:`PortablePaths` rewrites every absolute path: one below
the working folder becomes relative to it (``out/demo/data/office``); any
other becomes relative to the deepest folder that holds all of them
(``site_a/office``, ``site_b/office``), so data sets of one name in two
places stay apart and every file names a path the same way.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path

from ifmi.io.atomic import atomic_write_bytes, atomic_write_json

__all__ = ["PortablePaths", "absolute_paths_in", "read_json_or_none"]


def absolute_paths_in(value) -> set[str]:
    """Every string of a JSON value that is an absolute path."""
    if isinstance(value, str):
        return {value} if "\n" not in value and os.path.isabs(value) else set()
    if isinstance(value, dict):
        value = list(value.values())
    if isinstance(value, list):
        return set().union(*(absolute_paths_in(v) for v in value)) if value else set()
    return set()


def read_json_or_none(path: Path):
    """The JSON value of ``path``, or None when it is no JSON (its own reader names that problem)."""
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except (UnicodeDecodeError, ValueError, RecursionError, OSError):
        return None


@dataclass(frozen=True)
class PortablePaths:
    """Rewrites absolute paths relative to ``base`` (the working folder) or to ``root``.

    Attributes
    ----------
    base : Path
        Paths below it become relative to it.
    root : Path
        The deepest folder holding the folders of all other paths
        (:meth:`for_paths`); they become relative to it.
    """

    base: Path
    root: Path

    @classmethod
    def for_paths(cls, paths, *, base: Path) -> "PortablePaths":
        """The rewriter of ``paths`` (absolute path strings), the working folder being ``base``."""
        outside = [Path(p).parent for p in paths if not _is_below(Path(p), base)]
        root = Path(os.path.commonpath([str(p) for p in outside])) if outside else base
        return cls(base=base, root=root)

    def path(self, text: str) -> str:
        """``text`` if it is not an absolute path, else its portable form."""
        if "\n" in text or not os.path.isabs(text):
            return text
        path = Path(text)
        for folder in (self.base, self.root):
            if _is_below(path, folder):
                return path.relative_to(folder).as_posix() or "."
        return path.name or "."

    def value(self, value):
        """A JSON value with every string that is an absolute path made portable."""
        if isinstance(value, str):
            return self.path(value)
        if isinstance(value, dict):
            return {k: self.value(v) for k, v in value.items()}
        if isinstance(value, list):
            return [self.value(v) for v in value]
        return value

    def rewrite_json_file(self, path: Path) -> None:
        """Rewrite the JSON file ``path`` with portable paths (unchanged when none, or no JSON)."""
        value = read_json_or_none(path)
        if value is not None and absolute_paths_in(value):
            atomic_write_json(path, self.value(value))

    def rewrite_table_files(self, csv_path: Path, parquet_path: Path) -> None:
        """Rewrite a sweep's ``sweep.csv`` and ``sweep.parquet`` (each optional) with portable paths."""
        import pandas as pd

        for path, read in ((csv_path, pd.read_csv), (parquet_path, pd.read_parquet)):
            if not path.is_file():
                continue
            table = read(path)
            changed = False
            for column in [c for c in table.columns if not pd.api.types.is_numeric_dtype(table[c])]:
                new = table[column].map(lambda v: self.path(v) if isinstance(v, str) else v)
                changed |= not new.equals(table[column])
                table[column] = new
            if changed:
                data = table.to_csv(index=False).encode("utf-8") if path.suffix == ".csv" \
                    else table.to_parquet(index=False)
                atomic_write_bytes(path, data)


def _is_below(path: Path, folder: Path) -> bool:
    try:
        path.relative_to(folder)
    except ValueError:
        return False
    return True
