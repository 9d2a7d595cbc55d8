"""Geometry generators of ``[[objects]]``: one registry, one decorator, declared parameters.

A generator is a function ``f(ctx)`` that adds triangle meshes to a scene
through a :class:`GeneratorContext`. It is registered with
:func:`register_generator`, which declares every parameter it reads
(:class:`Param`: name, type, default, doc), so a scene file's ``[[objects]]``
table is checked before anything is rendered: unknown keys, values of the
wrong type or out of the declared bounds (sizes, counts up to
:data:`MAX_COUNT`, ``[low, high]`` ranges, non-empty lists of choices),
bounds one parameter has from others (:class:`Relation`), unknown materials,
photographs and missing files are one-line errors naming the object and the
key. ``omnisim generators`` prints the registry with the bounds
(:func:`describe_generators`).

Parameter types: ``int``, ``float``, ``bool``, ``str``, ``float[N]`` /
``int[N]`` (N numbers), ``str[]`` (a list of strings), ``material`` and
``material[]`` (names of ``[materials.*]`` entries), ``photo[]`` (bundled
photographs) and ``file`` (a path relative to the scene file, which must exist).
"""

from __future__ import annotations

import re
import textwrap
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Mapping

import numpy as np

from ifmi.errors import InputError

from .geometry import MeshGroup
from .materials import Appearance
from .settings import SettingError, check_bounds, check_value
from .textures import BUNDLED_PHOTOS

__all__ = ["Param", "Relation", "Generator", "GeneratorContext", "ObjectSpec", "MAX_COUNT", "MAX_ENTRY_TRIANGLES",
           "MAX_PLACED_REACH_M",
           "register_generator", "registered_generators", "object_from_table", "not_below",
           "describe_generators"]

# Largest number of objects one [[objects]] entry may make (a count, the lights of a grid, the
# poles of a row...). Book shelves, the heaviest objects, are about 1,300 triangles each (a box
# is 12, a tree 360), so this many make about 13 million triangles: at about 330 bytes a triangle
# while the meshes are built here, plus about 200 in Mitsuba (float32 vertices, indices, BVH),
# some 7 GiB -- what a 24 GiB machine holds beside the film, the textures and a second such
# entry. Building them takes minutes, where a mistyped count of 10^8 would never finish.
MAX_COUNT = 10_000
# Largest number of triangles one [[objects]] entry may make, whatever multiplies up to it (shelves
# x boards x books, a long street's poles, a mesh file): MAX_COUNT of the heaviest object, about
# 13 million triangles and 7 GiB while built (see above), with room for a detailed mesh file.
MAX_ENTRY_TRIANGLES = 20_000_000
# Largest coordinate of any generated or placed geometry, metres. Measured: a floor 2 m under the
# camera renders right up to a half-width of 2e9 m, black from 4e9 m and not at all from 4e18 m,
# with no error from Mitsuba; half the largest good size is allowed.
MAX_PLACED_REACH_M = 1e9
# Largest error of a texture lookup that float32 texture coordinates may cause, in texels. The
# renderer interpolates a hit's texture coordinates in float32 over its triangle, so they are off
# by about 2^-24 of the triangle's span in texture repeats, however exactly its vertices store
# them. Measured on a flat ground of 64 cells under a camera 1.3 m up (512 px grass photo, 64 px
# images, 4 spp) against the same texture on a 60 m ground: equal to PNG's rounding up to 0.012
# texel (400 repeats across a cell), 0.9 % of the pixels off by up to 3 levels at 0.024 and 19 %
# by up to 11 at 0.098; the texture is noise from about 1 texel (a 2e7 m ground of 512 cells).
# Storing each cell's coordinates wrapped to its own repeat (in float64, then cast) changed none
# of these. Chosen between the last clean and the first deviating measurement.
MAX_TEXEL_ERROR = 1.0 / 64.0
# Relative step of float32 numbers (half their machine epsilon): a coordinate's rounding error.
FLOAT32_STEP = 2.0 ** -24
# Triangles whose texture span is measured at once (a bounded temporary array).
SPAN_CHUNK_TRIANGLES = 1 << 20

_SCALAR_TYPES = {"int": int, "float": float, "bool": bool, "str": str, "material": str, "file": str}
_LIST_TYPES = {"str[]": str, "material[]": str, "photo[]": str}


@dataclass(frozen=True)
class Param:
    """One declared parameter of a generator.

    name : key in the ``[[objects]]`` table; kind : type name (see the module
    doc); default : value when the key is absent (``None``: absent means
    "not given", the generator decides); doc : one line with the unit;
    minimum, maximum : inclusive bounds of a number or of each number of a
    list; required : the key must be given; above : exclusive lower bound
    (sizes: ``above=0.0``); ordered : a ``float[2]`` / ``int[2]`` is a
    ``[low, high]`` range, ``low <= high``; nonempty : a list must name at
    least one item (a list of choices).
    """

    name: str
    kind: str
    default: Any
    doc: str
    minimum: float | None = None
    required: bool = False
    above: float | None = None
    maximum: float | None = None
    ordered: bool = False
    nonempty: bool = False

    def __post_init__(self):
        vector = _vector_kind(self.kind)
        if self.kind not in _SCALAR_TYPES and self.kind not in _LIST_TYPES and not vector:
            raise ValueError(f"parameter {self.name}: unknown type {self.kind!r}")
        if self.required and self.default is not None:
            raise ValueError(f"parameter {self.name}: a required parameter has no default")
        if self.ordered and (vector is None or vector[1] != 2):
            raise ValueError(f"parameter {self.name}: only a pair (float[2], int[2]) is an ordered range")
        if self.nonempty and self.kind not in _LIST_TYPES:
            raise ValueError(f"parameter {self.name}: only a list ({', '.join(_LIST_TYPES)}) can be non-empty")
        self.check(self.default)  # a declaration whose default does not fit is a bug of the generator

    def check(self, value):
        """``value`` checked against the declared type and bound, normalised (lists become tuples)."""
        if value is None:
            return None
        vector = _vector_kind(self.kind)
        if vector is not None:
            element, count = vector
            value = check_value(tuple[(element,) * count], value, self.name)
        elif self.kind in _LIST_TYPES:
            value = check_value(tuple[str, ...], value, self.name)
        else:
            value = check_value(_SCALAR_TYPES[self.kind], value, self.name)
        check_bounds(value, self.name, minimum=self.minimum, maximum=self.maximum, above=self.above)
        if self.ordered and value[0] > value[1]:
            raise SettingError(self.name, f"expected [low, high] with low <= high, got {list(value)}")
        if self.nonempty and not value:
            raise SettingError(self.name, "expected at least one name, got []")
        return value

    def bounds(self) -> list[str]:
        """The declared bounds in words, as ``omnisim generators`` lists them (e.g. ``["> 0.0"]``)."""
        words = [f"{sign} {_show(bound)}" for sign, bound in
                 ((">=", self.minimum), (">", self.above), ("<=", self.maximum)) if bound is not None]
        if self.ordered:
            words.append("low <= high")
        if self.nonempty:
            words.append("at least one")
        return words


def _vector_kind(kind: str):
    match = re.fullmatch(r"(int|float)\[(\d+)\]", kind)
    if match is None:
        return None
    return (int if match.group(1) == "int" else float), int(match.group(2))


@dataclass(frozen=True)
class Relation:
    """A bound of one parameter that depends on other parameters of the same object.

    key : the parameter the bound is on (named in the error); doc : the bound
    in words, listed by ``omnisim generators`` (e.g. ``"<= half the diagonal
    of region"``); expected : function of the object's checked parameters (a
    mapping) returning None when they fit, else what was expected, with this
    object's numbers (e.g. ``"<= 2.5 (half the diagonal of region [4.0, 3.0])"``).
    """

    key: str
    doc: str
    expected: Callable[[Mapping], str | None]


def not_below(key: str, other: str) -> Relation:
    """The :class:`Relation` "each number of ``key`` >= the same number of ``other``".

    Parameters
    ----------
    key : str
        The upper end of a range given as two parameters (e.g. ``size_max``), named in the error.
    other : str
        Its lower end (e.g. ``size_min``), a parameter of as many numbers.

    Returns
    -------
    Relation
    """

    def expected(params: Mapping) -> str | None:
        high, low = params[key], params[other]
        if all(h >= lo for h, lo in zip(high, low)):
            return None
        return f">= {other} = {list(low)} element by element"

    return Relation(key, f">= {other} element by element", expected)


@dataclass(frozen=True)
class Generator:
    """A registered generator: its name, function, one-paragraph doc, declared parameters and relations."""

    name: str
    function: Callable
    doc: str
    params: tuple
    relations: tuple = ()


# The registry filled by register_generator (module state by design: generators
# register themselves when their module is imported).
_REGISTRY: dict[str, Generator] = {}


def register_generator(name: str, *params: Param, relations=()):
    """Decorator registering ``f(ctx)`` as the ``[[objects]]`` generator ``name``.

    Parameters
    ----------
    name : str
        The value of ``generator = ...`` in a scene file.
    *params : Param
        Every key the generator reads; any other key in a table is an error.
    relations : sequence of Relation, keyword-only
        Bounds between parameters, checked (in this order) once every parameter is.

    Returns
    -------
    callable
        The decorator; it returns the function unchanged.
    """
    names = [p.name for p in params]
    if len(set(names)) != len(names) or "generator" in names:
        raise ValueError(f"generator {name}: duplicate or reserved parameter names {names}")
    unknown = [r.key for r in relations if r.key not in names]
    if unknown:
        raise ValueError(f"generator {name}: relations on undeclared parameters {unknown}")

    def decorate(function):
        if name in _REGISTRY:
            raise ValueError(f"generator {name!r} is already registered")
        doc = textwrap.dedent(function.__doc__ or "").strip().split("\n\n")[0].replace("\n", " ")
        _REGISTRY[name] = Generator(name=name, function=function, doc=doc, params=tuple(params),
                                    relations=tuple(relations))
        return function

    return decorate


def registered_generators() -> dict[str, Generator]:
    """The registered generators by name (the built-in ones once :mod:`omnisim.config` is imported)."""
    return dict(_REGISTRY)


@dataclass(frozen=True)
class ObjectSpec:
    """A checked ``[[objects]]`` entry: its position in the file, generator and complete parameters."""

    index: int
    generator: str
    params: Mapping

    def where(self) -> str:
        return f"[[objects]] #{self.index + 1} ({self.generator})"


def object_from_table(table: Mapping, *, index: int, path, materials) -> ObjectSpec:
    """Check one ``[[objects]]`` table against its generator's declaration.

    Parameters
    ----------
    table : mapping
        The table, with ``generator`` and the generator's keys.
    index : int, keyword-only
        0-based position in the file.
    path : path, keyword-only
        The scene file (named in errors; ``file`` parameters are relative to it).
    materials : collection of str, keyword-only
        Names of the scene's ``[materials.*]`` entries.

    Raises
    ------
    InputError
        Unknown generator or key, a value of the wrong type or range (its own
        or one set by other parameters), an unknown material or photograph, or
        a missing file.
    """
    path = Path(path)
    where = f"[[objects]] #{index + 1}"
    if not isinstance(table, Mapping):
        raise InputError(path, f"{where}: expected a table")
    name = table.get("generator")
    if name not in _REGISTRY:
        raise InputError(path, f"{where} generator: expected one of {', '.join(sorted(_REGISTRY))}, "
                               f"got {name!r}")
    gen = _REGISTRY[name]
    where = f"{where} ({name})"
    accepted = [p.name for p in gen.params]
    for key in table:
        if key != "generator" and key not in accepted:
            raise InputError(path, f"{where} {key}: unknown key; accepted keys: "
                                   f"{', '.join(['generator'] + accepted)}")
    params = {}
    for p in gen.params:
        if p.required and p.name not in table:
            raise InputError(path, f"{where} {p.name}: missing (required)")
        try:
            value = p.check(table.get(p.name, p.default))
        except SettingError as exc:
            raise InputError(path, f"{where} {exc.key}: {exc.problem}") from None
        params[p.name] = _resolve(p, value, path=path, where=where, materials=materials)
    for relation in gen.relations:
        expected = relation.expected(params)
        if expected is not None:
            value = params[relation.key]
            raise InputError(path, f"{where} {relation.key}: expected {expected}, "
                                   f"got {list(value) if isinstance(value, tuple) else value!r}")
    return ObjectSpec(index=index, generator=name, params=params)


def _resolve(p: Param, value, *, path: Path, where: str, materials):
    if value is None:
        return None
    if p.kind in ("material", "material[]"):
        for name in (value if isinstance(value, tuple) else (value,)):
            if name not in materials:
                known = ", ".join(sorted(materials)) or "none defined"
                raise InputError(path, f"{where} {p.name}: unknown material {name!r} ([materials.*]: {known})")
    if p.kind == "photo[]":
        for name in value:
            if name not in BUNDLED_PHOTOS:
                raise InputError(path, f"{where} {p.name}: unknown photo {name!r}; expected one of "
                                       f"{', '.join(BUNDLED_PHOTOS)}")
    if p.kind == "file":
        resolved = Path(value) if Path(value).is_absolute() else (path.parent / value).absolute()
        if not resolved.is_file():
            raise InputError(path, f"{where} {p.name}: file not found: {resolved}")
        return str(resolved)
    return value


def _largest_uv_span(uvs: np.ndarray, faces: np.ndarray) -> float:
    """The largest difference of one texture coordinate (u or v) between two vertices of one triangle."""
    largest = 0.0
    for start in range(0, len(faces), SPAN_CHUNK_TRIANGLES):
        a, b, c = (uvs[faces[start:start + SPAN_CHUNK_TRIANGLES, corner]] for corner in range(3))
        largest = max(largest, float(np.abs(a - b).max()), float(np.abs(b - c).max()), float(np.abs(c - a).max()))
    return largest


class GeneratorContext:
    """What a generator may use: its checked parameters, a seeded RNG and the scene's meshes.

    ``ctx[name]`` is a declared parameter (its default when absent).
    Meshes are added per appearance name with :meth:`add`; new appearances
    (a photograph, a file's texture, an emitter) with :meth:`add_appearance`.
    """

    def __init__(self, spec: ObjectSpec, *, path, rng: np.random.Generator, groups: dict,
                 appearances: dict, texture_sides: Mapping[str, int] | None = None):
        self.spec, self.path, self.rng = spec, Path(path), rng
        self.index = spec.index
        self.groups, self.appearances = groups, appearances
        self.texture_sides = dict(texture_sides or {})  # [textures.*] name -> larger side, pixels
        self.triangles = 0  # made so far, bounded by MAX_ENTRY_TRIANGLES

    def __getitem__(self, name: str):
        return self.spec.params[name]

    def fail(self, key: str, problem: str):
        """Raise the one-line :class:`InputError` of a bad parameter ``key``."""
        raise InputError(self.path, f"{self.spec.where()} {key}: {problem}")

    def add(self, appearance: str, mesh, color=(1.0, 1.0, 1.0)) -> None:
        """Append ``mesh = (positions, faces, uvs)`` to the group of ``appearance`` with ``color``.

        Raises InputError once the entry's meshes exceed :data:`MAX_ENTRY_TRIANGLES` triangles, or
        when a vertex lies farther than :data:`MAX_PLACED_REACH_M` from the origin (or is not finite),
        or when a triangle spans so many repeats of its appearance's texture that float32 texture
        coordinates miss its texels by more than :data:`MAX_TEXEL_ERROR` (:meth:`_check_texture_span`).
        """
        self.triangles += len(mesh[1])
        if self.triangles > MAX_ENTRY_TRIANGLES:
            raise InputError(self.path, f"{self.spec.where()}: makes more than {MAX_ENTRY_TRIANGLES} triangles; "
                                        "expected fewer (lower its counts or sizes, or split the mesh file)")
        reach = float(np.abs(mesh[0]).max()) if len(mesh[0]) else 0.0
        if not reach <= MAX_PLACED_REACH_M:
            raise InputError(self.path, f"{self.spec.where()}: expected geometry within {MAX_PLACED_REACH_M:.3g} m "
                                        f"of the origin (float32 ray tracing loses larger surfaces; lower its "
                                        f"sizes or distances), got {reach:.3g} m")
        self._check_texture_span(appearance, mesh)
        self.groups.setdefault(appearance, MeshGroup()).add(*mesh, color=color)

    def _repeating_texture(self, appearance: str) -> tuple[str, int, float] | None:
        """``(what, side in pixels, repeat length in texture coordinates)`` of the texture that
        repeats over ``appearance``'s meshes, or None (a colour, or a photograph clamped to them)."""
        look = self.appearances.get(appearance)
        if look is None or look.photo:
            return None
        if look.image is not None:
            side = int(max(look.image.shape[:2]))
            return f"its own texture image ({side} px)", side, 1.0
        texture = look.material.texture
        if not texture or texture not in self.texture_sides:
            return None
        side = self.texture_sides[texture]
        return f"texture {texture!r} ({side} px) of [materials.{appearance}]", side, look.material.tile

    def _check_texture_span(self, appearance: str, mesh) -> None:
        """Refuse a mesh one of whose triangles spans more than ``MAX_TEXEL_ERROR / (FLOAT32_STEP *
        side)`` repeats of its repeating texture of ``side`` pixels: the renderer's float32
        interpolation would scramble the texture there (a textured ground of 2e9 m, the largest
        allowed, rendered noise with exit 0)."""
        texture = self._repeating_texture(appearance)
        _, faces, uvs = mesh
        if texture is None or uvs is None or not len(faces):
            return
        what, side, tile = texture
        span = _largest_uv_span(np.asarray(uvs, dtype=np.float64), np.asarray(faces)) / tile
        limit = MAX_TEXEL_ERROR / (FLOAT32_STEP * side)
        if not span <= limit:
            raise InputError(self.path, f"{self.spec.where()}: one triangle spans {span:.3g} repeats of {what}, "
                                        f"expected at most {limit:.3g} (the renderer interpolates "
                                        f"texture coordinates in float32, which then miss the texels by more "
                                        f"than 1/{1 / MAX_TEXEL_ERROR:g} of one); use smaller triangles (more "
                                        "cells, smaller sizes) or a larger tile")

    def add_appearance(self, name: str, appearance: Appearance) -> None:
        """Declare a generated appearance (the name should include the object's index).

        Raises InputError when ``name`` is already taken (e.g. by a ``[materials.*]`` entry).
        """
        if name in self.appearances:
            self.fail("generator", f"the appearance {name!r} it makes clashes with an existing one "
                                   f"(rename [materials.{name}])")
        self.appearances[name] = appearance

    def color(self, lo: float = 0.1, hi: float = 0.9) -> np.ndarray:
        """A random linear RGB colour, each channel uniform in [lo, hi)."""
        return self.rng.uniform(lo, hi, size=3)


def describe_generators() -> str:
    """Text listing every registered generator with its doc and parameters (type, default, bounds, doc)."""
    lines = []
    for name in sorted(_REGISTRY):
        gen = _REGISTRY[name]
        lines.append(f"{name}: {gen.doc}")
        for p in gen.params:
            default = "required" if p.required else f"default {_show(p.default)}"
            bounds = p.bounds() + [r.doc for r in gen.relations if r.key == p.name]
            lines.append(f"    {p.name} ({', '.join([p.kind, default] + bounds)}): {p.doc}")
        lines.append("")
    return "\n".join(lines).rstrip() + "\n"


def _show(value) -> str:
    if value is None:
        return "none"
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_show(v) for v in value) + "]"
    if isinstance(value, str):
        return repr(value)
    return str(value)
