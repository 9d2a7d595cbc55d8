"""Materials: ``[materials.*]`` settings and the Mitsuba BSDF of a merged mesh's appearance.

A material is ``diffuse``, ``plastic``, ``roughplastic`` or ``conductor``,
coloured by ``color`` (linear RGB), a named ``[textures.*]`` image repeating
every ``tile`` metres, or per-vertex colours (``vertex_color = true``,
diffuse only). Generators may add appearances of their own
(:class:`Appearance`): a bundled photograph on a poster, a mesh file's own
texture image, or an emitting surface.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .settings import SettingError, check_fields, setting

__all__ = ["MATERIAL_TYPES", "MaterialSettings", "Appearance", "bsdf_dict"]

MATERIAL_TYPES = ("diffuse", "plastic", "roughplastic", "conductor")
# Shortest texture repeat length, metres, as the generators' ``tile``: texture coordinates are
# metres / tile, and a tile of 1e-30 m made them lose every texel (black pixels, exit 0).
MIN_TILE_M = 1e-6


@dataclass(frozen=True)
class MaterialSettings:
    """One ``[materials.NAME]`` table."""

    type: str = setting("diffuse", "BSDF", choices=MATERIAL_TYPES)
    color: tuple[float, float, float] = setting((0.5, 0.5, 0.5), "linear RGB reflectance",
                                                minimum=0.0, maximum=1.0)
    texture: str = setting("", "name of a [textures.*] entry (replaces color)")
    tile: float = setting(1.0, "texture repeat length, metres", minimum=MIN_TILE_M)
    vertex_color: bool = setting(False, "per-vertex colours from the generator or mesh file (diffuse only)")
    roughness: float = setting(0.2, "roughplastic: GGX roughness alpha", above=0.0, maximum=1.0)
    conductor: str = setting("Al", "conductor: Mitsuba's material name (Al, Au, Cu, ...)")

    def __post_init__(self):
        check_fields(self)
        if self.vertex_color and self.type != "diffuse":
            raise SettingError("vertex_color", f"only works with type = 'diffuse', got type = {self.type!r}")


@dataclass(frozen=True)
class Appearance:
    """How one merged mesh looks: a material plus what a generator adds.

    material : MaterialSettings;
    photo : a bundled photograph clamped onto the UV square (posters);
    image : ``(H, W, 3)`` float32 linear-RGB texture on the mesh's own UVs (image row 0 at v = 1,
    the OBJ/glTF-as-loaded-by-trimesh convention), repeating;
    emission : linear RGB radiance when the surface is an area light.
    """

    material: MaterialSettings
    photo: str = ""
    image: np.ndarray | None = None
    emission: tuple | None = None


def _reflectance(mi, appearance: Appearance, texture_images: dict) -> dict:
    material = appearance.material
    if appearance.photo:
        from .textures import photo_texture

        return {"type": "bitmap", "bitmap": mi.Bitmap(photo_texture(appearance.photo)), "raw": True,
                "filter_type": "bilinear", "wrap_mode": "clamp"}
    if appearance.image is not None:
        # Mitsuba's bitmap puts image row 0 at v = 0; the loaded UVs put it at v = 1.
        return {"type": "bitmap", "bitmap": mi.Bitmap(np.ascontiguousarray(appearance.image[::-1])),
                "raw": True, "filter_type": "bilinear", "wrap_mode": "repeat"}
    if material.texture:
        tile = material.tile
        return {"type": "bitmap", "bitmap": mi.Bitmap(texture_images[material.texture]), "raw": True,
                "filter_type": "bilinear", "wrap_mode": "repeat",
                "to_uv": mi.ScalarTransform4f().scale([1.0 / tile, 1.0 / tile, 1.0])}
    if material.vertex_color:
        return {"type": "mesh_attribute", "name": "vertex_color"}
    return {"type": "rgb", "value": [float(v) for v in material.color]}


def bsdf_dict(mi, appearance: Appearance, texture_images: dict) -> dict:
    """Mitsuba BSDF dict of an appearance.

    Parameters
    ----------
    mi : module
        Imported Mitsuba with its variant set.
    appearance : Appearance
    texture_images : dict
        ``[textures.*]`` name -> ``(H, W, 3)`` float32 linear RGB image.
    """
    material = appearance.material
    if material.type == "conductor":
        return {"type": "conductor", "material": material.conductor}
    reflectance = _reflectance(mi, appearance, texture_images)
    if material.type == "diffuse":
        return {"type": "diffuse", "reflectance": reflectance}
    out = {"type": material.type, "diffuse_reflectance": reflectance}
    if material.type == "roughplastic":
        out["alpha"] = material.roughness
    return out
