"""Files of estimate runs and evaluations.

An estimate ``DIR/NAME.txt`` (TUM) has two side files written by
``ifmi estimate``: ``NAME.frames.csv`` (one row per frame: frame,
reference_frame, success, reason, n_correspondences, n_inliers, seconds,
diagnostics...) and ``NAME.config.json`` (method, configuration, dataset,
versions).

An evaluation folder holds::

    evaluation.json    summary statistics + where everything came from
    per_frame.csv      per-frame errors (radians), one row per associated frame
    per_frame.npz      the same arrays, lossless
    config.json        copy of the estimate run's NAME.config.json (if any)
    frames.csv         copy of the estimate run's NAME.frames.csv (if any)

Reports read these files and never recompute estimates. The folder is
written as one set (built beside it and swapped in); an existing folder is
replaced only when it is an evaluation folder (``evaluation.json`` of kind
:data:`EVALUATION_KIND`) or empty, and files of the user's in it are kept.
"""

from __future__ import annotations

import csv
import io
import json
import os
import zipfile
import zlib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ifmi.errors import InputError, OutputError
from ifmi.io.atomic import (atomic_write_bytes, atomic_write_files, atomic_write_json, atomic_write_text,
                     check_output_folder, folder_of_kind, json_text, probe_writable, remove_leftovers, utf8_bytes,
                     write_folder)
from ifmi.io.camera_file import calibration_path
from ifmi.io.config import read_json_object
from ifmi.io.evaluation_file import (check_evaluation_document, check_per_frame_arrays,
                              check_run_config)
from ifmi.io.provenance import package_versions
from ifmi.io.text_file import number_from_text, read_text_file, refuse_special_file

__all__ = [
    "EVALUATION_KIND",
    "FrameTable",
    "EstimateSideFiles",
    "EvaluationRecord",
    "side_file_paths",
    "read_frames_csv",
    "read_run_config",
    "read_estimate_side_files",
    "write_evaluation",
    "read_evaluation",
    "is_evaluation_dir",
    "is_own_evaluation_dir",
    "jsonable",
    "check_estimate_outputs",
    "frames_csv_text",
    "write_estimate_run",
    "write_motion_flow",
    "read_motion_flow",
]

# Marker stored in evaluation.json so that folders can be recognised.
EVALUATION_KIND = "ifmi-evaluation"
# First comment of an estimate's TUM file; an existing file that starts so may be replaced by a new run.
ESTIMATE_HEADER = "ifmi estimate"
# Entries of an evaluation folder that a new evaluation replaces (anything else in it is
# kept). A report's copy of an evaluation also holds the motion-flow sample computed for
# it, which belongs to the estimate evaluated before.
EVALUATION_FILES = ("evaluation.json", "per_frame.csv", "per_frame.npz", "config.json",
                    "frames.csv", "motion_flow.npz")
# Columns every frames.csv must have (contract of ``ifmi estimate``).
REQUIRED_FRAME_COLUMNS = ("frame", "success", "seconds")


@dataclass(frozen=True)
class FrameTable:
    """Per-frame records of an estimate run.

    Attributes
    ----------
    columns : dict of str -> (F,) ndarray
        Every column of ``frames.csv``; numeric columns as float arrays,
        ``success`` as bool, others as object (str) arrays.
    """

    columns: dict = field(default_factory=dict)

    @property
    def frame(self) -> np.ndarray:
        return self.columns["frame"].astype(np.int64)

    @property
    def success(self) -> np.ndarray:
        return self.columns["success"]

    @property
    def seconds(self) -> np.ndarray:
        return self.columns["seconds"]

    @property
    def reference_frame(self) -> np.ndarray | None:
        col = self.columns.get("reference_frame")
        return None if col is None else col

    def __len__(self) -> int:
        return len(self.columns["frame"])


@dataclass(frozen=True)
class EstimateSideFiles:
    """What ``ifmi estimate`` wrote beside a TUM file (each part optional)."""

    frames: FrameTable | None
    config: dict | None
    frames_path: Path
    config_path: Path


@dataclass(frozen=True)
class EvaluationRecord:
    """An evaluation folder read back.

    Attributes
    ----------
    path : Path
        The folder.
    meta : dict
        Content of ``evaluation.json`` (``summary``, ``method``, ``dataset``, ...).
    arrays : dict of str -> ndarray
        Per-frame arrays from ``per_frame.npz``.
    config : dict or None
        The estimate run's configuration.
    frames : FrameTable or None
        The estimate run's per-frame records.
    """

    path: Path
    meta: dict
    arrays: dict
    config: dict | None
    frames: FrameTable | None

    @property
    def summary(self) -> dict:
        return self.meta["summary"]

    @property
    def method(self) -> str:
        return str(self.meta.get("method") or "unknown")

    @property
    def scene(self) -> str:
        return str(self.meta.get("scene") or "unknown")


def side_file_paths(estimate_path: str | os.PathLike) -> tuple[Path, Path]:
    """``(NAME.frames.csv, NAME.config.json)`` beside ``DIR/NAME.txt``."""
    p = Path(estimate_path)
    stem = p.with_suffix("") if p.suffix else p
    return stem.with_name(stem.name + ".frames.csv"), stem.with_name(stem.name + ".config.json")


def _parse_bool(path, line: int, text: str) -> bool:
    t = text.strip().lower()
    if t in ("1", "true", "yes", "y", "ok"):
        return True
    if t in ("0", "false", "no", "n", "failed"):
        return False
    raise InputError(path, f"line {line}: column success: expected true/false or 1/0, got {text!r}")


def read_frames_csv(path: str | os.PathLike) -> FrameTable:
    """Read an estimate run's ``frames.csv``.

    An empty (or ``nan``) ``seconds`` field is a frame whose time was not
    recorded (NaN in :attr:`FrameTable.seconds`); an empty
    ``reference_frame`` is a frame without a reference.

    Raises
    ------
    InputError
        Missing or unreadable file, missing required column, a column
        named twice, a row of the
        wrong length, a ``frame`` that is not a whole number from 0 to
        ``2**63 - 1`` (a 64-bit frame index), a
        ``reference_frame`` that is not a whole number, or a
        ``seconds`` value that is not a time >= 0, or ``seconds`` whose total
        overflows (each naming the line).
    """
    path = Path(path)
    # A byte-order mark (spreadsheets and Windows editors write one) is skipped, not a column name.
    text = read_text_file(path, what="frames file", encoding="utf-8-sig")
    # Comment lines are read as empty lines so that the reader's line numbers are the file's.
    reader = csv.reader("\n" if line.startswith("#") else line for line in io.StringIO(text))
    numbered = [(reader.line_num, row) for row in reader if row]
    if not numbered:
        raise InputError(path, "empty frames file (expected a header line)")
    header = [h.strip() for h in numbered[0][1]]
    repeated = next((h for k, h in enumerate(header) if h in header[:k]), None)
    if repeated is not None:  # the later column would silently replace the earlier one
        raise InputError(path, f"line {numbered[0][0]}: column {repeated} given twice; expected each "
                               "column once")
    missing = [c for c in REQUIRED_FRAME_COLUMNS if c not in header]
    if missing:
        raise InputError(path, f"missing column(s) {', '.join(missing)}; got {', '.join(header)}")
    lines, body = [n for n, _ in numbered[1:]], [row for _, row in numbered[1:]]
    for number, row in zip(lines, body):
        if len(row) != len(header):
            raise InputError(path, f"line {number}: expected {len(header)} fields, got {len(row)}")
    columns: dict[str, np.ndarray] = {}
    for j, name in enumerate(header):
        values = [row[j] for row in body]
        if name == "success":
            columns[name] = np.array([_parse_bool(path, n, v) for n, v in zip(lines, values)],
                                     dtype=bool)
        elif name in _CHECKED_FRAME_COLUMNS:
            columns[name] = _checked_column(path, name, lines, values)
            if name == "seconds":
                _check_total_time(path, lines, columns[name])
        else:
            columns[name] = _optional_numeric_column(values)
    return FrameTable(columns=columns)


def _parse_number(text: str) -> float:
    """The number of a CSV field; an empty field is NaN (raises ValueError when not a number)."""
    return number_from_text(text) if text.strip() != "" else np.nan


def _optional_numeric_column(values: list[str]) -> np.ndarray:
    """A float array when every field is a number or empty, otherwise the strings."""
    try:
        return np.array([_parse_number(v) for v in values], dtype=np.float64)
    except ValueError:
        return np.array(values, dtype=object)


def _whole_number(value: float) -> bool:
    return bool(np.isfinite(value) and value == np.floor(value))


# Columns of frames.csv that evaluations read, with the values each accepts: (test, what is
# expected, whether an empty or NaN field is accepted).
_CHECKED_FRAME_COLUMNS = {
    "frame": (lambda v: _whole_number(v) and 0 <= v < 2 ** 63,
              "a frame number (a whole number from 0 to 2**63 - 1)", False),
    "reference_frame": (_whole_number, "a frame number (a whole number; empty for none)", True),
    "seconds": (lambda v: np.isfinite(v) and v >= 0,
                "a time in seconds >= 0 (empty when not recorded)", True),
}


def _checked_column(path: Path, name: str, lines: list[int], values: list[str]) -> np.ndarray:
    """A numeric column of :data:`_CHECKED_FRAME_COLUMNS`, every value checked."""
    accepts, expected, may_be_missing = _CHECKED_FRAME_COLUMNS[name]
    out = np.empty(len(values))
    for k, (number, text) in enumerate(zip(lines, values)):
        try:
            value = _parse_number(text)
        except ValueError:
            value = None
        if value is None or not (accepts(value) or (may_be_missing and np.isnan(value))):
            raise InputError(path, f"line {number}: column {name}: expected {expected}, "
                                   f"got {text!r}")
        out[k] = value
    return out


def _check_total_time(path: Path, lines: list[int], seconds: np.ndarray) -> None:
    """Refuse per-frame times whose total is past what milliseconds can show.

    Evaluations and reports give the time per frame in milliseconds; a total
    past ``float max / 1000`` seconds would make its mean or sum infinite.

    Raises
    ------
    InputError
        Naming the line at which the running total of ``seconds`` goes past that bound.
    """
    milliseconds_per_second = 1e3
    bound = np.finfo(np.float64).max / milliseconds_per_second
    with np.errstate(over="ignore"):
        total = np.cumsum(np.nan_to_num(seconds, nan=0.0))
    past = np.flatnonzero(~(total <= bound))
    if past.size:
        raise InputError(path, f"line {lines[past[0]]}: column seconds: expected times that add up "
                               f"to at most {bound:.4g} s, got a total past it at this line")


def read_run_config(path: str | os.PathLike) -> dict:
    """Read an estimate run's ``config.json``.

    Raises
    ------
    InputError
        Missing file, invalid JSON (also nested too deeply, or an integer
        of too many digits) or a JSON value that is not an object
        (:func:`~ifmi.io.config.read_json_object`).
    """
    return read_json_object(path, what="config file")


def read_estimate_side_files(estimate_path: str | os.PathLike) -> EstimateSideFiles:
    """Read the side files of an estimate where they exist (absent ones are None).

    Raises
    ------
    InputError
        A malformed side file (:func:`read_frames_csv`, :func:`read_run_config`),
        one that is a FIFO, device or socket, or a config whose ``method`` or ``dataset`` is of the wrong kind
        (:func:`~ifmi.io.evaluation_file.check_run_config`).
    """
    frames_path, config_path = side_file_paths(estimate_path)
    refuse_special_file(frames_path, what="frames file")
    refuse_special_file(config_path, what="config file")
    frames = read_frames_csv(frames_path) if frames_path.exists() else None
    config = read_run_config(config_path) if config_path.exists() else None
    if config is not None:
        check_run_config(config_path, config)
    return EstimateSideFiles(frames=frames, config=config, frames_path=frames_path,
                             config_path=config_path)


def _csv_text(arrays: dict) -> str:
    names = list(arrays)
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(names)
    n = len(next(iter(arrays.values()))) if arrays else 0
    for i in range(n):
        row = []
        for name in names:
            v = arrays[name][i]
            if isinstance(v, (np.integer, int)):
                row.append(str(int(v)))
            elif isinstance(v, (np.floating, float)):
                row.append("" if not np.isfinite(v) else repr(float(v)))
            else:
                row.append(str(v))
        writer.writerow(row)
    return buf.getvalue()


def _npz_bytes(arrays: dict) -> bytes:
    buf = io.BytesIO()
    np.savez_compressed(buf, **{k: np.asarray(v) for k, v in arrays.items()})
    return buf.getvalue()


def jsonable(obj):
    """Replace non-finite floats by None so that the JSON is standard."""
    if isinstance(obj, dict):
        return {str(k): jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [jsonable(v) for v in obj]
    if isinstance(obj, (np.floating, float)):
        return float(obj) if np.isfinite(obj) else None
    if isinstance(obj, (np.integer,)):
        return int(obj)
    if isinstance(obj, np.bool_):
        return bool(obj)
    return obj


def write_evaluation(out_dir: str | os.PathLike, *, meta: dict, arrays: dict,
                     side_files: EstimateSideFiles | None = None) -> Path:
    """Write an evaluation folder as one set.

    The files are written into a temporary folder beside ``out_dir`` that
    takes its place when complete (:func:`~ifmi.io.atomic.write_folder`):
    after a failure an earlier evaluation there is unchanged. Files of the
    user's in an earlier evaluation folder are kept.

    Parameters
    ----------
    out_dir : path
        Folder to create, or an earlier evaluation folder (or an empty
        folder) to replace. A symbolic link is written through.
    meta : dict, keyword-only
        JSON-serialisable description with at least ``summary``;
        ``kind`` is set here.
    arrays : dict of str -> (N,) ndarray, keyword-only
        Per-frame arrays, all the same length.
    side_files : EstimateSideFiles, optional, keyword-only
        Copied into the folder as ``config.json`` and ``frames.csv``.

    Returns
    -------
    Path
        ``out_dir/evaluation.json``.

    Raises
    ------
    OutputError
        ``out_dir`` is a file or an existing folder that is neither empty
        nor an evaluation folder (checked before anything is written), or
        the folder cannot be written (names ``out_dir`` and the OS reason).
    """
    out = check_output_folder(out_dir, is_own=is_own_evaluation_dir,
                              what="an evaluation folder written by ifmi evaluate")
    frames_csv = None
    if side_files is not None and side_files.frames is not None:
        try:
            frames_csv = side_files.frames_path.read_bytes()
        except OSError as exc:
            raise InputError(side_files.frames_path,
                             f"cannot read frames file ({exc.__class__.__name__})") from None
    document = jsonable(dict(meta, kind=EVALUATION_KIND))

    def fill(folder: Path) -> None:
        atomic_write_bytes(folder / "per_frame.npz", _npz_bytes(arrays))
        atomic_write_text(folder / "per_frame.csv", _csv_text(arrays))
        if side_files is not None and side_files.config is not None:
            atomic_write_json(folder / "config.json", side_files.config)
        if frames_csv is not None:
            atomic_write_bytes(folder / "frames.csv", frames_csv)
        atomic_write_json(folder / "evaluation.json", document)

    write_folder(out, fill, replaces=EVALUATION_FILES)
    return Path(out_dir) / "evaluation.json"


def is_evaluation_dir(path: str | os.PathLike) -> bool:
    """True when ``path`` is a folder holding an ``evaluation.json``."""
    return (Path(path) / "evaluation.json").is_file()


def is_own_evaluation_dir(path: str | os.PathLike) -> bool:
    """True when ``path`` holds an ``evaluation.json`` that :func:`write_evaluation` wrote.

    That is a JSON object of kind :data:`EVALUATION_KIND`; an unreadable or
    foreign ``evaluation.json`` does not count.
    """
    return folder_of_kind(path, "evaluation.json", EVALUATION_KIND)


def read_evaluation(path: str | os.PathLike) -> EvaluationRecord:
    """Read an evaluation folder written by :func:`write_evaluation`.

    Raises
    ------
    InputError
        Not an evaluation folder, or one of its files is missing or malformed:
        an ``evaluation.json`` entry that a report reads of the wrong kind
        (:func:`~ifmi.io.evaluation_file.check_evaluation_document`), a
        truncated ``per_frame.npz`` or one whose arrays do not fit the
        summary (:func:`~ifmi.io.evaluation_file.check_per_frame_arrays`).
    """
    folder = Path(path)
    doc_path = folder / "evaluation.json"
    for name in EVALUATION_FILES:
        refuse_special_file(folder / name, what="file of an evaluation")
    meta = read_run_config(doc_path) if doc_path.exists() else None
    if meta is None:
        raise InputError(folder, "not an evaluation folder (no evaluation.json)")
    if meta.get("kind") != EVALUATION_KIND:
        raise InputError(doc_path, f"not an evaluation file (kind {meta.get('kind')!r})")
    check_evaluation_document(doc_path, meta)
    arrays = _read_npz(folder / "per_frame.npz", what="per-frame arrays")
    check_per_frame_arrays(folder / "per_frame.npz", arrays,
                           associated=int(meta["summary"]["frames"]["associated"]))
    config = read_run_config(folder / "config.json") if (folder / "config.json").exists() else None
    frames = read_frames_csv(folder / "frames.csv") if (folder / "frames.csv").exists() else None
    return EvaluationRecord(path=folder, meta=meta, arrays=arrays, config=config, frames=frames)


def frames_csv_text(rows: list[dict]) -> str:
    """CSV text of per-frame rows (dicts); the header is the union of keys in first-seen order."""
    header: list[str] = []
    for row in rows:
        for key in row:
            if key not in header:
                header.append(key)
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(header)
    for row in rows:
        out = []
        for key in header:
            v = row.get(key, "")
            if isinstance(v, (bool, np.bool_)):
                out.append("true" if v else "false")
            elif isinstance(v, (float, np.floating)):
                out.append("" if not np.isfinite(v) else repr(float(v)))
            else:
                out.append(str(v))
        writer.writerow(out)
    return buf.getvalue()


def check_estimate_outputs(path: str | os.PathLike, *, dataset_dir: str | os.PathLike | None = None,
                           input_files: tuple = (), overwrite: bool = False) -> tuple[Path, Path, Path]:
    """The three files an estimate writes, checked before anything is computed.

    An earlier run's files are replaced (a run repeated into the same
    place); any other non-empty file at one of the three paths is not,
    unless ``overwrite``: it may be the user's own trajectory or notes.

    Parameters
    ----------
    path : path
        The TUM file (``DIR/NAME.txt``); a path ending in a separator names
        a folder, not a file, and is refused, as is a path without a file
        name (``""``, ``"."``).
    dataset_dir : path, optional, keyword-only
        The input dataset; no output may replace one of its files.
    input_files : tuple of path, keyword-only
        Other inputs (a video and its calibration) no output may replace.
    overwrite : bool, keyword-only
        Replace existing files that no earlier estimate wrote.

    Returns
    -------
    (Path, Path, Path)
        ``NAME.txt``, ``NAME.frames.csv``, ``NAME.config.json``.

    Raises
    ------
    OutputError
        An output would replace a file of the input dataset (compared by
        resolved path and by inode, so links count), or without ``overwrite``
        a non-empty file no estimate wrote or the side files of another
        estimate beside it (``NAME`` and ``NAME.txt``); ``path`` ends in a separator; an
        output is a folder, a device
        node, a FIFO or a socket, a regular file stands where a folder of
        its path should be, or its folder cannot be written
        (:func:`~ifmi.io.atomic.probe_writable`).
    """
    from ifmi.io.dataset import dataset_conflict

    if str(path).endswith(("/", os.sep)):
        raise OutputError(path, "expected the estimate's file path (DIR/NAME.txt), got a folder path "
                                "ending in a separator")
    if not Path(path).name:
        # "" and "." name the current folder: there is no NAME to give the side files.
        raise OutputError(repr(str(path)), "expected the estimate's file path (DIR/NAME.txt), got a path "
                                           "without a file name")
    outputs = (Path(path), *side_file_paths(path))
    for output, kind in zip(outputs, ("trajectory", "frames", "config")):
        target = probe_writable(output)
        conflict = None if dataset_dir is None else dataset_conflict(dataset_dir, target)
        for source in input_files:
            if _same_file(source, target):
                conflict = f"would replace the input file {source}"
        if conflict is not None:
            raise OutputError(output, f"{conflict}; choose another output path")
        if not overwrite and not _earlier_estimate_output(target, kind):
            raise OutputError(output, "an existing file that no estimate wrote; choose another output path "
                                      "or pass --force to replace it")
    sibling = None if overwrite else _sibling_estimate(Path(path))
    if sibling is not None:
        raise OutputError(outputs[1], f"is also the side file of the estimate {sibling} (side files are "
                                      "named without the suffix, so they would pair with both); choose "
                                      "another output path or pass --force to replace it")
    return outputs


def _sibling_estimate(path: Path) -> Path | None:
    """Another estimate's trajectory beside ``path`` with the same side files (``DIR/NAME`` for
    ``DIR/NAME.txt`` and the other way round), or ``None``."""
    stem = path.with_suffix("") if path.suffix else path
    try:
        candidates = [p for p in stem.parent.iterdir() if p.name == stem.name or p.name.startswith(f"{stem.name}.")]
    except OSError:
        return None
    for candidate in sorted(candidates):
        if (side_file_paths(candidate) == side_file_paths(path) and not _same_file(candidate, path)
                and candidate.name != path.name and candidate.is_file() and candidate.stat().st_size > 0
                and _earlier_estimate_output(candidate, "trajectory")):
            return candidate
    return None


# How much of an existing output is read to tell whether an earlier estimate wrote it.
_SNIFF_BYTES = 4096


def _earlier_estimate_output(path: Path, kind: str) -> bool:
    """Whether ``path`` may be replaced: absent, empty, or one of an earlier estimate's three files
    (``kind``: "trajectory" with the TUM header :func:`write_estimate_run` writes, "frames" with
    the per-frame CSV's first columns, "config" with the config file's keys)."""
    try:
        if not path.is_file() or path.stat().st_size == 0:
            return True
        if kind == "config":
            data = json.loads(path.read_text(encoding="utf-8"))
            return isinstance(data, dict) and {"method", "config", "versions"} <= data.keys()
        with open(path, "rb") as f:
            first = f.read(_SNIFF_BYTES).split(b"\n", 1)[0].decode("utf-8", errors="replace")
    except (OSError, UnicodeDecodeError, ValueError, RecursionError):  # RecursionError: JSON nested too deeply
        return False
    if kind == "trajectory":
        return first.startswith(f"# {ESTIMATE_HEADER}")
    return first.startswith("frame,reference_frame,success,")


def _same_file(a: str | os.PathLike, b: str | os.PathLike) -> bool:
    """Whether two paths name one existing file (through links, by inode)."""
    try:
        return os.path.samefile(a, b)
    except OSError:
        return False


def write_estimate_run(path: str | os.PathLike, estimate, *, dataset_dir: str | os.PathLike | None,
                       extra: dict | None = None, input_files: tuple = (), overwrite: bool = False) -> Path:
    """Write an estimate as ``NAME.txt`` (TUM) with ``NAME.frames.csv`` and ``NAME.config.json``.

    The three files are written as one set (:func:`~ifmi.io.atomic.atomic_write_files`):
    after a failure (full disk, permissions) the previous set is unchanged,
    never mixed with new files.

    Parameters
    ----------
    path : path
        The TUM file to write.
    estimate : ifmi.pipeline.SequenceEstimate
    dataset_dir : path or None, keyword-only
        Dataset the estimate came from (recorded in the config file with
        its calibration file, ``calib_results.txt`` or ``camera.yaml``; no
        output may replace one of its files).
    extra : dict, optional, keyword-only
        More entries for the config file (a video run records its
        ``video`` and ``calib`` here).
    input_files : tuple of path, keyword-only
        Other inputs no output may replace (see :func:`check_estimate_outputs`).
    overwrite : bool, keyword-only
        Replace files no earlier estimate wrote (see :func:`check_estimate_outputs`).

    Returns
    -------
    Path
        ``path``.

    Raises
    ------
    OutputError
        See :func:`check_estimate_outputs`; or a write failed (the user's
        path and the OS reason).
    """
    from ifmi.io.tum import format_tum

    path, frames_path, config_path = check_estimate_outputs(path, dataset_dir=dataset_dir,
                                                            input_files=input_files, overwrite=overwrite)
    config = {
        "method": estimate.method,
        "config": estimate.config.to_dict(),
        "dataset": None if dataset_dir is None else str(Path(dataset_dir).resolve()),
        "calib": None if dataset_dir is None else str(calibration_path(dataset_dir).resolve()),
        "versions": _versions(),
    }
    config.update(extra or {})
    tum = format_tum(estimate.trajectory, header=f"{ESTIMATE_HEADER}, method {estimate.method}")
    atomic_write_files({
        config_path: utf8_bytes(json_text(jsonable(config))),
        frames_path: utf8_bytes(frames_csv_text([r.to_row() for r in estimate.frames])),
        path: utf8_bytes(tum),
    })
    # Temporaries and backups of these files that a killed earlier run left beside them.
    remove_leftovers(path.parent, names={path.name, frames_path.name, config_path.name})
    return path


def _versions() -> dict:
    return package_versions(("omnisim-ifmi", "numpy", "opencv-python-headless", "poselib", "scipy"))


def write_motion_flow(path: str | os.PathLike, sample: dict) -> None:
    """Write a motion-flow sample (dict of arrays) as ``.npz`` atomically."""
    atomic_write_bytes(path, _npz_bytes(sample))


def read_motion_flow(path: str | os.PathLike) -> dict:
    """Read a motion-flow sample written by :func:`write_motion_flow`.

    Raises
    ------
    InputError
        Missing, unreadable, truncated or corrupt file, a missing array, or
        an array of another shape than :data:`MOTION_FLOW_SHAPES` gives.
    """
    path = Path(path)
    sample = _read_npz(path, what="motion-flow file")
    missing = [k for k in MOTION_FLOW_SHAPES if k not in sample and k != "frames"]
    if missing:
        raise InputError(path, f"missing array(s) {', '.join(missing)}")
    for name, shape in MOTION_FLOW_SHAPES.items():
        array = sample.get(name)
        if array is not None and not _fits(array, shape):
            wanted = "(" + ", ".join(str(n) if n else "N" for n in shape) + ")"
            raise InputError(path, f"array {name}: expected numbers of shape {wanted}, got "
                                   f"{array.dtype} of shape {array.shape}")
    for first, second in (("panorama_a", "panorama_b"), ("points_a", "points_b")):
        if sample[first].shape != sample[second].shape:
            raise InputError(path, f"{first} is {sample[first].shape}, {second} "
                                   f"{sample[second].shape}; expected the same shape")
    return sample


# Arrays of a motion-flow sample and their shapes (0: any length); ``frames`` may be absent.
MOTION_FLOW_SHAPES = {"panorama_a": (0, 0), "panorama_b": (0, 0), "points_a": (0, 2),
                      "points_b": (0, 2), "tile_centers": (0, 2), "tile_size": (), "frames": (2,)}


def _fits(array: np.ndarray, shape: tuple) -> bool:
    """Whether ``array`` holds numbers in ``shape`` (0 matching any length)."""
    return (array.dtype.kind in "biuf" and array.ndim == len(shape)
            and all(n == 0 or n == m for n, m in zip(shape, array.shape)))


# What np.load and zipfile raise on a truncated or corrupt .npz: OSError, ValueError (a bad
# header, pickled data), EOFError and BadZipFile (truncated), zlib.error (corrupt compressed
# data), NotImplementedError (an unknown zip version or compression), RuntimeError (encryption).
_NPZ_ERRORS = (OSError, ValueError, EOFError, zipfile.BadZipFile, zlib.error, NotImplementedError,
               RuntimeError)
_CORRUPT_ZIP = (zipfile.BadZipFile, EOFError, zlib.error)


def _read_npz(path: Path, *, what: str) -> dict[str, np.ndarray]:
    """All arrays of an ``.npz`` file; a missing or corrupt file is an :class:`InputError`."""
    try:
        loaded = np.load(path, allow_pickle=False)
        if not isinstance(loaded, np.lib.npyio.NpzFile):
            raise InputError(path, f"cannot read {what} (a single array; expected a NumPy .npz "
                                   "archive of named arrays)")
        with loaded as data:
            return {k: data[k] for k in data.files}
    except InputError:  # a ValueError, but already the message
        raise
    except FileNotFoundError:
        raise InputError(path, f"{what} not found") from None
    except _CORRUPT_ZIP:
        raise InputError(path, f"cannot read {what} (truncated or corrupt file; expected a NumPy "
                               ".npz archive)") from None
    except _NPZ_ERRORS as exc:
        raise InputError(path, f"cannot read {what} ({exc.__class__.__name__})") from None
