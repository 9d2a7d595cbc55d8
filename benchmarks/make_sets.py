"""Build the benchmark sets of ``benchmarks/sets.toml`` from the scene files, seeded and resumable.

Usage::

    python benchmarks/make_sets.py DATA                  # every set, under DATA/
    python benchmarks/make_sets.py DATA --only 'fast/*'  # the sets whose name matches (and their sources)
    python benchmarks/make_sets.py DATA --list           # the sets and how each is made

Renders go through ``omnisim render`` (a rerun resumes an interrupted render and refuses other
settings in an existing folder); subsampled, degraded and warped sets are made from their sources
after them. A set whose folder is complete is skipped. A render that overrides scene keys is
rendered from a copy of its scene file written to ``DATA/scenes/NAME.toml``, with the keys set and
the relative file names of the scene made absolute.
"""

from __future__ import annotations

import argparse
import fnmatch
import json
import re
import sys
from dataclasses import dataclass, field
from pathlib import Path

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10
    import tomli as tomllib

from ifmi.errors import InputError
from ifmi.io.atomic import atomic_write_text

ROOT = Path(__file__).resolve().parents[1]
CATALOGUE = Path(__file__).resolve().parent / "sets.toml"
# Scene keys whose value is a file name relative to the scene file.
PATH_KEYS = ("file", "kalibr", "tum", "mitsuba_xml")
# A table header of a scene file: [table] or [[array of tables]].
_HEADER = re.compile(r"^\s*\[+([^\]]+)\]+")


@dataclass(frozen=True)
class SetRecipe:
    """How one set is made: ``kind`` (render, subsample, degrade, warp), its source set and options."""

    name: str
    kind: str
    source: str | None = None
    options: dict = field(default_factory=dict)


def recipes_from_catalogue(catalogue: dict) -> list[SetRecipe]:
    """Every set of a parsed ``sets.toml``, sources before the sets made from them."""
    recipes = [SetRecipe(r["name"], "render", options={k: v for k, v in r.items() if k != "name"})
               for r in catalogue.get("render", [])]
    for kind in ("subsample", "degrade", "warp"):
        for entry in catalogue.get(kind, []):
            recipes += _expanded(kind, entry, [r.name for r in recipes])
    return recipes


def _expanded(kind: str, entry: dict, known: list[str]) -> list[SetRecipe]:
    """The sets one ``[[subsample]]``, ``[[degrade]]`` or ``[[warp]]`` entry stands for."""
    patterns = entry.get("sources", [entry.get("source")])
    sources = [name for pattern in patterns for name in known if fnmatch.fnmatchcase(name, pattern)]
    if not sources:
        raise InputError(CATALOGUE, f"{kind} {entry['name']!r}: no set matches {patterns}")
    options = {k: v for k, v in entry.items() if k not in ("name", "source", "sources", "steps", "starts")}
    out = []
    for source in sources:
        base = source.rpartition("/")[2]
        if kind != "subsample":
            out.append(SetRecipe(entry["name"].format(source=base), kind, source, options))
            continue
        for step in entry["steps"]:
            for start in entry["starts"]:
                name = entry["name"].format(source=base, step=step, start=start)
                out.append(SetRecipe(name, kind, source, {"step": step, "start": start}))
    return out


def scene_with_overrides(scene_file: Path, overrides: dict, out_file: Path) -> Path:
    """A copy of ``scene_file`` with ``"table.key" = value`` overrides set; relative file names made absolute.

    A key already in its table has its value replaced; a missing one is added at the table's top.
    """
    lines = scene_file.read_text(encoding="utf-8-sig").splitlines()
    present = _keys_by_table(lines)
    pending = dict(overrides)
    table, out = None, []
    for line in lines:
        header = _HEADER.match(line)
        if header:
            table = header.group(1).strip()
            out.append(line)
            out += [f"{key.rpartition('.')[2]} = {_toml_value(pending.pop(key))}"
                    for key in list(pending) if key.rpartition(".")[0] == table
                    and key.rpartition(".")[2] not in present.get(table, set())]
            continue
        assignment = re.match(r"^(\s*)([A-Za-z_]+)(\s*=\s*)(\"[^\"]*\"|[^#]+?)(\s*#.*)?$", line)
        if assignment and f"{table}.{assignment.group(2)}" in pending:
            value = _toml_value(pending.pop(f"{table}.{assignment.group(2)}"))
            line = f"{assignment.group(1)}{assignment.group(2)}{assignment.group(3)}{value}"
        elif assignment and assignment.group(2) in PATH_KEYS and assignment.group(4).startswith('"'):
            path = Path(json.loads(assignment.group(4)))
            if not path.is_absolute():
                line = f"{assignment.group(1)}{assignment.group(2)} = {json.dumps(str(scene_file.parent.resolve() / path))}"
        out.append(line)
    if pending:
        raise InputError(scene_file, f"no table for the overridden keys {sorted(pending)}")
    out_file.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_text(out_file, "\n".join(out) + "\n")
    return out_file


def _keys_by_table(lines: list[str]) -> dict[str, set[str]]:
    """The keys each table of a scene file's lines assigns."""
    keys: dict[str, set[str]] = {}
    table = None
    for line in lines:
        header = _HEADER.match(line)
        if header:
            table = header.group(1).strip()
            continue
        assignment = re.match(r"^\s*([A-Za-z_]+)\s*=", line)
        if assignment:
            keys.setdefault(table, set()).add(assignment.group(1))
    return keys


def _toml_value(value) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    return json.dumps(value)


def build(recipe: SetRecipe, data: Path) -> str:
    """Make one set under ``data`` (resuming or skipping a complete one); a one-line summary."""
    out = data / recipe.name
    if recipe.kind == "render":
        return _render(recipe, data, out)
    source = data / recipe.source
    if recipe.kind == "subsample":
        from subsample_dataset import subsample
        if (out / "meta.json").is_file():
            return f"{recipe.name}: done"
        return f"{recipe.name}: {subsample(source, out, recipe.options['step'], start=recipe.options['start'])} frames"
    if recipe.kind == "degrade":
        from omnisim.config import EffectsSettings
        from omnisim.degrade import degrade_dataset
        options = dict(recipe.options)
        seed, vignetting = options.pop("seed", 0), options.pop("vignetting", 0.0)
        degrade_dataset(source, out, effects=EffectsSettings(**options), seed=seed, vignetting=vignetting,
                        progress=False)
        return f"{recipe.name}: degraded"
    return _warp(recipe, source, out)


def _render(recipe: SetRecipe, data: Path, out: Path) -> str:
    from omnisim.renderer import render_dataset
    options = dict(recipe.options)
    scene = ROOT / options.pop("scene")
    overrides = options.pop("overrides", None)
    if overrides:
        scene = scene_with_overrides(scene, overrides, data / "scenes" / f"{recipe.name}.toml")
    result = render_dataset(scene, out, progress=False, **options)
    return f"{recipe.name}: {result}"


def _warp(recipe: SetRecipe, source: Path, out: Path) -> str:
    from ifmi.io.dataset import read_dataset
    from omnisim.warp import WarpSettings, warp_dataset
    data = read_dataset(source)
    warp_dataset(data.image_paths[0], data.calib_path, out, settings=WarpSettings(**recipe.options),
                 progress=False)
    return f"{recipe.name}: warped"


def needed(recipes: list[SetRecipe], patterns: list[str] | None) -> list[SetRecipe]:
    """The recipes whose name matches one of ``patterns`` (all without), with the sources they need."""
    if not patterns:
        return recipes
    by_name = {r.name: r for r in recipes}
    wanted = {r.name for r in recipes if any(fnmatch.fnmatchcase(r.name, p) for p in patterns)}
    frontier = list(wanted)
    while frontier:
        source = by_name[frontier.pop()].source
        if source is not None and source not in wanted:
            wanted.add(source)
            frontier.append(source)
    return [r for r in recipes if r.name in wanted]


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("data", help="folder that receives the sets (made if missing)")
    parser.add_argument("--only", nargs="+", metavar="PATTERN", help="sets whose name matches (fnmatch)")
    parser.add_argument("--list", action="store_true", help="name the sets and how each is made; build nothing")
    args = parser.parse_args(argv)
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    try:
        recipes = needed(recipes_from_catalogue(tomllib.loads(CATALOGUE.read_text(encoding="utf-8"))), args.only)
        if not recipes:
            raise InputError(CATALOGUE, f"no set matches {args.only}")
        for recipe in recipes:
            if args.list:
                print(f"{recipe.name:<44} {recipe.kind:<9} {recipe.source or recipe.options.get('scene')} "
                      f"{ {k: v for k, v in recipe.options.items() if k != 'scene'} }")
            else:
                print(build(recipe, Path(args.data)), flush=True)
    except InputError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
