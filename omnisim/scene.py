"""Scene construction: a validated :class:`~omnisim.config.SceneConfig` -> Mitsuba scene dict.

Geometry comes from named generators (``[[objects]]`` with ``generator = ...``),
each drawing its random layout from a generator seeded by the scene's layout
seed and the object's index, so the same file always gives the same scene.
Meshes are merged per material into a few large triangle meshes.
World frame: metres, z up.

Generators and their keys (defaults in the code):

* ``room``: size [x, y, z]; materials floor, walls, ceiling; tile.
* ``ceiling_lights``: room, grid [rows, cols], size [x, y], radiance [r, g, b].
* ``shelves``: room, count, size [width, depth, height], boards; material, books (vertex_color).
* ``tables``: count, region [x, y], clear_radius; material, legs (with a chair each).
* ``boxes``: count, region, clear_radius, size_min, size_max, z, tile; material.
* ``posters``: room, photos (scikit-image photo names).
* ``ground``: size [x, y], cells, amplitude (metres of relief), tile; material.
* ``trees``: count, distance [min, max]; trunk, canopy. ``rocks``: count, distance; material.
* ``street``: length, road_width, sidewalk_width, tile; road, sidewalk, marking.
* ``facades``: length, offset, materials (list), tile; window.
* ``cars``: count, length, lane_offset, clear_distance; material, wheels, window.
* ``poles``: spacing, length, offset; material.

Materials: ``type`` diffuse | plastic | roughplastic | conductor, with
``color = [r, g, b]``, ``texture = NAME`` (+ ``tile`` metres) or
``vertex_color = true`` (diffuse only). Lights: ``sky`` (zenith, horizon,
ground colours, scale), ``sun`` (azimuth_deg, elevation_deg, irradiance),
``constant`` (radiance).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from ifmi.errors import InputError

from .config import SceneConfig
from .geometry import (MeshGroup, box_mesh, cylinder_mesh, heightfield_mesh, quad_mesh,
                       rotation_z, sphere_mesh)
from .textures import noise_texture, texture_from_spec

__all__ = ["GENERATORS", "build_scene_dict", "sky_image"]


class _Ctx:
    """What a generator may use: its parameters, a seeded RNG and the mesh groups."""

    def __init__(self, path, index, params, rng, groups, shapes, materials):
        self.path, self.index, self.params, self.rng = path, index, params, rng
        self.groups, self.shapes, self.materials = groups, shapes, materials

    def fail(self, key, problem):
        raise InputError(self.path, f"[[objects]] #{self.index + 1} ({self.params['generator']}) {key}: {problem}")

    def get(self, key, default):
        value = self.params.get(key, default)
        if default is not None and isinstance(default, (int, float)) and not isinstance(default, bool):
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                self.fail(key, f"expected a number, got {value!r}")
            if isinstance(default, int) and int(value) != value:
                self.fail(key, f"expected an integer, got {value!r}")
            return type(default)(value)
        if isinstance(default, (list, tuple)):
            numeric = all(isinstance(v, (int, float)) for v in default)
            if not isinstance(value, (list, tuple)) or (numeric and len(value) != len(default)):
                self.fail(key, f"expected a list like {list(default)!r}, got {value!r}")
        return value

    def material(self, key, default):
        name = self.params.get(key, default)
        if name not in self.materials:
            self.fail(key, f"unknown material {name!r}")
        return name

    def group(self, material) -> MeshGroup:
        return self.groups.setdefault(material, MeshGroup())

    def add(self, material, mesh, color=(1.0, 1.0, 1.0)):
        self.group(material).add(*mesh, color=color)

    def color(self, lo=0.1, hi=0.9):
        return self.rng.uniform(lo, hi, size=3)


def _room(ctx: _Ctx):
    lx, ly, lz = ctx.get("size", [6.0, 5.0, 3.0])
    tile = ctx.get("tile", 1.0)
    hx, hy = lx / 2, ly / 2
    floor = np.array([[-hx, -hy, 0], [hx, -hy, 0], [hx, hy, 0], [-hx, hy, 0]], float)
    ceiling = floor[::-1] + [0, 0, lz]
    ctx.add(ctx.material("floor", "floor"), quad_mesh(floor, tile=tile))
    ctx.add(ctx.material("ceiling", "ceiling"), quad_mesh(ceiling, tile=tile))
    walls = [
        [[-hx, -hy, 0], [-hx, hy, 0], [-hx, hy, lz], [-hx, -hy, lz]],
        [[hx, hy, 0], [hx, -hy, 0], [hx, -hy, lz], [hx, hy, lz]],
        [[hx, -hy, 0], [-hx, -hy, 0], [-hx, -hy, lz], [hx, -hy, lz]],
        [[-hx, hy, 0], [hx, hy, 0], [hx, hy, lz], [-hx, hy, lz]],
    ]
    for wall in walls:
        ctx.add(ctx.material("walls", "walls"), quad_mesh(np.array(wall, float), tile=tile))


def _wall_slot(ctx, room, wall, offset, depth):
    """Centre and yaw of an object of ``depth`` standing against a room wall (0..3) at ``offset``."""
    hx, hy = room[0] / 2, room[1] / 2
    if wall == 0:
        return np.array([-hx + depth / 2, offset, 0.0]), math.pi / 2
    if wall == 1:
        return np.array([hx - depth / 2, offset, 0.0]), -math.pi / 2
    if wall == 2:
        return np.array([offset, -hy + depth / 2, 0.0]), 0.0
    return np.array([offset, hy - depth / 2, 0.0]), math.pi


def _shelves(ctx: _Ctx):
    room = ctx.get("room", [6.0, 5.0, 3.0])
    count = ctx.get("count", 3)
    width, depth, height = ctx.get("size", [1.2, 0.35, 2.0])
    boards = ctx.get("boards", 5)
    wood = ctx.material("material", "wood")
    books = ctx.material("books", "books")
    for k in range(count):
        wall = int(ctx.rng.integers(0, 4))
        span = (room[1] if wall < 2 else room[0]) / 2 - width / 2 - 0.1
        base, yaw = _wall_slot(ctx, room, wall, ctx.rng.uniform(-span, span), depth)
        rot = rotation_z(yaw)
        def local(p):
            return base + rot @ np.asarray(p, float)
        for side in (-1, 1):
            ctx.add(wood, box_mesh(local([side * (width / 2 - 0.01), 0, height / 2]), [0.02, depth, height], yaw=yaw))
        for b in range(boards):
            z = 0.05 + b * (height - 0.1) / max(boards - 1, 1)
            ctx.add(wood, box_mesh(local([0, 0, z]), [width, depth, 0.025], yaw=yaw))
            if b == boards - 1:
                continue
            x = -width / 2 + 0.03
            gap = (height - 0.1) / max(boards - 1, 1)
            while True:
                bw = ctx.rng.uniform(0.02, 0.06)
                if x + bw > width / 2 - 0.03:
                    break
                if ctx.rng.random() < 0.12:
                    x += bw
                    continue
                bh = ctx.rng.uniform(0.5, 0.9) * gap
                bd = ctx.rng.uniform(0.6, 0.95) * depth
                ctx.add(books, box_mesh(local([x + bw / 2, 0, z + 0.0125 + bh / 2]), [bw, bd, bh], yaw=yaw),
                        color=ctx.color(0.05, 0.85))
                x += bw


def _tables(ctx: _Ctx):
    count = ctx.get("count", 2)
    region = ctx.get("region", [4.0, 3.0])
    top = ctx.material("material", "wood")
    legs = ctx.material("legs", top)
    for _ in range(count):
        w, d = ctx.rng.uniform(0.8, 1.6), ctx.rng.uniform(0.6, 0.9)
        h = ctx.rng.uniform(0.7, 0.78)
        c = np.array([ctx.rng.uniform(-region[0] / 2, region[0] / 2), ctx.rng.uniform(-region[1] / 2, region[1] / 2), 0])
        if np.hypot(c[0], c[1]) < ctx.get("clear_radius", 1.0):
            c[:2] *= ctx.get("clear_radius", 1.0) / max(np.hypot(c[0], c[1]), 1e-6)
        yaw = ctx.rng.uniform(0, math.pi)
        rot = rotation_z(yaw)
        ctx.add(top, box_mesh(c + [0, 0, h], [w, d, 0.04], yaw=yaw), color=ctx.color(0.3, 0.8))
        for sx in (-1, 1):
            for sy in (-1, 1):
                p = c + rot @ np.array([sx * (w / 2 - 0.05), sy * (d / 2 - 0.05), h / 2])
                ctx.add(legs, box_mesh(p, [0.04, 0.04, h], yaw=yaw))
        # A chair beside the table.
        pc = c + rot @ np.array([0.0, d / 2 + 0.35, 0.0])
        ctx.add(legs, box_mesh(pc + [0, 0, 0.45], [0.45, 0.45, 0.05], yaw=yaw), color=ctx.color())
        ctx.add(legs, box_mesh(pc + rot @ np.array([0, 0.2, 0.7]), [0.45, 0.04, 0.5], yaw=yaw), color=ctx.color())


def _boxes(ctx: _Ctx):
    count = ctx.get("count", 5)
    region = ctx.get("region", [4.0, 3.0])
    size_min = ctx.get("size_min", [0.3, 0.3, 0.3])
    size_max = ctx.get("size_max", [1.0, 0.6, 1.2])
    mat = ctx.material("material", "painted")
    clear = ctx.get("clear_radius", 1.0)
    for _ in range(count):
        size = ctx.rng.uniform(size_min, size_max)
        c = np.array([ctx.rng.uniform(-region[0] / 2, region[0] / 2), ctx.rng.uniform(-region[1] / 2, region[1] / 2), 0.0])
        r = np.hypot(c[0], c[1])
        if r < clear:
            c[:2] = c[:2] / max(r, 1e-6) * clear
        c[2] = ctx.get("z", 0.0) + size[2] / 2
        ctx.add(mat, box_mesh(c, size, yaw=ctx.rng.uniform(0, math.pi), tile=ctx.get("tile", 1.0)), color=ctx.color())


def _posters(ctx: _Ctx):
    room = ctx.get("room", [6.0, 5.0, 3.0])
    photos = ctx.get("photos", ["astronaut", "coffee", "chelsea", "rocket"])
    for k, photo in enumerate(photos):
        wall = k % 4
        w = ctx.rng.uniform(0.6, 1.0)
        h = w * ctx.rng.uniform(0.7, 1.3)
        z = ctx.rng.uniform(1.2, min(2.2, room[2] - h / 2 - 0.1))
        span = (room[1] if wall < 2 else room[0]) / 2 - w / 2 - 0.1
        base, yaw = _wall_slot(ctx, room, wall, ctx.rng.uniform(-span, span), 0.02)
        rot = rotation_z(yaw)
        corners = np.array([[-w / 2, 0, -h / 2], [w / 2, 0, -h / 2], [w / 2, 0, h / 2], [-w / 2, 0, h / 2]])
        corners = corners @ rot.T + base + [0, 0, z]
        name = f"poster_{ctx.index}_{k}"
        ctx.materials[name] = {"type": "diffuse", "texture": f"{name}_tex", "_photo": photo}
        p, f, _ = quad_mesh(corners)
        ctx.add(name, (p, f, np.array([[0, 1], [1, 1], [1, 0], [0, 0]], float)))


def _ceiling_lights(ctx: _Ctx):
    """A grid of rectangular area lights facing down, merged into one emitting mesh.

    One mesh means one emitter, so the scene's emitter order (and with it the
    light-sampling pattern) cannot change between loads.
    """
    room = ctx.get("room", [6.0, 5.0, 3.0])
    rows, cols = ctx.get("grid", [2, 2])
    size = ctx.get("size", [1.2, 0.3])
    radiance = ctx.get("radiance", [6.0, 6.0, 5.5])
    name = f"lights_{ctx.index}"
    ctx.materials[name] = {"type": "diffuse", "color": [0.9, 0.9, 0.9],
                           "_emission": [float(v) for v in radiance]}
    hx, hy = size[0] / 2, size[1] / 2
    z = room[2] - 0.01
    for i in range(int(rows)):
        for j in range(int(cols)):
            x = (i + 0.5) / rows * room[0] - room[0] / 2
            y = (j + 0.5) / cols * room[1] - room[1] / 2
            # Clockwise seen from above: the face normal points down into the room.
            corners = np.array([[x - hx, y - hy, z], [x - hx, y + hy, z], [x + hx, y + hy, z], [x + hx, y - hy, z]])
            ctx.add(name, quad_mesh(corners))


def _ground(ctx: _Ctx):
    size = ctx.get("size", [60.0, 60.0])
    cells = ctx.get("cells", 64)
    amplitude = ctx.get("amplitude", 0.0)
    heights = np.zeros((cells + 1, cells + 1))
    if amplitude > 0:
        noise = noise_texture(cells + 1, seed=int(ctx.rng.integers(1 << 31)), octaves=3, base_cells=2,
                              color_a=(-1, -1, -1), color_b=(1, 1, 1))[..., 0]
        heights = amplitude * noise
        # Flatten the ground under the camera so it never sits inside a bump.
        xs = np.linspace(-size[0] / 2, size[0] / 2, cells + 1)
        r = np.hypot(*np.meshgrid(xs, xs, indexing="ij"))
        heights = heights * np.clip(r / 4.0, 0, 1) - 0.02
    ctx.add(ctx.material("material", "ground"), heightfield_mesh(size, cells=cells, heights=heights,
                                                                 tile=ctx.get("tile", 1.0)))


def _trees(ctx: _Ctx):
    count = ctx.get("count", 4)
    rmin, rmax = ctx.get("distance", [6.0, 20.0])
    bark = ctx.material("trunk", "bark")
    leaves = ctx.material("canopy", "leaves")
    for _ in range(count):
        a, r = ctx.rng.uniform(0, 2 * math.pi), ctx.rng.uniform(rmin, rmax)
        base = np.array([r * math.cos(a), r * math.sin(a), -0.05])
        h = ctx.rng.uniform(2.0, 4.0)
        ctx.add(bark, cylinder_mesh(base, radius=ctx.rng.uniform(0.1, 0.25), height=h, sections=10))
        crown = ctx.rng.uniform(1.0, 2.2)
        ctx.add(leaves, sphere_mesh(base + [0, 0, h + crown * 0.6], radius=crown, subdivisions=2,
                                    scale=(1, 1, ctx.rng.uniform(0.8, 1.3))), color=ctx.color(0.5, 1.0))


def _rocks(ctx: _Ctx):
    count = ctx.get("count", 3)
    rmin, rmax = ctx.get("distance", [3.0, 12.0])
    mat = ctx.material("material", "stone")
    for _ in range(count):
        a, r = ctx.rng.uniform(0, 2 * math.pi), ctx.rng.uniform(rmin, rmax)
        s = ctx.rng.uniform(0.2, 0.7)
        ctx.add(mat, sphere_mesh([r * math.cos(a), r * math.sin(a), 0.0], radius=s, subdivisions=1,
                                 scale=ctx.rng.uniform(0.6, 1.4, size=3)), color=ctx.color(0.5, 1.0))


def _street(ctx: _Ctx):
    length = ctx.get("length", 120.0)
    road_w = ctx.get("road_width", 8.0)
    walk_w = ctx.get("sidewalk_width", 3.0)
    road = np.array([[-length / 2, -road_w / 2, 0], [length / 2, -road_w / 2, 0],
                     [length / 2, road_w / 2, 0], [-length / 2, road_w / 2, 0]], float)
    ctx.add(ctx.material("road", "asphalt"), quad_mesh(road, tile=ctx.get("tile", 2.0)))
    for side in (-1, 1):
        y = side * (road_w / 2 + walk_w / 2)
        ctx.add(ctx.material("sidewalk", "pavement"), box_mesh([0, y, 0.075], [length, walk_w, 0.15], tile=1.5))
    # Lane markings.
    for x in np.arange(-length / 2, length / 2, 6.0):
        mark = np.array([[x, -0.08, 0.005], [x + 3, -0.08, 0.005], [x + 3, 0.08, 0.005], [x, 0.08, 0.005]])
        ctx.add(ctx.material("marking", "marking"), quad_mesh(mark))


def _facades(ctx: _Ctx):
    length = ctx.get("length", 120.0)
    offset = ctx.get("offset", 7.0)
    mats = ctx.get("materials", ["brick", "plaster"])
    for m in mats:
        if m not in ctx.materials:
            ctx.fail("materials", f"unknown material {m!r}")
    window = ctx.material("window", "glass")
    for side in (-1, 1):
        x = -length / 2
        while x < length / 2:
            w = ctx.rng.uniform(6.0, 14.0)
            h = ctx.rng.uniform(8.0, 22.0)
            d = 10.0
            mat = mats[int(ctx.rng.integers(0, len(mats)))]
            cy = side * (offset + d / 2)
            ctx.add(mat, box_mesh([x + w / 2, cy, h / 2], [w - 0.3, d, h], tile=ctx.get("tile", 2.0)),
                    color=ctx.color(0.6, 1.0))
            face_y = side * (offset - 0.02)
            floors = int(h // 3.2)
            cols = int(w // 2.2)
            for f in range(1, floors):
                for c in range(cols):
                    cx = x + (c + 0.5) * w / cols
                    z0 = f * 3.2 + 0.8
                    corners = np.array([[cx - 0.6, face_y, z0], [cx + 0.6, face_y, z0],
                                        [cx + 0.6, face_y, z0 + 1.4], [cx - 0.6, face_y, z0 + 1.4]])
                    if side > 0:
                        corners = corners[::-1]
                    ctx.add(window, quad_mesh(corners),
                            color=ctx.rng.uniform(0.08, 0.3) * np.array([0.8, 0.9, 1.0]))
            x += w


def _cars(ctx: _Ctx):
    count = ctx.get("count", 6)
    length = ctx.get("length", 60.0)
    lane = ctx.get("lane_offset", 2.6)
    paint = ctx.material("material", "car_paint")
    tyre = ctx.material("wheels", "rubber")
    glass = ctx.material("window", "glass")
    for _ in range(count):
        x = ctx.rng.uniform(-length / 2, length / 2)
        if abs(x) < ctx.get("clear_distance", 4.0):
            x = math.copysign(ctx.get("clear_distance", 4.0) + abs(x), x if x != 0 else 1.0)
        y = lane * (1 if ctx.rng.random() < 0.5 else -1)
        yaw = 0.0 if y > 0 else math.pi
        color = ctx.color(0.05, 0.9)
        L, W = ctx.rng.uniform(3.8, 4.8), ctx.rng.uniform(1.7, 1.9)
        ctx.add(paint, box_mesh([x, y, 0.65], [L, W, 0.7], yaw=yaw), color=color)
        ctx.add(paint, box_mesh([x - 0.2, y, 1.25], [L * 0.55, W * 0.92, 0.5], yaw=yaw), color=color)
        ctx.add(glass, box_mesh([x - 0.2, y, 1.25], [L * 0.57, W * 0.8, 0.42], yaw=yaw), color=(0.4, 0.4, 0.45))
        for sx in (-1, 1):
            for sy in (-1, 1):
                ctx.add(tyre, box_mesh([x + sx * L * 0.33, y + sy * W * 0.45, 0.32], [0.64, 0.22, 0.64], yaw=yaw))


def _poles(ctx: _Ctx):
    spacing = ctx.get("spacing", 15.0)
    length = ctx.get("length", 120.0)
    offset = ctx.get("offset", 5.0)
    mat = ctx.material("material", "metal")
    for side in (-1, 1):
        for x in np.arange(-length / 2 + ctx.rng.uniform(0, spacing), length / 2, spacing):
            base = [x, side * offset, 0.0]
            ctx.add(mat, cylinder_mesh(base, radius=0.08, height=6.0, sections=10))
            ctx.add(mat, box_mesh([x, side * (offset - 0.6), 6.0], [0.4, 1.4, 0.15]))


GENERATORS = {
    "room": _room, "shelves": _shelves, "tables": _tables, "boxes": _boxes, "posters": _posters,
    "ceiling_lights": _ceiling_lights, "ground": _ground, "trees": _trees, "rocks": _rocks,
    "street": _street, "facades": _facades, "cars": _cars, "poles": _poles,
}


def sky_image(*, zenith, horizon, ground, width: int = 256) -> np.ndarray:
    """Latitude-longitude sky, ``(width/2, width, 3)`` float32: row 0 is straight up (linear RGB)."""
    height = width // 2
    elevation = (0.5 - (np.arange(height) + 0.5) / height) * math.pi
    t = np.clip(np.sin(elevation), 0, 1)[:, None] ** 0.5
    sky = (1 - t) * np.asarray(horizon)[None, :] + t * np.asarray(zenith)[None, :]
    sky = np.where((elevation < 0)[:, None], np.asarray(ground)[None, :], sky)
    return np.ascontiguousarray(np.repeat(sky[:, None, :], width, axis=1).astype(np.float32))


def _bsdf(mi, name, spec, textures, tex_images, path):
    kind = spec.get("type", "diffuse")
    if "_photo" in spec:
        from .textures import photo_texture
        image = photo_texture(spec["_photo"])
        reflectance = {"type": "bitmap", "bitmap": mi.Bitmap(image), "raw": True,
                       "filter_type": "bilinear", "wrap_mode": "clamp"}
    elif "texture" in spec:
        tile = float(spec.get("tile", 1.0))
        reflectance = {"type": "bitmap", "bitmap": mi.Bitmap(tex_images[spec["texture"]]), "raw": True,
                       "filter_type": "bilinear", "wrap_mode": "repeat",
                       "to_uv": mi.ScalarTransform4f().scale([1.0 / tile, 1.0 / tile, 1.0])}
    elif spec.get("vertex_color", False):
        reflectance = {"type": "mesh_attribute", "name": "vertex_color"}
    else:
        value = spec.get("color", [0.5, 0.5, 0.5])
        if not (isinstance(value, list) and len(value) == 3):
            raise InputError(path, f"[materials.{name}] color: expected [r, g, b], got {value!r}")
        reflectance = {"type": "rgb", "value": [float(v) for v in value]}
    if kind == "diffuse":
        return {"type": "diffuse", "reflectance": reflectance}
    if kind in ("plastic", "roughplastic"):
        if spec.get("vertex_color", False):
            raise InputError(path, f"[materials.{name}] vertex_color: only works with type = 'diffuse'")
        out = {"type": kind, "diffuse_reflectance": reflectance}
        if kind == "roughplastic":
            out["alpha"] = float(spec.get("roughness", 0.2))
        return out
    if kind == "conductor":
        return {"type": "conductor", "material": spec.get("conductor", "Al")}
    raise InputError(path, f"[materials.{name}] type: expected diffuse, plastic, roughplastic or "
                           f"conductor, got {kind!r}")


def _mesh(mi, name, group: MeshGroup, bsdf, emission=None):
    positions, faces, uvs, colors = group.arrays()
    props = mi.Properties()
    props["bsdf"] = mi.load_dict({"type": "twosided", "bsdf": bsdf})
    if emission is not None:
        props["emitter"] = mi.load_dict({"type": "area", "radiance": {"type": "rgb", "value": list(emission)}})
    mesh = mi.Mesh(name, len(positions), len(faces), has_vertex_normals=False,
                   has_vertex_texcoords=True, props=props)
    params = mi.traverse(mesh)
    params["vertex_positions"] = mi.Float(positions.astype(np.float32).ravel())
    params["faces"] = mi.UInt32(faces.astype(np.uint32).ravel())
    params["vertex_texcoords"] = mi.Float(uvs.astype(np.float32).ravel())
    mesh.add_attribute("vertex_color", 3, mi.Float(colors.astype(np.float32).ravel()))
    params.update()
    return mesh


def _light(mi, spec, index, path):
    kind = spec.get("type")
    if kind == "sky":
        image = sky_image(zenith=spec.get("zenith", [0.25, 0.45, 0.9]),
                          horizon=spec.get("horizon", [0.8, 0.85, 0.95]),
                          ground=spec.get("ground", [0.3, 0.3, 0.3]))
        # The lat-long map's pole is Mitsuba's +y axis; turn it to the world's +z.
        return {"type": "envmap", "bitmap": mi.Bitmap(image), "scale": float(spec.get("scale", 1.0)),
                "to_world": mi.ScalarTransform4f().rotate([1, 0, 0], 90)}
    if kind == "sun":
        az, el = math.radians(spec.get("azimuth_deg", 40.0)), math.radians(spec.get("elevation_deg", 45.0))
        direction = [-math.cos(el) * math.cos(az), -math.cos(el) * math.sin(az), -math.sin(el)]
        return {"type": "directional", "direction": direction,
                "irradiance": {"type": "rgb", "value": list(spec.get("irradiance", [3.0, 2.9, 2.7]))}}
    if kind == "constant":
        return {"type": "constant", "radiance": {"type": "rgb", "value": list(spec.get("radiance", [0.2, 0.2, 0.2]))}}
    raise InputError(path, f"[[lights]] #{index + 1} type: expected sky, sun or constant, got {kind!r}")


def build_scene_dict(config: SceneConfig, mi, *, sensor: dict) -> dict:
    """Mitsuba scene dict of a scene file, with the given sensor entry.

    Parameters
    ----------
    config : SceneConfig
    mi : module
        Imported Mitsuba with its variant set.
    sensor : dict
        Sensor entry (e.g. from :func:`omnisim.sensor.sensor_dict`).
    """
    path = Path(config.path)
    materials = {name: dict(spec) for name, spec in config.materials.items()}
    groups: dict[str, MeshGroup] = {}
    shapes: dict[str, dict] = {}
    for index, params in enumerate(config.objects):
        generator = GENERATORS.get(params.get("generator"))
        if generator is None:
            raise InputError(path, f"[[objects]] #{index + 1} generator: expected one of "
                                   f"{', '.join(GENERATORS)}, got {params.get('generator')!r}")
        rng = np.random.default_rng([config.layout_seed, index])
        ctx = _Ctx(path, index, params, rng, groups, shapes, materials)
        try:
            generator(ctx)
        except InputError:
            raise
        except (TypeError, ValueError, IndexError) as exc:
            raise InputError(path, f"[[objects]] #{index + 1} ({params.get('generator')}): "
                                   f"bad parameter ({exc})") from None
    tex_images = {}
    for name, spec in config.textures.items():
        try:
            tex_images[name] = texture_from_spec(spec, seed=config.layout_seed)
        except (KeyError, ValueError, TypeError) as exc:
            raise InputError(path, f"[textures.{name}]: {exc}") from None
    scene = {
        "type": "scene",
        "integrator": {"type": "path", "max_depth": int(config.render.max_depth), "hide_emitters": False},
        "sensor": sensor,
    }
    for name, group in sorted(groups.items()):
        try:
            bsdf = _bsdf(mi, name, materials[name], config.textures, tex_images, path)
            scene[f"mesh_{name}"] = _mesh(mi, name, group, bsdf, emission=materials[name].get("_emission"))
        except (TypeError, ValueError, RuntimeError) as exc:
            if isinstance(exc, InputError):
                raise
            raise InputError(path, f"[materials.{name}]: {str(exc).splitlines()[0]}") from None
    for name, shape in shapes.items():
        scene[name] = shape
    for index, spec in enumerate(config.lights):
        # Instantiated one by one, in file order, so the emitter order never changes.
        try:
            scene[f"light_{index}"] = mi.load_dict(_light(mi, spec, index, path), parallel=False)
        except (TypeError, ValueError, RuntimeError) as exc:
            if isinstance(exc, InputError):
                raise
            raise InputError(path, f"[[lights]] #{index + 1}: {str(exc).splitlines()[0]}") from None
    return scene
