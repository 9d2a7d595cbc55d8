"""Built-in procedural generators: rooms, furniture, posters, lights, ground, nature, streets.

Each draws its random layout from the seeded generator of its context
(scene layout seed and the object's index), so the same scene file always
gives the same meshes. World frame: metres, z up. ``omnisim generators``
lists them with their parameters and bounds; parameters that could only give
an impossible layout (a shelf wider than the walls, a clear radius no place of
the region reaches) are refused with the scene file, before anything is built.
"""

from __future__ import annotations

import math

import numpy as np

from .generators import MAX_COUNT, GeneratorContext, Param, Relation, not_below, register_generator
from .geometry import box_mesh, cylinder_mesh, heightfield_mesh, quad_mesh, rotation_z, sphere_mesh
from .materials import Appearance, MaterialSettings
from .settings import MAX_RADIANCE
from .textures import noise_texture

__all__: list[str] = []

# Length kept free at either end of a wall by the shelves and posters along it, metres.
WALL_END_GAP = 0.1
# Height of the lowest board's centre above a shelf's foot, and of the highest under its top, metres.
SHELF_BOARD_INSET = 0.05
# Width of a poster, metres, and its height as a fraction of its width (uniform in these ranges).
POSTER_WIDTH = (0.6, 1.0)
POSTER_ASPECT = (0.7, 1.3)
# Height of a poster's centre above the floor, metres (lower in a room too low for the range).
POSTER_CENTRE_HEIGHT = (1.2, 2.2)
# Height kept free between a poster's top and the ceiling, metres.
CEILING_GAP = 0.1
# Smallest room extent x, y, z that holds the largest poster: its width and WALL_END_GAP at either
# end of a wall; the lowest centre, half the tallest height and CEILING_GAP. fsum rounds exactly,
# so a room of just these extents is not refused by a rounding error.
_POSTER_WALL = math.fsum([POSTER_WIDTH[1], 2 * WALL_END_GAP])
POSTER_ROOM_MIN = (_POSTER_WALL, _POSTER_WALL,
                   math.fsum([POSTER_CENTRE_HEIGHT[0], POSTER_WIDTH[1] * POSTER_ASPECT[1] / 2, CEILING_GAP]))
# Width of one building of the facades, metres (uniform in this range).
FACADE_WIDTH = (6.0, 14.0)
# Period of the dashed lane markings along the street, metres.
MARKING_PERIOD = 6.0
# Most cells along a side of the ground grid: 2 * 2048^2 = 8.4 million triangles, within the
# budget of about 13 million that MAX_COUNT sets for the objects of one entry.
MAX_GROUND_CELLS = 2048


@register_generator(
    "room",
    Param("size", "float[3]", (6.0, 5.0, 3.0), "extent along x, y, z, metres; floor at z = 0, centred", above=0.0),
    Param("tile", "float", 1.0, "texture repeat length, metres", minimum=1e-6),
    Param("floor", "material", "floor", "material of the floor"),
    Param("walls", "material", "walls", "material of the four walls"),
    Param("ceiling", "material", "ceiling", "material of the ceiling"),
)
def _room(ctx: GeneratorContext):
    """A closed box room: floor, four walls and ceiling, faces pointing inside."""
    lx, ly, lz = ctx["size"]
    tile = ctx["tile"]
    hx, hy = lx / 2, ly / 2
    floor = np.array([[-hx, -hy, 0], [hx, -hy, 0], [hx, hy, 0], [-hx, hy, 0]], float)
    ceiling = floor[::-1] + [0, 0, lz]
    ctx.add(ctx["floor"], quad_mesh(floor, tile=tile))
    ctx.add(ctx["ceiling"], quad_mesh(ceiling, tile=tile))
    walls = [
        [[-hx, -hy, 0], [-hx, hy, 0], [-hx, hy, lz], [-hx, -hy, lz]],
        [[hx, hy, 0], [hx, -hy, 0], [hx, -hy, lz], [hx, hy, lz]],
        [[hx, -hy, 0], [-hx, -hy, 0], [-hx, -hy, lz], [hx, -hy, lz]],
        [[-hx, hy, 0], [hx, hy, 0], [hx, hy, lz], [-hx, hy, lz]],
    ]
    for wall in walls:
        ctx.add(ctx["walls"], quad_mesh(np.array(wall, float), tile=tile))


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


def _random_wall_slot(ctx, room, wall, width, depth):
    """:func:`_wall_slot` at a random offset along the wall, ``width`` kept WALL_END_GAP from either end.

    The parameters are checked to leave room for ``width`` (:func:`_shelf_fits_room`,
    :func:`_posters_fit_room`); a span a rounding error below zero is taken as zero.
    """
    span = max((room[1] if wall < 2 else room[0]) / 2 - width / 2 - WALL_END_GAP, 0.0)
    return _wall_slot(ctx, room, wall, ctx.rng.uniform(-span, span), depth)


def _ring_point(ctx, distance, z):
    """A random point at height ``z`` whose distance from the z axis is uniform in ``distance``."""
    a, r = ctx.rng.uniform(0, 2 * math.pi), ctx.rng.uniform(*distance)
    return np.array([r * math.cos(a), r * math.sin(a), z])


def _shelf_fits_room(params) -> str | None:
    """None when a shelf of ``size`` fits along every wall of ``room`` and under its ceiling, else the bound."""
    width, _, height = params["size"]
    room = params["room"]
    # fsum: the bounds exactly rounded, so a shelf that just fits is not refused by a rounding error.
    widest = math.fsum([min(room[0], room[1]), -2 * WALL_END_GAP])
    if width > widest:
        return (f"width <= {widest:g} (the shorter wall of room {list(room)} less {WALL_END_GAP:g} m "
                f"at either end)")
    if not 2 * SHELF_BOARD_INSET < height <= room[2]:
        return (f"height > {2 * SHELF_BOARD_INSET:g} (the boards' insets) and <= {room[2]:g} "
                f"(the height of room)")
    return None


def _boards_in_all_shelves(params) -> str | None:
    """None when the shelves' boards number at most MAX_COUNT, else the bound (each board carries a
    row of books, so boards are the objects that multiply)."""
    if params["count"] * params["boards"] <= MAX_COUNT:
        return None
    return f"<= {MAX_COUNT // max(params['count'], 1)} (count x boards <= {MAX_COUNT}; count is {params['count']})"


@register_generator(
    "shelves",
    Param("room", "float[3]", (6.0, 5.0, 3.0), "room extent x, y, z, metres (shelves stand at its walls)", above=0.0),
    Param("count", "int", 3, "number of shelves", minimum=0, maximum=MAX_COUNT),
    Param("size", "float[3]", (1.2, 0.35, 2.0), "width, depth, height of a shelf, metres", above=0.0),
    Param("boards", "int", 5, "boards per shelf", minimum=1, maximum=MAX_COUNT),
    Param("material", "material", "wood", "material of the boards"),
    Param("books", "material", "books", "material of the books (vertex_color gives each its colour)"),
    relations=(Relation("size", f"width <= the shorter wall of room less {2 * WALL_END_GAP:g}, "
                                f"{2 * SHELF_BOARD_INSET:g} < height <= the height of room", _shelf_fits_room),
               Relation("boards", f"count x boards <= {MAX_COUNT}", _boards_in_all_shelves)),
)
def _shelves(ctx: GeneratorContext):
    """Book shelves standing against the room walls, filled with books of random size and colour."""
    room = ctx["room"]
    count = ctx["count"]
    width, depth, height = ctx["size"]
    boards = ctx["boards"]
    wood = ctx["material"]
    books = ctx["books"]
    for k in range(count):
        wall = int(ctx.rng.integers(0, 4))
        base, yaw = _random_wall_slot(ctx, room, wall, width, depth)
        rot = rotation_z(yaw)
        def local(p):
            return base + rot @ np.asarray(p, float)
        for side in (-1, 1):
            ctx.add(wood, box_mesh(local([side * (width / 2 - 0.01), 0, height / 2]), [0.02, depth, height], yaw=yaw))
        for b in range(boards):
            z = SHELF_BOARD_INSET + b * (height - 2 * SHELF_BOARD_INSET) / max(boards - 1, 1)
            ctx.add(wood, box_mesh(local([0, 0, z]), [width, depth, 0.025], yaw=yaw))
            if b == boards - 1:
                continue
            x = -width / 2 + 0.03
            gap = (height - 2 * SHELF_BOARD_INSET) / max(boards - 1, 1)
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


def _clear_radius_in_region(params) -> str | None:
    """None when some place of ``region`` is ``clear_radius`` or more from the z axis, else the bound."""
    region = params["region"]
    reach = math.hypot(region[0], region[1]) / 2
    if params["clear_radius"] <= reach:
        return None
    return f"<= {reach:.4g} (half the diagonal of region {list(region)}: no place in it is farther from the z axis)"


# The objects of the region generators must have places in the region outside the clear radius.
CLEAR_RADIUS_IN_REGION = Relation("clear_radius", "<= half the diagonal of region", _clear_radius_in_region)


@register_generator(
    "tables",
    Param("count", "int", 2, "number of tables (each with a chair)", minimum=0, maximum=MAX_COUNT),
    Param("region", "float[2]", (4.0, 3.0), "x, y extent of the area they stand in, metres, centred", above=0.0),
    Param("clear_radius", "float", 1.0, "no table centre closer than this to the z axis, metres", minimum=0.0),
    Param("material", "material", "wood", "material of the table tops"),
    Param("legs", "material", None, "material of the legs and chairs (default: material)"),
    relations=(CLEAR_RADIUS_IN_REGION,),
)
def _tables(ctx: GeneratorContext):
    """Tables on four legs, each with a chair, at random places and angles."""
    count = ctx["count"]
    region = ctx["region"]
    top = ctx["material"]
    legs = ctx["legs"] or top
    for _ in range(count):
        w, d = ctx.rng.uniform(0.8, 1.6), ctx.rng.uniform(0.6, 0.9)
        h = ctx.rng.uniform(0.7, 0.78)
        c = np.array([ctx.rng.uniform(-region[0] / 2, region[0] / 2),
                      ctx.rng.uniform(-region[1] / 2, region[1] / 2), 0])
        if np.hypot(c[0], c[1]) < ctx["clear_radius"]:
            c[:2] *= ctx["clear_radius"] / max(np.hypot(c[0], c[1]), 1e-6)
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


@register_generator(
    "boxes",
    Param("count", "int", 5, "number of boxes", minimum=0, maximum=MAX_COUNT),
    Param("region", "float[2]", (4.0, 3.0), "x, y extent of the area they stand in, metres, centred", above=0.0),
    Param("clear_radius", "float", 1.0, "no box centre closer than this to the z axis, metres", minimum=0.0),
    Param("size_min", "float[3]", (0.3, 0.3, 0.3), "smallest extent x, y, z, metres", above=0.0),
    Param("size_max", "float[3]", (1.0, 0.6, 1.2), "largest extent x, y, z, metres", above=0.0),
    Param("z", "float", 0.0, "height of the box bottoms, metres"),
    Param("tile", "float", 1.0, "texture repeat length, metres", minimum=1e-6),
    Param("material", "material", "painted", "material (vertex_color gives each box its colour)"),
    relations=(CLEAR_RADIUS_IN_REGION, not_below("size_max", "size_min")),
)
def _boxes(ctx: GeneratorContext):
    """Boxes of random size, place and yaw standing on the floor (flat ones make rugs)."""
    count = ctx["count"]
    region = ctx["region"]
    size_min = ctx["size_min"]
    size_max = ctx["size_max"]
    mat = ctx["material"]
    clear = ctx["clear_radius"]
    for _ in range(count):
        size = ctx.rng.uniform(size_min, size_max)
        c = np.array([ctx.rng.uniform(-region[0] / 2, region[0] / 2),
                      ctx.rng.uniform(-region[1] / 2, region[1] / 2), 0.0])
        r = np.hypot(c[0], c[1])
        if r < clear:
            c[:2] = c[:2] / max(r, 1e-6) * clear
        c[2] = ctx["z"] + size[2] / 2
        ctx.add(mat, box_mesh(c, size, yaw=ctx.rng.uniform(0, math.pi), tile=ctx["tile"]), color=ctx.color())


_POSTERS_ROOM_DOC = f">= [{', '.join(f'{v:g}' for v in POSTER_ROOM_MIN)}] element by element"


def _posters_fit_room(params) -> str | None:
    """None when the largest poster fits on every wall of ``room`` and under its ceiling, else the bound."""
    if all(extent >= least for extent, least in zip(params["room"], POSTER_ROOM_MIN)):
        return None
    return (f"{_POSTERS_ROOM_DOC} (the largest poster, {WALL_END_GAP:g} m from the wall ends "
            f"and {CEILING_GAP:g} m under the ceiling)")


@register_generator(
    "posters",
    Param("room", "float[3]", (6.0, 5.0, 3.0), "room extent x, y, z, metres (posters hang on its walls)", above=0.0),
    Param("photos", "photo[]", ("astronaut", "coffee", "chelsea", "rocket"),
          "bundled photographs, one poster each, walls in turn"),
    relations=(Relation("room", _POSTERS_ROOM_DOC, _posters_fit_room),),
)
def _posters(ctx: GeneratorContext):
    """Framed photographs on the room walls (textured quads)."""
    room = ctx["room"]
    photos = ctx["photos"]
    for k, photo in enumerate(photos):
        wall = k % 4
        w = ctx.rng.uniform(*POSTER_WIDTH)
        h = w * ctx.rng.uniform(*POSTER_ASPECT)
        z = ctx.rng.uniform(POSTER_CENTRE_HEIGHT[0], min(POSTER_CENTRE_HEIGHT[1], room[2] - h / 2 - CEILING_GAP))
        base, yaw = _random_wall_slot(ctx, room, wall, w, 0.02)
        rot = rotation_z(yaw)
        corners = np.array([[-w / 2, 0, -h / 2], [w / 2, 0, -h / 2], [w / 2, 0, h / 2], [-w / 2, 0, h / 2]])
        corners = corners @ rot.T + base + [0, 0, z]
        name = f"poster_{ctx.index}_{k}"
        ctx.add_appearance(name, Appearance(MaterialSettings(), photo=photo))
        p, f, _ = quad_mesh(corners)
        ctx.add(name, (p, f, np.array([[0, 1], [1, 1], [1, 0], [0, 0]], float)))


def _grid_count(params) -> str | None:
    """None when the light grid holds at most MAX_COUNT lights, else the bound."""
    rows, cols = params["grid"]
    return None if rows * cols <= MAX_COUNT else f"rows x cols <= {MAX_COUNT} lights"


@register_generator(
    "ceiling_lights",
    Param("room", "float[3]", (6.0, 5.0, 3.0), "room extent x, y, z, metres (lights hang under its ceiling)",
          above=0.0),
    Param("grid", "int[2]", (2, 2), "rows (along x) and columns (along y) of lights", minimum=1),
    Param("size", "float[2]", (1.2, 0.3), "x, y extent of one light, metres", above=0.0),
    Param("radiance", "float[3]", (6.0, 6.0, 5.5), "emitted linear RGB radiance", minimum=0.0,
          maximum=MAX_RADIANCE),
    relations=(Relation("grid", f"rows x cols <= {MAX_COUNT}", _grid_count),),
)
def _ceiling_lights(ctx: GeneratorContext):
    """A grid of rectangular area lights under the ceiling, facing down.

    The lights are merged into one emitting mesh.

    One mesh means one emitter, so the scene's emitter order (and with it the
    light-sampling pattern) cannot change between loads.
    """
    room = ctx["room"]
    rows, cols = ctx["grid"]
    size = ctx["size"]
    radiance = ctx["radiance"]
    name = f"lights_{ctx.index}"
    ctx.add_appearance(name, Appearance(MaterialSettings(color=(0.9, 0.9, 0.9)),
                                        emission=tuple(float(v) for v in radiance)))
    hx, hy = size[0] / 2, size[1] / 2
    z = room[2] - 0.01
    for i in range(int(rows)):
        for j in range(int(cols)):
            x = (i + 0.5) / rows * room[0] - room[0] / 2
            y = (j + 0.5) / cols * room[1] - room[1] / 2
            # Clockwise seen from above: the face normal points down into the room.
            corners = np.array([[x - hx, y - hy, z], [x - hx, y + hy, z], [x + hx, y + hy, z], [x + hx, y - hy, z]])
            ctx.add(name, quad_mesh(corners))


@register_generator(
    "ground",
    Param("size", "float[2]", (60.0, 60.0), "x, y extent, metres, centred", above=0.0),
    Param("cells", "int", 64, "grid cells along each side", minimum=1, maximum=MAX_GROUND_CELLS),
    Param("amplitude", "float", 0.0, "relief height, metres (flat under the camera)", minimum=0.0),
    Param("tile", "float", 1.0, "texture repeat length, metres", minimum=1e-6),
    Param("material", "material", "ground", "material of the ground"),
)
def _ground(ctx: GeneratorContext):
    """Ground grid with optional seeded relief, flat under the camera."""
    size = ctx["size"]
    cells = ctx["cells"]
    amplitude = ctx["amplitude"]
    heights = np.zeros((cells + 1, cells + 1))
    if amplitude > 0:
        noise = noise_texture(cells + 1, seed=int(ctx.rng.integers(1 << 31)), octaves=3, base_cells=2,
                              color_a=(-1, -1, -1), color_b=(1, 1, 1))[..., 0]
        heights = amplitude * noise
        # Flatten the ground under the camera so it never sits inside a bump.
        xs = np.linspace(-size[0] / 2, size[0] / 2, cells + 1)
        r = np.hypot(*np.meshgrid(xs, xs, indexing="ij"))
        heights = heights * np.clip(r / 4.0, 0, 1) - 0.02
    ctx.add(ctx["material"], heightfield_mesh(size, cells=cells, heights=heights,
                                                                 tile=ctx["tile"]))


@register_generator(
    "trees",
    Param("count", "int", 4, "number of trees", minimum=0, maximum=MAX_COUNT),
    Param("distance", "float[2]", (6.0, 20.0), "smallest and largest distance from the z axis, metres",
          minimum=0.0, ordered=True),
    Param("trunk", "material", "bark", "material of the trunks"),
    Param("canopy", "material", "leaves", "material of the crowns"),
)
def _trees(ctx: GeneratorContext):
    """Trees (cylinder trunk, ellipsoid crown) around the z axis."""
    count = ctx["count"]
    bark = ctx["trunk"]
    leaves = ctx["canopy"]
    for _ in range(count):
        base = _ring_point(ctx, ctx["distance"], -0.05)
        h = ctx.rng.uniform(2.0, 4.0)
        ctx.add(bark, cylinder_mesh(base, radius=ctx.rng.uniform(0.1, 0.25), height=h, sections=10))
        crown = ctx.rng.uniform(1.0, 2.2)
        ctx.add(leaves, sphere_mesh(base + [0, 0, h + crown * 0.6], radius=crown, subdivisions=2,
                                    scale=(1, 1, ctx.rng.uniform(0.8, 1.3))), color=ctx.color(0.5, 1.0))


@register_generator(
    "rocks",
    Param("count", "int", 3, "number of rocks", minimum=0, maximum=MAX_COUNT),
    Param("distance", "float[2]", (3.0, 12.0), "smallest and largest distance from the z axis, metres",
          minimum=0.0, ordered=True),
    Param("material", "material", "stone", "material of the rocks"),
)
def _rocks(ctx: GeneratorContext):
    """Rocks (deformed spheres) around the z axis."""
    count = ctx["count"]
    mat = ctx["material"]
    for _ in range(count):
        centre = _ring_point(ctx, ctx["distance"], 0.0)
        s = ctx.rng.uniform(0.2, 0.7)
        ctx.add(mat, sphere_mesh(centre, radius=s, subdivisions=1,
                                 scale=ctx.rng.uniform(0.6, 1.4, size=3)), color=ctx.color(0.5, 1.0))


@register_generator(
    "street",
    # At most MAX_COUNT lane markings.
    Param("length", "float", 120.0, "length along x, metres", above=0.0, maximum=MAX_COUNT * MARKING_PERIOD),
    Param("road_width", "float", 8.0, "road width, metres", above=0.0),
    Param("sidewalk_width", "float", 3.0, "width of each sidewalk, metres", above=0.0),
    Param("tile", "float", 2.0, "road texture repeat length, metres", minimum=1e-6),
    Param("road", "material", "asphalt", "material of the road"),
    Param("sidewalk", "material", "pavement", "material of the sidewalks"),
    Param("marking", "material", "marking", "material of the lane markings"),
)
def _street(ctx: GeneratorContext):
    """A road along x with a sidewalk on each side and dashed lane markings."""
    length = ctx["length"]
    road_w = ctx["road_width"]
    walk_w = ctx["sidewalk_width"]
    road = np.array([[-length / 2, -road_w / 2, 0], [length / 2, -road_w / 2, 0],
                     [length / 2, road_w / 2, 0], [-length / 2, road_w / 2, 0]], float)
    ctx.add(ctx["road"], quad_mesh(road, tile=ctx["tile"]))
    for side in (-1, 1):
        y = side * (road_w / 2 + walk_w / 2)
        ctx.add(ctx["sidewalk"], box_mesh([0, y, 0.075], [length, walk_w, 0.15], tile=1.5))
    # Lane markings.
    for x in np.arange(-length / 2, length / 2, MARKING_PERIOD):
        mark = np.array([[x, -0.08, 0.005], [x + 3, -0.08, 0.005], [x + 3, 0.08, 0.005], [x, 0.08, 0.005]])
        ctx.add(ctx["marking"], quad_mesh(mark))


@register_generator(
    "facades",
    # About MAX_COUNT buildings at most in the two rows (one more a row).
    Param("length", "float", 120.0, "length of the rows of buildings along x, metres", minimum=0.0,
          maximum=MAX_COUNT * FACADE_WIDTH[0] / 2),
    Param("offset", "float", 7.0, "distance of the facades from the street axis, metres", minimum=0.0),
    Param("materials", "material[]", ("brick", "plaster"), "materials the buildings are drawn from", nonempty=True),
    Param("tile", "float", 2.0, "texture repeat length, metres", minimum=1e-6),
    Param("window", "material", "glass", "material of the windows"),
)
def _facades(ctx: GeneratorContext):
    """Rows of box buildings with windows on both sides of the street."""
    length = ctx["length"]
    offset = ctx["offset"]
    mats = ctx["materials"]
    window = ctx["window"]
    for side in (-1, 1):
        x = -length / 2
        while x < length / 2:
            w = ctx.rng.uniform(*FACADE_WIDTH)
            h = ctx.rng.uniform(8.0, 22.0)
            d = 10.0
            mat = mats[int(ctx.rng.integers(0, len(mats)))]
            cy = side * (offset + d / 2)
            ctx.add(mat, box_mesh([x + w / 2, cy, h / 2], [w - 0.3, d, h], tile=ctx["tile"]),
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


def _clear_distance_on_stretch(params) -> str | None:
    """None when some place of the stretch is ``clear_distance`` or more from x = 0, else the bound."""
    reach = params["length"] / 2
    if params["clear_distance"] <= reach:
        return None
    return f"<= {reach:g} (half of length {params['length']:g}: no place on the stretch is farther from x = 0)"


@register_generator(
    "cars",
    Param("count", "int", 6, "number of cars", minimum=0, maximum=MAX_COUNT),
    Param("length", "float", 60.0, "length of the stretch they park along x, metres", minimum=0.0),
    Param("lane_offset", "float", 2.6, "distance of the lanes from the street axis, metres", minimum=0.0),
    Param("clear_distance", "float", 4.0, "no car closer than this to x = 0, metres", minimum=0.0),
    Param("material", "material", "car_paint", "material of the bodies (vertex_color gives each its colour)"),
    Param("wheels", "material", "rubber", "material of the wheels"),
    Param("window", "material", "glass", "material of the windows"),
    relations=(Relation("clear_distance", "<= half of length", _clear_distance_on_stretch),),
)
def _cars(ctx: GeneratorContext):
    """Parked cars (body, cabin, windows, wheels) in the two lanes."""
    count = ctx["count"]
    length = ctx["length"]
    lane = ctx["lane_offset"]
    paint = ctx["material"]
    tyre = ctx["wheels"]
    glass = ctx["window"]
    for _ in range(count):
        x = ctx.rng.uniform(-length / 2, length / 2)
        if abs(x) < ctx["clear_distance"]:
            x = math.copysign(ctx["clear_distance"] + abs(x), x if x != 0 else 1.0)
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


def _pole_count(params) -> str | None:
    """None when the two rows hold about MAX_COUNT poles at most (one more a row), else the bound of ``spacing``."""
    least = 2 * params["length"] / MAX_COUNT
    if params["spacing"] >= least:
        return None
    return f">= {least:g} (2 x length / {MAX_COUNT}: about {MAX_COUNT} poles at most in the two rows)"


@register_generator(
    "poles",
    Param("spacing", "float", 15.0, "distance between poles, metres", minimum=1e-6),
    Param("length", "float", 120.0, "length of the rows along x, metres", minimum=0.0),
    Param("offset", "float", 5.0, "distance of the rows from the street axis, metres", minimum=0.0),
    Param("material", "material", "metal", "material of the poles"),
    relations=(Relation("spacing", f">= 2 x length / {MAX_COUNT}", _pole_count),),
)
def _poles(ctx: GeneratorContext):
    """Street-light poles in two rows along the street."""
    spacing = ctx["spacing"]
    length = ctx["length"]
    offset = ctx["offset"]
    mat = ctx["material"]
    for side in (-1, 1):
        for x in np.arange(-length / 2 + ctx.rng.uniform(0, spacing), length / 2, spacing):
            base = [x, side * offset, 0.0]
            ctx.add(mat, cylinder_mesh(base, radius=0.08, height=6.0, sections=10))
            ctx.add(mat, box_mesh([x, side * (offset - 0.6), 6.0], [0.4, 1.4, 0.15]))
