"""Write the mesh file of the example scene ``scenes/atelier.toml`` (offline, deterministic).

The file is a binary glTF (GLB) with three kinds of appearance, so the
scene exercises each way ``generator = "mesh"`` reads one:

* a room (floor, walls, ceiling) with texture images on its own UVs
  (scikit-image's bundled brick photograph on the walls, seeded noise on the
  floor), faces pointing inside;
* plinths with plain base colours;
* sculptures (deformed icospheres) with per-vertex colours.

Units are metres, z up, the floor at z = 0 and the room centred on the z axis.
Run ``python scripts/make_example_mesh.py`` (default output
``scenes/meshes/atelier.glb``); the same code always writes the same bytes.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
# Room extent x, y, z (metres) and the texture repeat lengths (metres).
ROOM = (8.0, 6.0, 3.2)
WALL_TILE, FLOOR_TILE = 2.0, 1.5
# Seed of every random choice in the file.
SEED = 21
# Texture images are this many pixels square.
TEXTURE_SIZE = 256


def _uint8_srgb(linear: np.ndarray) -> np.ndarray:
    from omnisim.effects import srgb_uint8_from_linear

    return srgb_uint8_from_linear(linear)


def _textured(positions, faces, uvs, image_uint8):
    import trimesh
    from PIL import Image

    visual = trimesh.visual.TextureVisuals(uv=uvs, image=Image.fromarray(image_uint8))
    return trimesh.Trimesh(positions, faces, visual=visual, process=False)


def _room_parts():
    """Walls (brick photo) and floor (noise) with metric UVs, ceiling with a base colour."""
    import trimesh

    from omnisim.geometry import box_mesh
    from omnisim.textures import noise_texture, photo_texture

    lx, ly, lz = ROOM
    positions, faces, uvs = box_mesh((0.0, 0.0, lz / 2), ROOM, inward=True)
    # box_mesh writes the faces in the order +x, -x, +y, -y, +z, -z, two triangles each.
    walls, ceiling, floor = faces[:8], faces[8:10], faces[10:12]
    from PIL import Image

    brick = Image.fromarray(_uint8_srgb(photo_texture("brick", tint=(0.95, 0.7, 0.55))))
    brick = np.asarray(brick.resize((TEXTURE_SIZE, TEXTURE_SIZE), Image.Resampling.LANCZOS))
    wood = _uint8_srgb(noise_texture(TEXTURE_SIZE, seed=SEED, octaves=6, base_cells=3,
                                     color_a=(0.2, 0.11, 0.05), color_b=(0.55, 0.36, 0.2)))
    parts = {
        "walls": _textured(positions, walls, uvs / WALL_TILE, brick),
        "floor": _textured(positions, floor, uvs / FLOOR_TILE, wood),
    }
    top = trimesh.Trimesh(positions, ceiling, process=False)
    top.visual = trimesh.visual.TextureVisuals(material=trimesh.visual.material.SimpleMaterial(
        diffuse=(225, 225, 220, 255)))
    parts["ceiling"] = top
    return parts


def _plinths_and_sculptures(rng: np.random.Generator):
    """Plinths (base colours) along the walls, each with a vertex-coloured sculpture on top."""
    import trimesh

    parts = {}
    lx, ly, _ = ROOM
    for k in range(6):
        side = 1 if k % 2 else -1
        x = (k // 2 - 1) * lx / 3.5
        y = side * (ly / 2 - 1.0)
        height = rng.uniform(0.6, 1.1)
        plinth = trimesh.creation.box(extents=(0.6, 0.6, height))
        plinth.apply_translation((x, y, height / 2))
        grey = int(rng.integers(150, 240))
        plinth.visual = trimesh.visual.TextureVisuals(material=trimesh.visual.material.SimpleMaterial(
            diffuse=(grey, grey, int(grey * 0.9), 255)))
        parts[f"plinth_{k}"] = plinth
        sculpture = trimesh.creation.icosphere(subdivisions=3, radius=0.3)
        sculpture.vertices *= rng.uniform(0.6, 1.4, size=3)
        sculpture.vertices += rng.normal(0.0, 0.03, size=sculpture.vertices.shape)
        sculpture.apply_translation((x, y, height + 0.35))
        t = (sculpture.vertices[:, 2] - sculpture.vertices[:, 2].min()) / np.ptp(sculpture.vertices[:, 2])
        low, high = rng.uniform(0.1, 0.9, size=3), rng.uniform(0.1, 0.9, size=3)
        colors = (255 * ((1 - t)[:, None] * low + t[:, None] * high)).astype(np.uint8)
        sculpture.visual = trimesh.visual.ColorVisuals(sculpture, vertex_colors=colors)
        parts[f"sculpture_{k}"] = sculpture
    return parts


def atelier_glb() -> bytes:
    """The GLB bytes of the example atelier."""
    import trimesh

    rng = np.random.default_rng(SEED)
    scene = trimesh.Scene()
    for name, mesh in {**_room_parts(), **_plinths_and_sculptures(rng)}.items():
        scene.add_geometry(mesh, geom_name=name, node_name=name)
    return scene.export(file_type="glb")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default=str(ROOT / "scenes" / "meshes" / "atelier.glb"),
                        help="GLB file to write (default: scenes/meshes/atelier.glb)")
    args = parser.parse_args(argv)
    from ifmi.io.atomic import atomic_write_bytes

    atomic_write_bytes(args.out, atelier_glb())
    print(args.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
