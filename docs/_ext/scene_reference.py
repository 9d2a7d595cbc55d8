"""Sphinx directive ``scene-reference``: every key of a scene file, generated from the code.

The tables come from the settings dataclasses of :mod:`omnisim.config`,
:mod:`omnisim.lights`, :mod:`omnisim.materials` and :mod:`omnisim.textures`
(their ``setting(...)`` declarations: type, default, bounds, doc) and from the
generator registry of :mod:`omnisim.generators`, so the page cannot drift from
what the scene reader accepts.
"""

from __future__ import annotations

from dataclasses import MISSING, fields
from pathlib import Path

from docutils import nodes
from docutils.statemachine import StringList
from sphinx.util.docutils import SphinxDirective


def _show(value) -> str:
    if value is MISSING:
        return "required"
    if value is None:
        return "none"
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_show(v) for v in value) + "]"
    if isinstance(value, str):
        return f'"{value}"'
    return str(value)


def _bounds(metadata) -> str:
    words = []
    for sign, key in ((">=", "minimum"), (">", "above"), ("<=", "maximum")):
        bound = metadata.get(key)
        if bound is not None:
            words.append(f"{sign} {_show(bound)}")
    if metadata.get("choices"):
        words.append("one of " + ", ".join(_show(c) for c in metadata["choices"]))
    return "; ".join(words)


def _cell(text: str) -> str:
    return " ".join(str(text).split()).replace("|", "\\|") or " "


def _code(text: str) -> str:
    return f"`{_cell(text)}`" if str(text) else " "


def settings_rows(cls) -> list[str]:
    """Markdown table rows of one settings dataclass (key, type, default, bounds, meaning)."""
    from omnisim.settings import type_name
    import typing

    hints = typing.get_type_hints(cls)
    rows = []
    for f in fields(cls):
        if not f.init:
            continue
        rows.append(f"| `{f.name}` | {_cell(type_name(hints[f.name]))} | {_code(_show(f.default))} | "
                    f"{_cell(_bounds(f.metadata))} | {_cell(f.metadata.get('doc', ''))} |")
    return rows


def _table(title: str, rows: list[str], intro: str = "") -> list[str]:
    header = ["| key | type | default | bounds | meaning |", "|---|---|---|---|---|"]
    lines = [f"**`{title}`**", ""]
    if intro:
        lines += [intro, ""]
    return lines + header + rows + [""]


def scene_tables() -> list[str]:
    """Markdown of every scene-file table."""
    from omnisim import config, lights, materials, textures

    lines = []
    for section, cls in (("[scene]", config.SceneSettings), ("[render]", config.RenderSettings),
                         ("[camera]", config.CameraTable), ("[trajectory]", config.TrajectorySettings),
                         ("[capture]", config.CaptureSettings), ("[effects]", config.EffectsSettings)):
        lines += _table(section, settings_rows(cls), _cell(config.SECTIONS.get(section.strip("[]"), "")))
    for kind, cls in textures.TEXTURE_SOURCES.items():
        lines += _table(f'[textures.NAME] source = "{kind}"', settings_rows(cls), _first_line(cls))
    lines += _table("[materials.NAME]", settings_rows(materials.MaterialSettings), _first_line(materials.MaterialSettings))
    for kind, cls in lights.LIGHT_TYPES.items():
        lines += _table(f'[[lights]] type = "{kind}"', settings_rows(cls), _first_line(cls))
    return lines


def _first_line(cls) -> str:
    return _cell((cls.__doc__ or "").strip().split("\n\n")[0])


def generator_tables() -> list[str]:
    """Markdown of every registered ``[[objects]]`` generator and its parameters."""
    from omnisim.config import registered_generators

    lines = []
    for name, gen in sorted(registered_generators().items()):
        rows = []
        for p in gen.params:
            bounds = p.bounds() + [r.doc for r in gen.relations if r.key == p.name]
            default = "required" if p.required else _code(_show(p.default))
            rows.append(f"| `{p.name}` | {_cell(p.kind)} | {default} | {_cell('; '.join(bounds))} | "
                        f"{_cell(p.doc)} |")
        lines += _table(f'[[objects]] generator = "{name}"', rows, _cell(gen.doc))
    return lines


class SceneReference(SphinxDirective):
    """``scene-reference`` with the argument ``tables`` or ``generators`` (in a MyST page: the
    content is parsed as Markdown)."""

    required_arguments = 1

    def run(self):
        import omnisim

        # The page is read again whenever a module the tables come from changes.
        for path in sorted(Path(omnisim.__file__).parent.glob("*.py")):
            self.env.note_dependency(str(path))
        which = self.arguments[0]
        lines = scene_tables() if which == "tables" else generator_tables()
        container = nodes.container()
        self.state.nested_parse(StringList(lines, source="scene-reference"), self.content_offset, container)
        return container.children


def setup(app):
    app.add_directive("scene-reference", SceneReference)
    return {"version": "1", "parallel_read_safe": True, "parallel_write_safe": True}
