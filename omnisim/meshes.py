"""Mesh files as scene objects: the ``mesh`` generator (OBJ, PLY, STL, glTF/GLB through trimesh).

A file is read as a trimesh scene; every geometry is taken with its node
transform, in the file's units. It is placed by ``scale`` (file units to
metres), then ``rotation_deg`` = [roll, pitch, yaw] in degrees with
``R = Rz(yaw) Ry(pitch) Rx(roll)`` about the world axes (the project's ZYX
convention, :func:`ifmi.geometry.rotations.matrix_from_rpy`), then ``position``:
``p_world = R (scale p_file) + position``.

Without ``material`` each geometry keeps the file's own appearance:

* a texture image on its UVs (8-bit sRGB decoded to linear, as Mitsuba does
  for 8-bit bitmaps); colour factors beside a texture are ignored (tools
  write arbitrary ones, trimesh a grey 0.4);
* else per-vertex colours, 8-bit values mapped to [0, 1] (used as linear
  reflectance, which is what Mitsuba's own PLY loader expects; an OBJ's
  float colours, and its materials' ``Kd``, must lie in [0, 1]);
* else per-face colours (each face gets its own vertices);
* else the material's base (diffuse) colour, mapped to [0, 1];
* else mid grey (an STL file has no appearance).
"""

from __future__ import annotations

import base64
import io
import itertools
import json
import re
import stat
import struct
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ifmi.errors import InputError, InputWarning, first_line

from omnisim.generators import MAX_PLACED_REACH_M, GeneratorContext, Param, register_generator
from omnisim.materials import Appearance, MaterialSettings
from omnisim.settings import FLOAT32_MAX  # largest coordinate a mesh file may scale to: Mitsuba stores float32
from omnisim.textures import linear_texture_from_image

__all__ = ["MeshPart", "mesh_parts_from_file", "mesh_side_files"]

# Reflectance of a geometry that carries no appearance (STL).
DEFAULT_GREY = (0.5, 0.5, 0.5)
# Largest value of the 8-bit colours trimesh stores.
UINT8_MAX = 255.0
# An OBJ vertex line (its values after ``v``), and the columns of its colour values (``v x y z r g b``).
_OBJ_VERTEX_LINE = re.compile(rb"^[ \t]*v[ \t]+([^\r\n#]*)", flags=re.MULTILINE)
_OBJ_COLOUR_COLUMNS = (3, 4, 5)
# A material library's diffuse colour line (its values after ``Kd``, any case as the reader takes it).
_MTL_DIFFUSE_LINE = re.compile(rb"^[ \t]*[Kk][Dd][ \t]+([^\r\n]*)", flags=re.MULTILINE)


@dataclass(frozen=True)
class MeshPart:
    """One geometry of a mesh file, in the file's frame and units.

    positions (V, 3); faces (F, 3) int; uvs (V, 2) or None (v = 0 at the
    image's bottom row); colors (V, 3) linear RGB in [0, 1]; image
    (H, W, 3) float32 linear RGB texture or None (rows top to bottom).
    """

    positions: np.ndarray
    faces: np.ndarray
    uvs: np.ndarray | None
    colors: np.ndarray
    image: np.ndarray | None


def _material_color(material) -> np.ndarray | None:
    color = getattr(material, "main_color", None)
    if color is None:
        return None
    return np.asarray(color, dtype=np.float64)[:3] / UINT8_MAX


def _texture_part(mesh, positions, faces) -> MeshPart:
    visual = mesh.visual
    material = getattr(visual, "material", None)
    uvs = None if visual.uv is None or len(visual.uv) != len(positions) else np.asarray(visual.uv, np.float64)
    image = None
    if material is not None:
        image = getattr(material, "image", None)
        if image is None:
            image = getattr(material, "baseColorTexture", None)  # glTF materials
    base = _material_color(material) if material is not None else None
    if uvs is not None and image is not None:
        texture = linear_texture_from_image(image)
        white = np.ones_like(positions)
        return MeshPart(positions, faces, uvs, white, np.ascontiguousarray(texture, dtype=np.float32))
    color = base if base is not None else np.asarray(DEFAULT_GREY)
    return MeshPart(positions, faces, uvs, np.broadcast_to(color, positions.shape).copy(), None)


def _part(mesh) -> MeshPart:
    positions = np.asarray(mesh.vertices, dtype=np.float64)
    faces = np.asarray(mesh.faces, dtype=np.int64)
    visual = mesh.visual
    kind = getattr(visual, "kind", None)
    if kind == "texture":
        return _texture_part(mesh, positions, faces)
    if kind == "vertex":
        colors = np.asarray(visual.vertex_colors, dtype=np.float64)[:, :3] / UINT8_MAX
        return MeshPart(positions, faces, None, colors, None)
    if kind == "face":
        # Every face gets its own three vertices so its colour does not bleed into its neighbours.
        colors = np.repeat(np.asarray(visual.face_colors, dtype=np.float64)[:, :3] / UINT8_MAX, 3, axis=0)
        return MeshPart(positions[faces].reshape(-1, 3), np.arange(3 * len(faces)).reshape(-1, 3),
                        None, colors, None)
    grey = np.broadcast_to(np.asarray(DEFAULT_GREY), positions.shape).copy()
    return MeshPart(positions, faces, None, grey, None)


def mesh_parts_from_file(path) -> list[MeshPart]:
    """The triangle geometries of a mesh file with their node transforms applied.

    Parameters
    ----------
    path : str or path
        OBJ, PLY, STL, glTF or GLB file (with its material and texture files beside it).

    Returns
    -------
    list of MeshPart
        In the file's frame and units; empty geometries are left out.

    Raises
    ------
    InputError
        The file cannot be read, holds no triangles, ends before the rows
        its (PLY) header declares or names an OBJ vertex 0; or an OBJ
        vertex colour or a diffuse colour (``Kd``) of its material library
        is not a number in [0, 1] (the message names the file and line).

    Warns
    -----
    InputWarning
        An OBJ's material library (``mtllib``) or a texture it names
        (``map_Kd``), or a glTF/GLB material's base colour texture, is
        missing or holds no image: the geometry renders with the colour left.
    """
    import trimesh

    path = Path(path)
    suffix = path.suffix.lower()
    if suffix == ".obj":
        data = _bytes_or_none(path)  # one read serves both scans; an unreadable file is the reader's to report
        if data is not None:
            _check_obj_face_indices(path, data)
            libraries = _obj_material_files(path, data)  # one scan of the OBJ's lines for its side files
            _check_obj_colours(path, data, [found for _, found, _ in libraries])
            _warn_missing_obj_files(path, libraries)
    elif suffix in (".gltf", ".glb"):
        _warn_unreadable_gltf_textures(path)
    try:
        scene = trimesh.load_scene(str(path), process=False)
        meshes = scene.dump(concatenate=False)
    except Exception as exc:  # trimesh raises many kinds for a broken file
        raise InputError(path, f"cannot read mesh file ({first_line(exc)})") from None
    meshes = [m for m in meshes if isinstance(m, trimesh.Trimesh)]
    for mesh in meshes:  # before empty geometries are left out: a cut file may have no faces left
        _check_ply_rows(path, mesh)
    meshes = [m for m in meshes if len(m.faces) > 0]
    if not meshes:
        raise InputError(path, "mesh file holds no triangles")
    for number, mesh in enumerate(meshes):
        _check_geometry(path, number, mesh)
    return [_part(m) for m in meshes]


def _check_geometry(path: Path, number: int, mesh) -> None:
    """Refuse vertices that are not finite 3-D points and faces that name vertices the mesh lacks
    (readers pass both on: a PLY face ``3 0 1 57`` of an 8-vertex mesh rendered with exit 0)."""
    try:
        vertices = np.asarray(mesh.vertices, dtype=np.float64)
        faces = np.asarray(mesh.faces)
    except (TypeError, ValueError) as exc:  # ragged rows: a vertex line with two coordinates, ...
        raise InputError(path, f"geometry {number}: vertices or faces are no table of numbers "
                               f"({first_line(exc)})") from None
    if vertices.ndim != 2 or vertices.shape[1] != 3:
        raise InputError(path, f"geometry {number}: expected 3 coordinates per vertex, got an array of "
                               f"shape {vertices.shape}")
    bad = ~np.isfinite(vertices).all(axis=1)
    if bad.any():
        index = int(np.argmax(bad))
        raise InputError(path, f"geometry {number} vertex {index}: expected finite coordinates, "
                               f"got {vertices[index].tolist()}")
    if faces.ndim != 2 or faces.shape[1] != 3 or not np.issubdtype(faces.dtype, np.integer):
        raise InputError(path, f"geometry {number}: expected triangles of 3 vertex indices, got an array of "
                               f"shape {faces.shape} ({faces.dtype})")
    outside = (faces < 0) | (faces >= len(vertices))
    if outside.any():
        face = int(np.argmax(outside.any(axis=1)))
        raise InputError(path, f"geometry {number} face {face}: vertex indices {faces[face].tolist()}, "
                               f"expected 0 to {len(vertices) - 1} (the mesh has {len(vertices)} vertices)")
    _check_uvs(path, number, mesh)


def _check_uvs(path: Path, number: int, mesh) -> None:
    """Refuse texture coordinates that are not finite, where a geometry's texture uses them (one per
    vertex, as :func:`_texture_part` takes them): an OBJ ``vt nan 0`` rendered black texels, exit 0."""
    visual = mesh.visual
    uvs = getattr(visual, "uv", None) if getattr(visual, "kind", None) == "texture" else None
    if uvs is None or len(uvs) != len(mesh.vertices):
        return
    uvs = np.asarray(uvs, dtype=np.float64)
    bad = ~np.isfinite(uvs).all(axis=1)
    if bad.any():
        index = int(np.argmax(bad))
        raise InputError(path, f"geometry {number} vertex {index}: expected finite texture coordinates, "
                               f"got {uvs[index].tolist()}")


def _bytes_or_none(path: Path) -> bytes | None:
    """The bytes of ``path``, or None when it cannot be read."""
    try:
        return path.read_bytes()
    except OSError:
        return None


def _check_obj_face_indices(path: Path, data: bytes) -> None:
    """Refuse an OBJ whose face lines (``f`` first on the line, as the reader finds them) name index 0 in
    any form (``0``, ``0/1``, ``1/0``, ``1//0``): OBJ counts from 1, negative indices count back from the
    last, and the reader turns 0 into the last element without a word. Lone zeros are found with numpy
    (a scan takes a fraction of the reader's time) in the file's bytes ``data``; their face lines are
    then split to confirm them."""
    data = b"\n" + data + b"\n"
    text = np.frombuffer(data, dtype=np.uint8)
    zeros = np.flatnonzero(text == ord("0"))
    zeros = zeros[np.isin(text[zeros - 1], list(b" \t/")) & np.isin(text[zeros + 1], list(b" \t/\r\n#"))]
    newlines = np.flatnonzero(text == ord("\n"))
    lines = np.searchsorted(newlines, zeros) - 1  # the line of each lone zero, counted from 0
    starts = newlines[lines] + 1
    for line in np.unique(lines[(text[starts] == ord("f")) & np.isin(text[starts + 1], list(b" \t"))]):
        words = data[newlines[line] + 1:newlines[line + 1]].split(b"#")[0].split()
        if b"0" in (index for word in words[1:] for index in word.split(b"/")):
            shown = b" ".join(words).decode("utf-8", errors="replace")
            raise InputError(path, f"line {line + 1} ({shown!r}): expected face indices from 1 (OBJ counts "
                                   f"from 1, negative ones back from the last), got 0")


def _obj_vertex_colours(tails: list[bytes]) -> np.ndarray | None:
    """The colours ``(V, 3)`` on the OBJ ``v`` lines whose values are ``tails``, as the reader takes
    them: the 4th to 6th value when every ``v`` line has at least six values; else None (the reader
    then keeps no vertex colours; words that are no numbers are its to report)."""
    if not tails:
        return None
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        try:
            return np.loadtxt(tails, dtype=np.float64, usecols=_OBJ_COLOUR_COLUMNS, ndmin=2)
        except ValueError:  # a line with fewer values, or a word that is no number
            return None


def _check_obj_colours(path: Path, data: bytes, libraries: list[Path | None]) -> None:
    """Refuse colour values outside [0, 1] in the OBJ ``path`` (bytes ``data``) and its material
    ``libraries`` (the files its ``mtllib`` lines name; None for one not found).

    The reader keeps vertex colours (``v x y z r g b``, on every ``v`` line) and diffuse colours
    (``Kd r g b``) as 8-bit values: NaN became 0 and anything else was clipped to [0, 1] without a
    word (``Kd -0.3 0.5 nan`` rendered a green, 1.5 a white, exit 0). Colours are linear
    reflectances, so values outside [0, 1] are refused, naming the file and the line.
    """
    tails = _OBJ_VERTEX_LINE.findall(data)
    values = _obj_vertex_colours(tails)
    outside = np.zeros((0, 3), bool) if values is None else ~((values >= 0.0) & (values <= 1.0))  # NaN too
    if outside.any():
        row, column = (int(i) for i in np.argwhere(outside)[0])
        match = next(itertools.islice(_OBJ_VERTEX_LINE.finditer(data), row, None))
        word = tails[row].split()[_OBJ_COLOUR_COLUMNS[column]]
        _refuse_colour(path, data, match.start(), "vertex colour values", word.decode("ascii", "replace"))
    for library in libraries:
        text = _bytes_or_none(library) if library is not None else None
        if text is not None:
            _check_mtl_colours(library, text)


def _check_mtl_colours(path: Path, data: bytes) -> None:
    """Refuse ``Kd`` lines of the material library ``path`` (bytes ``data``) whose values are numbers
    outside [0, 1] (see :func:`_check_obj_colours`); a line the reader cannot parse (``Kd spectral
    f.rfl``) is the reader's to skip."""
    for match in re.finditer(_MTL_DIFFUSE_LINE, data):
        words = match.group(1).split(b"#")[0].split()
        try:
            values = [float(word) for word in words]  # as the reader parses them
        except ValueError:
            continue
        outside = [word for word, value in zip(words, values) if not 0.0 <= value <= 1.0]  # NaN too
        if outside:
            _refuse_colour(path, data, match.start(), "diffuse colour (Kd) values",
                           outside[0].decode("ascii", "replace"))


def _refuse_colour(path: Path, data: bytes, start: int, what: str, bad: str) -> None:
    """Raise the one-line error for the colour value ``bad`` on the line of ``data`` that begins at ``start``."""
    end = data.find(b"\n", start)
    shown = data[start:end if end >= 0 else len(data)].decode("utf-8", errors="replace").strip()
    line = data.count(b"\n", 0, start) + 1
    raise InputError(path, f"line {line} ({shown!r}): expected {what} in [0, 1] (linear reflectance), got {bad}")


def _check_ply_rows(path: Path, mesh) -> None:
    """Refuse a PLY file that ends before the rows its header declares: the ASCII reader keeps the rows
    that are there (a box cut after 5 of its 12 faces rendered with exit 0), or inside its last row
    (:func:`_check_ply_last_row`). Other files pass."""
    elements = mesh.metadata.get("_ply_raw") or {}  # the PLY reader's header counts and the rows it read
    rows = [(name, e["length"], _rows_read(e["data"])) for name, e in elements.items()
            if e.get("length") and "data" in e]
    if any(got < expected for _, expected, got in rows):
        declared = " and ".join(f"{expected} {name}" for name, expected, _ in rows)
        found = " and ".join(f"{got} {name}" for name, _, got in rows)
        raise InputError(path, f"expected {declared} rows (as its header says), the file ends after {found} rows")
    last = [(name, e["properties"]) for name, e in elements.items() if e.get("length") and "properties" in e]
    if last and _is_ascii_ply(path):
        _check_ply_last_row(path, *last[-1])


# Bytes at the end of an ASCII PLY file read to find its last row.
_PLY_TAIL_BYTES = 1 << 16


def _is_ascii_ply(path: Path) -> bool:
    """Whether the PLY file's header (in its first bytes) declares the ASCII format."""
    with open(path, "rb") as f:
        return b"format ascii" in f.read(256)


def _check_ply_last_row(path: Path, element: str, properties) -> None:
    """Refuse an ASCII PLY file whose last row has fewer values than its element's properties take:
    the reader drops a face cut inside its row (``3 1 3`` of ``3 1 3 2``) and renders the rest."""
    with open(path, "rb") as f:
        f.seek(max(0, f.seek(0, 2) - _PLY_TAIL_BYTES))
        lines = [line for line in f.read().split(b"\n") if line.strip()]
    tokens = lines[-1].split() if lines else []
    needed = 0
    for dtype in properties.values():
        if "$LIST" not in str(dtype):
            needed += 1
        elif needed < len(tokens):  # a count, then that many values
            try:
                needed += 1 + int(float(tokens[needed]))
            except (ValueError, OverflowError):  # not a count: the reader refuses or reads the row itself
                return
        else:
            needed += 1
    if len(tokens) < needed:
        raise InputError(path, f"its last {element} row holds {len(tokens)} of the {needed} values its "
                               "properties take: the file ends inside that row")


def _rows_read(data) -> int:
    """How many rows of a PLY element the reader read: ``data`` is a dict of columns by property (ASCII)
    or a record array (binary)."""
    return len(next(iter(data.values()), ())) if isinstance(data, dict) else len(data)


def _named_files(path: Path, keyword: str, data: bytes | None = None) -> list[tuple[str, Path | None]]:
    """``(name, file or None if missing)`` of each file that a line starting with ``keyword`` names in
    the text file ``path`` (whose bytes are ``data`` when already read), relative to it. Options come
    first (``map_Kd -s 1 1 1 wood.png``) and names may hold spaces, so every tail of the line is tried;
    a missing name is shown as the rest of the line, or its last word after options. An unreadable
    file names nothing."""
    data = _bytes_or_none(path) if data is None else data
    if data is None:
        return []
    lines = data.decode("utf-8", errors="replace").splitlines()
    named = []
    for line in lines:
        words = line.split()
        if len(words) < 2 or words[0] != keyword:
            continue
        rest = line.strip()[len(keyword):].strip()
        tails = [" ".join(words[k:]) for k in range(1, len(words))]  # the name after any options
        for tail in tails:
            _check_not_special(path, path.parent / tail)
        found = next((path.parent / n for n in tails if (path.parent / n).is_file()), None)
        named.append((words[-1] if rest.startswith("-") else rest, found))
    return named


def _check_not_special(path: Path, named: Path) -> None:
    """Refuse a side file of ``path`` that exists but is no regular file or folder: the reader would
    wait forever on a FIFO or a terminal (a material library that was a FIFO hung the render)."""
    try:
        mode = named.stat().st_mode
    except (OSError, ValueError):  # not there (or a name the OS refuses): the callers report it
        return
    if not (stat.S_ISREG(mode) or stat.S_ISDIR(mode)):
        raise InputError(path, f"names {named.name}, which is not a regular file; expected a file to read")


def _warn_missing_obj_files(path: Path, libraries: list) -> None:
    """One warning naming the material libraries and diffuse textures the OBJ ``path`` needs
    (``libraries``: :func:`_obj_material_files`) that are not there, or that are there but hold no
    image (the reader then drops them without a word)."""
    missing = []
    for library, found, textures in libraries:
        if found is None:
            missing.append(f"material library {library} not found")
            continue
        for texture, there in textures:
            problem = "not found" if there is None else _image_file_kind_problem(there)
            if problem:
                missing.append(f"texture {texture} (named by {library}) {problem}")
    _warn_left_out(path, missing)


def _obj_material_files(path: Path, data: bytes | None = None) -> list[tuple[str, Path | None,
                                                                         list[tuple[str, Path | None]]]]:
    """``(name, file or None, textures)`` of each material library (``mtllib``) an OBJ names (its bytes
    ``data`` when already read); the textures are the ``(name, file or None)`` of the diffuse maps
    (``map_Kd``) a found library names."""
    return [(library, found, _named_files(found, "map_Kd") if found is not None else [])
            for library, found in _named_files(path, "mtllib", data)]


def _gltf_file_uris(path: Path, header) -> list[str]:
    """URIs of the buffers and images a glTF/GLB header names as files beside ``path`` (not ``data:``),
    each checked to be no FIFO or device (:func:`_check_not_special`, whose InputError passes through);
    none from a header too broken to list them (the reader refuses it)."""
    try:
        uris = [item.get("uri", "") for item in header.get("buffers", []) + header.get("images", [])]
    except _GLTF_UNREADABLE:
        return []
    uris = [uri for uri in uris if isinstance(uri, str) and uri and not uri.startswith("data:")]
    for uri in uris:
        _check_not_special(path, path.parent / uri)
    return uris


def mesh_side_files(path) -> list[str]:
    """The files beside a mesh file that its reader takes pixels from, in the order it names them.

    An OBJ's material libraries (``mtllib``) and the diffuse textures they
    name (``map_Kd``); a glTF's or GLB's buffers and images given by a URI.
    Only files that are there are listed (:func:`mesh_parts_from_file` warns
    about missing ones); other mesh formats have none.

    Parameters
    ----------
    path : str or path
        The mesh file.

    Returns
    -------
    list of str
        Absolute paths, each once.

    Raises
    ------
    InputError
        A side file that is no regular file (a FIFO, a device).
    """
    path = Path(path)
    suffix = path.suffix.lower()
    found = []
    if suffix == ".obj":
        for _, library, textures in _obj_material_files(path):
            if library is not None:
                found += [library] + [texture for _, texture in textures if texture]
    elif suffix in (".gltf", ".glb"):
        try:
            header, _ = _gltf_parts(path)
        except _GLTF_UNREADABLE:
            return []  # the reader refuses the file
        for uri in _gltf_file_uris(path, header):
            found += [f for f in (path.parent / uri, path.parent / Path(uri).name) if f.is_file()][:1]
    return list(dict.fromkeys(str(f.absolute()) for f in found))


# What a glTF/GLB too broken to list its side files raises while it is read here; the reader refuses it.
_GLTF_UNREADABLE = (OSError, ValueError, LookupError, TypeError, AttributeError, struct.error)


def _warn_unreadable_gltf_textures(path: Path) -> None:
    """One warning naming the base colour textures of a glTF/GLB's materials that are missing or hold no
    image (the reader drops them without a word). A file too broken to list them is the reader's to refuse."""
    try:
        header, binary = _gltf_parts(path)
    except _GLTF_UNREADABLE:
        return
    _gltf_file_uris(path, header)
    try:
        textures = header.get("textures", [])
        used = {m["pbrMetallicRoughness"]["baseColorTexture"]["index"] for m in header.get("materials", [])
                if "baseColorTexture" in m.get("pbrMetallicRoughness", {})}
        problems = []
        for index in sorted({textures[t]["source"] for t in used if "source" in textures[t]}):
            image = header["images"][index]
            uri = image.get("uri", "")
            data = _gltf_image_bytes(path, header, binary, image)
            problem = "not found" if data is None else _image_bytes_problem(data, tga=uri.lower().endswith(".tga"))
            if problem:
                name = uri if uri and not uri.startswith("data:") else f"image {index}"
                problems.append(f"texture {name} {problem}")
    except _GLTF_UNREADABLE:
        return
    _warn_left_out(path, problems)


def _warn_left_out(path: Path, problems: list[str]) -> None:
    """One warning, from ``mesh_parts_from_file``'s caller, listing the material files and textures of
    ``path`` that are left out and why (nothing when the list is empty)."""
    if problems:
        warnings.warn(f"{path}: {', '.join(problems)}; the geometries that use "
                      f"{'it' if len(problems) == 1 else 'them'} render with their base colour or grey",
                      InputWarning, stacklevel=4)


def _gltf_parts(path: Path) -> tuple[dict, bytes]:
    """The JSON header of a glTF or GLB file and a GLB's binary chunk (``b""`` for a .gltf)."""
    data = path.read_bytes()
    if not data.startswith(b"glTF"):  # a .gltf: JSON text
        return json.loads(data), b""
    (size,) = struct.unpack_from("<I", data, 12)  # after the 12-byte file header: the JSON chunk's length, type
    return json.loads(data[20:20 + size]), data[28 + size:]  # the BIN chunk's data, after its length and type


def _gltf_image_bytes(path: Path, header: dict, binary: bytes, image: dict) -> bytes | None:
    """The bytes of a glTF ``image``: in a buffer view or at its URI (None when the file it names is not there)."""
    if "bufferView" not in image:
        return _gltf_uri_bytes(path, image["uri"])
    view = header["bufferViews"][image["bufferView"]]
    uri = header["buffers"][view["buffer"]].get("uri")
    data = binary if uri is None else _gltf_uri_bytes(path, uri)
    start = view.get("byteOffset", 0)
    return None if data is None else data[start:start + view["byteLength"]]


def _gltf_uri_bytes(path: Path, uri: str) -> bytes | None:
    """The bytes a glTF URI names, found as the reader finds them: base64 data, or a file in the folder of
    ``path`` by its name as written (not percent-decoded) or its last part (None when there is none)."""
    from trimesh.resolvers import FilePathResolver

    if "base64," in uri:
        return base64.b64decode(uri[uri.index("base64,") + len("base64,"):])
    try:
        return FilePathResolver(path).get(uri)
    except (OSError, ValueError):  # not there, or outside the folder
        return None


# Leading bytes of the image files a texture may be: PNG, JPEG, TIFF (both byte orders), BMP, GIF, TGA
# has none (so any non-empty .tga passes). WebP: a RIFF file (bytes 0-3) of form WEBP (bytes 8-11).
_IMAGE_SIGNATURES = (b"\x89PNG\r\n\x1a\n", b"\xff\xd8", b"II*\x00", b"MM\x00*", b"BM", b"GIF8")
_WEBP_RIFF, _WEBP_FORM = b"RIFF", b"WEBP"


def _image_file_kind_problem(path: Path) -> str:
    """Why the image file ``path`` will be dropped by the mesh reader ("" when it may be read)."""
    try:
        data = path.read_bytes()
    except OSError as exc:
        return f"cannot be read ({exc.strerror or exc.__class__.__name__})"
    return _image_bytes_problem(data, tga=path.suffix.lower() == ".tga")


def _image_bytes_problem(data: bytes, *, tga: bool) -> str:
    """Why the image ``data`` will be dropped by the mesh reader ("" when it may be read); a TGA
    (``tga``) has no leading signature."""
    if not data:
        return "is empty"
    webp = data.startswith(_WEBP_RIFF) and data[8:12] == _WEBP_FORM
    if not tga and not webp and not data.startswith(_IMAGE_SIGNATURES):
        return "is no image file"
    return image_open_problem(data)


def image_open_problem(data: bytes) -> str:
    """Why Pillow, which trimesh reads textures with, will not open the image ``data`` ("" when it
    will): a header it cannot parse, or a size beyond twice its ``MAX_IMAGE_PIXELS`` (a decompression
    bomb). trimesh then drops the texture; pixel data that fails later is refused by the reader."""
    from PIL import Image

    try:
        with Image.open(io.BytesIO(data)):
            return ""
    except Image.DecompressionBombError:  # raised on opening, from the header's size
        return f"is too large to be read (more than {2 * Image.MAX_IMAGE_PIXELS} pixels)"
    except Exception:  # Pillow raises many kinds for a header it cannot parse
        return "is a damaged image file"


def _planar_uvs(positions: np.ndarray) -> np.ndarray:
    """Metric UVs for a named material on a mesh without its own: (x + z, y + z) in metres."""
    return np.stack([positions[:, 0] + positions[:, 2], positions[:, 1] + positions[:, 2]], axis=1)


def _placed(ctx: GeneratorContext, positions: np.ndarray, rotation: np.ndarray, offset: np.ndarray) -> np.ndarray:
    """``R (scale p) + position`` of a part's vertices, refused when the renderer's float32 cannot hold them."""
    reach = float(np.abs(positions).max())
    if not ctx["scale"] * reach <= FLOAT32_MAX:
        ctx.fail("scale", f"expected at most {FLOAT32_MAX:.3g} / {reach:.3g} (the mesh's reach in file units; "
                          f"the renderer stores float32 metres), got {ctx['scale']:g}")
    placed = (ctx["scale"] * positions) @ rotation.T + offset
    reach = float(np.abs(placed).max())
    if not reach <= MAX_PLACED_REACH_M:
        ctx.fail("position" if np.abs(offset).max() > MAX_PLACED_REACH_M else "scale",
                 f"expected the placed mesh within {MAX_PLACED_REACH_M:.3g} m of the origin (float32 ray "
                 f"tracing loses larger surfaces), got {reach:.3g} m")
    return placed


@register_generator(
    "mesh",
    Param("file", "file", None, "OBJ, PLY, STL, glTF or GLB file, relative to the scene file", required=True),
    Param("position", "float[3]", (0.0, 0.0, 0.0), "where the file's origin goes in the world, metres"),
    Param("rotation_deg", "float[3]", (0.0, 0.0, 0.0),
          "[roll, pitch, yaw] about world x, y, z, degrees: R = Rz(yaw) Ry(pitch) Rx(roll)"),
    Param("scale", "float", 1.0, "file units to metres", minimum=1e-12),
    Param("material", "material", None, "a [materials.*] entry for the whole mesh (default: the file's own "
                                        "texture, vertex colours or base colours)"),
)
def _mesh(ctx: GeneratorContext):
    """A mesh file placed in the world, with its own appearance or a scene material."""
    from ifmi.geometry.rotations import matrix_from_rpy  # scipy: imported when a scene is built

    rotation = matrix_from_rpy(np.radians(np.asarray(ctx["rotation_deg"], dtype=np.float64)))
    offset = np.asarray(ctx["position"], dtype=np.float64)
    for k, part in enumerate(mesh_parts_from_file(ctx["file"])):
        positions = _placed(ctx, part.positions, rotation, offset)
        if ctx["material"] is not None:
            uvs = part.uvs if part.uvs is not None else _planar_uvs(positions)
            ctx.add(ctx["material"], (positions, part.faces, uvs), color=part.colors)
            continue
        name = f"mesh_{ctx.index}_{k}"
        if part.image is not None:
            appearance = Appearance(MaterialSettings(), image=part.image)
        else:
            appearance = Appearance(MaterialSettings(vertex_color=True))
        ctx.add_appearance(name, appearance)
        uvs = part.uvs if part.uvs is not None else np.zeros((len(positions), 2))
        ctx.add(name, (positions, part.faces, uvs), color=part.colors)
