"""Mesh files as scene objects: the ``mesh`` generator (OBJ, PLY, STL, glTF/GLB through trimesh).

A file is read as a trimesh scene; every geometry is taken with its node
transform, in the file's units. It is placed by ``scale`` (file units to
metres), then ``rotation_deg`` = [roll, pitch, yaw] in degrees with
``R = Rz(yaw) Ry(pitch) Rx(roll)`` about the world axes (the project's ZYX
convention, :func:`ifmi.rotations.matrix_from_rpy`), then ``position``:
``p_world = R (scale p_file) + position``.

Without ``material`` each geometry keeps the file's own appearance:

* a texture image on its UVs (8-bit sRGB decoded to linear, as Mitsuba does
  for 8-bit bitmaps); colour factors beside a texture are ignored (tools
  write arbitrary ones, trimesh a grey 0.4);
* else per-vertex colours, 8-bit values mapped to [0, 1] (used as linear
  reflectance, which is what Mitsuba's own PLY loader expects);
* else per-face colours (each face gets its own vertices);
* else the material's base (diffuse) colour, mapped to [0, 1];
* else mid grey (an STL file has no appearance).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ifmi.errors import InputError, InputWarning

from .generators import GeneratorContext, Param, register_generator
from .materials import Appearance, MaterialSettings
from .settings import FLOAT32_MAX  # largest coordinate a placed mesh may have: Mitsuba stores float32
from .textures import linear_texture_from_image

__all__ = ["MeshPart", "mesh_parts_from_file"]

# Reflectance of a geometry that carries no appearance (STL).
DEFAULT_GREY = (0.5, 0.5, 0.5)
# Largest value of the 8-bit colours trimesh stores.
UINT8_MAX = 255.0


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
        The file cannot be read or holds no triangles.

    Warns
    -----
    InputWarning
        An OBJ's material library (``mtllib``) or a texture it names
        (``map_Kd``) is missing: the geometry renders with the colour left.
    """
    import trimesh

    path = Path(path)
    if path.suffix.lower() == ".obj":
        _warn_missing_obj_files(path)
    try:
        scene = trimesh.load_scene(str(path), process=False)
        meshes = scene.dump(concatenate=False)
    except Exception as exc:  # trimesh raises many kinds for a broken file
        first = str(exc).splitlines()[0] if str(exc) else exc.__class__.__name__
        raise InputError(path, f"cannot read mesh file ({first})") from None
    meshes = [m for m in meshes if isinstance(m, trimesh.Trimesh) and len(m.faces) > 0]
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
                               f"({str(exc).splitlines()[0]})") from None
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


def _named_files(path: Path, keyword: str) -> list[tuple[str, Path | None]]:
    """``(name, file or None if missing)`` of each file that a line starting with ``keyword`` names in
    the text file ``path``, relative to it. Options come first (``map_Kd -s 1 1 1 wood.png``) and
    names may hold spaces, so every tail of the line is tried; a missing name is shown as the rest
    of the line, or its last word after options. An unreadable file names nothing."""
    try:
        lines = path.read_bytes().decode("utf-8", errors="replace").splitlines()
    except OSError:
        return []
    named = []
    for line in lines:
        words = line.split()
        if len(words) < 2 or words[0] != keyword:
            continue
        rest = line.strip()[len(keyword):].strip()
        tails = [" ".join(words[k:]) for k in range(1, len(words))]  # the name after any options
        found = next((path.parent / n for n in tails if (path.parent / n).is_file()), None)
        named.append((words[-1] if rest.startswith("-") else rest, found))
    return named


def _warn_missing_obj_files(path: Path) -> None:
    """One warning naming the material libraries and diffuse textures an OBJ needs that are not there,
    or that are there but hold no image (the reader then drops them without a word)."""
    missing = []
    for library, found in _named_files(path, "mtllib"):
        if found is None:
            missing.append(f"material library {library} not found")
            continue
        for texture, there in _named_files(found, "map_Kd"):
            problem = "not found" if there is None else _image_file_kind_problem(there)
            if problem:
                missing.append(f"texture {texture} (named by {library}) {problem}")
    if missing:
        warnings.warn(f"{path}: {', '.join(missing)}; the geometries that use "
                      f"{'it' if len(missing) == 1 else 'them'} render with their base colour or grey",
                      InputWarning, stacklevel=3)


# Leading bytes of the image files a texture may be: PNG, JPEG, TIFF (both byte orders), BMP, GIF, TGA
# has none (so any non-empty .tga passes).
_IMAGE_SIGNATURES = (b"\x89PNG\r\n\x1a\n", b"\xff\xd8", b"II*\x00", b"MM\x00*", b"BM", b"GIF8")


def _image_file_kind_problem(path: Path) -> str:
    """Why ``path`` is no image file by its first bytes ("" when it may be one)."""
    try:
        with open(path, "rb") as f:
            head = f.read(8)
    except OSError as exc:
        return f"cannot be read ({exc.strerror or exc.__class__.__name__})"
    if not head:
        return "is empty"
    if path.suffix.lower() != ".tga" and not head.startswith(_IMAGE_SIGNATURES):
        return "is no image file"
    return _image_size_problem(path)


def _image_size_problem(path: Path) -> str:
    """Why the mesh reader will refuse to decode ``path`` for its size ("" when it will decode it):
    Pillow, which trimesh reads textures with, stops at twice its ``MAX_IMAGE_PIXELS`` (a
    decompression bomb) and trimesh then drops the texture."""
    from PIL import Image

    try:
        with Image.open(path):
            return ""
    except Image.DecompressionBombError:  # raised on opening, from the header's size
        return f"is too large to be read (more than {2 * Image.MAX_IMAGE_PIXELS} pixels)"
    except Exception:  # any other error of Pillow's is the reader's to report
        return ""


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
    if not float(np.abs(placed).max()) <= FLOAT32_MAX:
        ctx.fail("position", f"expected the placed mesh within {FLOAT32_MAX:.3g} m of the origin (the renderer "
                             f"stores float32), got {list(ctx['position'])}")
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
    from ifmi.rotations import matrix_from_rpy  # scipy: imported when a scene is built

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
