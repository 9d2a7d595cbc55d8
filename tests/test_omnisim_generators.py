"""[[objects]] generator parameters: declared bounds, [low, high] ranges, relations and counts (no rendering)."""

from __future__ import annotations

import re

import pytest

from ifmi.errors import InputError
from scene_files import camera_128_section, write_scene

pytest.importorskip("skimage")

from omnisim.config import load_scene_config  # noqa: E402
from omnisim.generators import MAX_COUNT, Param, Relation, describe_generators  # noqa: E402
from omnisim.scene import scene_meshes  # noqa: E402

BASE = """
[render]
resolution = [64, 64]
spp = 1

""" + camera_128_section(skewed=False) + """
[trajectory]
frames = 1

[materials.painted]
vertex_color = true
"""


def _object(generator: str, **keys) -> str:
    """An ``[[objects]]`` table of ``generator`` with ``keys`` (TOML values written as Python literals)."""
    lines = ["[[objects]]", f'generator = "{generator}"']
    for key, value in keys.items():
        text = f'"{value}"' if isinstance(value, str) else str(value).replace("'", '"')
        lines.append(f"{key} = {text}")
    return "\n".join(lines) + "\n"


PAINTED = {"material": "painted"}
STREET = {"road": "painted", "sidewalk": "painted", "marking": "painted"}


@pytest.mark.parametrize("table, message", [
    # [low, high] ranges and pairs of bounds.
    (_object("boxes", size_min=[2.4, 0.3, 0.5], size_max=[0.9, 0.5, 1.3], **PAINTED),
     r"\(boxes\) size_max: expected >= size_min = \[2.4, 0.3, 0.5\] element by element, got \[0.9, 0.5, 1.3\]"),
    (_object("rocks", distance=[12.0, 3.0], **PAINTED),
     r"\(rocks\) distance: expected \[low, high\] with low <= high, got \[12.0, 3.0\]"),
    (_object("trees", distance=[20.0, 6.0], trunk="painted", canopy="painted"),
     r"\(trees\) distance: expected \[low, high\] with low <= high, got \[20.0, 6.0\]"),
    # Lists of choices.
    (_object("facades", materials=[], window="painted"),
     r"\(facades\) materials: expected at least one name, got \[\]"),
    # Sizes.
    (_object("room", size=[0.0, 6.0, 3.0], floor="painted", walls="painted", ceiling="painted"),
     r"\(room\) size: expected > 0.0, got \[0.0, 6.0, 3.0\]"),
    (_object("boxes", region=[0.0, 0.0], clear_radius=0.0, **PAINTED),
     r"\(boxes\) region: expected > 0.0, got \[0.0, 0.0\]"),
    (_object("ceiling_lights", size=[0.0, 1.0]), r"\(ceiling_lights\) size: expected > 0.0, got \[0.0, 1.0\]"),
    (_object("street", road_width=0.0, **STREET), r"\(street\) road_width: expected > 0.0, got 0.0"),
    (_object("ceiling_lights", grid=[0, 0]), r"\(ceiling_lights\) grid: expected >= 1, got \[0, 0\]"),
    (_object("ceiling_lights", radiance=[3e38, 1.0, 1.0]),
     r"\(ceiling_lights\) radiance: expected <= 1e\+27, got \[3e\+38, 1.0, 1.0\]"),
    # Places the objects could never have.
    (_object("boxes", region=[2.0, 2.0], clear_radius=5.0, **PAINTED),
     r"\(boxes\) clear_radius: expected <= 1.414 \(half the diagonal of region \[2.0, 2.0\]: no place in it is "
     r"farther from the z axis\), got 5.0"),
    (_object("tables", region=[2.0, 2.0], clear_radius=5.0, **PAINTED),
     r"\(tables\) clear_radius: expected <= 1.414 \(half the diagonal of region \[2.0, 2.0\]"),
    (_object("cars", length=10.0, clear_distance=50.0, material="painted", wheels="painted", window="painted"),
     r"\(cars\) clear_distance: expected <= 5 \(half of length 10: no place on the stretch is farther from x = 0\), "
     r"got 50.0"),
    (_object("shelves", room=[2.0, 6.0, 3.0], size=[2.5, 0.3, 2.0], books="painted", **PAINTED),
     r"\(shelves\) size: expected width <= 1.8 \(the shorter wall of room \[2.0, 6.0, 3.0\] less 0.1 m at either "
     r"end\), got \[2.5, 0.3, 2.0\]"),
    (_object("shelves", room=[6.0, 6.0, 3.0], size=[1.2, 0.3, 3.5], books="painted", **PAINTED),
     r"\(shelves\) size: expected height > 0.1 \(the boards' insets\) and <= 3 \(the height of room\), "
     r"got \[1.2, 0.3, 3.5\]"),
    (_object("posters", room=[7.0, 6.0, 1.5]),
     r"\(posters\) room: expected >= \[1.2, 1.2, 1.95\] element by element \(the largest poster, 0.1 m from the "
     r"wall ends and 0.1 m under the ceiling\), got \[7.0, 6.0, 1.5\]"),
    # Counts, given and implied.
    (_object("shelves", count=100000000, books="painted", **PAINTED),
     rf"\(shelves\) count: expected <= {MAX_COUNT}, got 100000000"),
    (_object("ceiling_lights", grid=[1000, 1000]),
     rf"\(ceiling_lights\) grid: expected rows x cols <= {MAX_COUNT} lights, got \[1000, 1000\]"),
    (_object("poles", spacing=0.001, **PAINTED),
     rf"\(poles\) spacing: expected >= 0.024 \(2 x length / {MAX_COUNT}: about {MAX_COUNT} poles at most in the "
     r"two rows\), got 0.001"),
    (_object("facades", length=1e9, materials=["painted"], window="painted"),
     r"\(facades\) length: expected <= 30000.0, got 1000000000.0"),
    (_object("street", length=1e9, **STREET), r"\(street\) length: expected <= 60000.0, got 1000000000.0"),
    (_object("ground", cells=100000, **PAINTED), r"\(ground\) cells: expected <= 2048, got 100000"),
    (_object("shelves", count=10000, boards=10000, books="painted", **PAINTED),
     r"\(shelves\) boards: expected <= 1 \(count x boards <= 10000; count is 10000\), got 10000"),
])
def test_impossible_generator_parameters_are_one_line_errors(tmp_path, table, message):
    with pytest.raises(InputError) as info:
        load_scene_config(write_scene(tmp_path, BASE + table))
    assert re.search(r"\[\[objects\]\] #1 " + message, str(info.value)), str(info.value)
    assert str(info.value).startswith(str(tmp_path / "scene.toml") + ": ")
    assert "\n" not in str(info.value)


@pytest.mark.parametrize("table", [
    _object("shelves", room=[1.4, 1.4, 3.0], size=[1.2, 0.3, 2.0], count=20, books="painted", **PAINTED),
    _object("posters", room=[1.2, 1.2, 1.95], photos=["astronaut", "coffee", "chelsea", "rocket"]),
    _object("boxes", region=[2.0, 2.0], clear_radius=2.0 ** 0.5, size_min=[0.5, 0.5, 0.5],
            size_max=[0.5, 0.5, 0.5], **PAINTED),
    _object("rocks", distance=[4.0, 4.0], **PAINTED),
])
@pytest.mark.slow
def test_objects_that_just_fit_are_built(tmp_path, table):
    """At the bounds (a rounding error from them) the generators still build their objects."""
    groups, _ = scene_meshes(load_scene_config(write_scene(tmp_path, BASE + table)))
    assert sum(len(group.arrays()[1]) for group in groups.values()) > 0


@pytest.mark.slow
def test_an_entry_whose_counts_multiply_past_the_triangle_budget_is_refused(tmp_path, monkeypatch):
    """Each count is bounded, but shelves x boards x books multiply: the entry's triangles are bounded
    too. Here the budget is lowered to 1000 (three default shelves make several thousand)."""
    import omnisim.generators as generators

    table = _object("shelves", count=3, books="painted", **PAINTED)
    groups, _ = scene_meshes(load_scene_config(write_scene(tmp_path, BASE + table)))
    made = sum(len(group.arrays()[1]) for group in groups.values())
    assert made > 1000
    monkeypatch.setattr(generators, "MAX_ENTRY_TRIANGLES", 1000)
    with pytest.raises(InputError, match=r"\[\[objects\]\] #1 \(shelves\): makes more than 1000 triangles; "
                                         r"expected fewer"):
        scene_meshes(load_scene_config(write_scene(tmp_path, BASE + table)))
    monkeypatch.setattr(generators, "MAX_ENTRY_TRIANGLES", made)  # exactly what it makes: built
    scene_meshes(load_scene_config(write_scene(tmp_path, BASE + table)))


def test_generated_geometry_beyond_float32_ray_tracing_is_refused(tmp_path, capsys):
    """A room 3e38 m wide had its walls and ceiling lost by Mitsuba's float32 ray tracing: the closed
    room rendered as an open floor under the sky, with exit 0. Every generator's vertices are bounded
    as a mesh file's are."""
    from omnisim.cli import main as omnisim_main

    table = _object("room", size=[3e38, 3e38, 3e38], floor="painted", walls="painted", ceiling="painted")
    scene = write_scene(tmp_path, BASE + table)
    assert omnisim_main(["render", str(scene), "--out", str(tmp_path / "out"), "--no-progress"]) == 2
    assert capsys.readouterr().err.strip() == (
        f"omnisim render: error: {scene}: [[objects]] #1 (room): expected geometry within 1e+09 m of the "
        "origin (float32 ray tracing loses larger surfaces; lower its sizes or distances), got 1.5e+38 m")
    assert not (tmp_path / "out").exists()


def test_generator_listing_states_the_bounds_that_are_checked():
    text = describe_generators()
    assert f"    count (int, default 5, >= 0, <= {MAX_COUNT}): number of boxes" in text
    assert "    distance (float[2], default [3.0, 12.0], >= 0.0, low <= high): " in text
    assert "    clear_radius (float, default 1.0, >= 0.0, <= half the diagonal of region): " in text
    assert "    size_max (float[3], default [1.0, 0.6, 1.2], > 0.0, >= size_min element by element): " in text
    assert "    materials (material[], default ['brick', 'plaster'], at least one): " in text


def test_relation_of_a_registered_generator_is_checked_and_listed(tmp_path, monkeypatch):
    from omnisim import generators
    from omnisim.generators import register_generator

    monkeypatch.setattr(generators, "_REGISTRY", dict(generators._REGISTRY))

    def fits(params):
        return None if params["height"] <= params["base"] else f"<= base = {params['base']}"

    @register_generator("pyramid", Param("base", "float", 2.0, "side of the base, metres", above=0.0),
                        Param("height", "float", 1.0, "apex height, metres", above=0.0),
                        relations=(Relation("height", "<= base", fits),))
    def _pyramid(ctx):
        """A test pyramid."""

    with pytest.raises(InputError, match=r"#1 \(pyramid\) height: expected <= base = 2.0, got 3.0$"):
        load_scene_config(write_scene(tmp_path, BASE + _object("pyramid", height=3.0)))
    assert "    height (float, default 1.0, > 0.0, <= base): apex height, metres" in describe_generators()
    with pytest.raises(ValueError, match=r"relations on undeclared parameters \['width'\]"):
        register_generator("wedge", Param("height", "float", 1.0, "metres"), relations=(Relation("width", "", fits),))
    with pytest.raises(ValueError, match="only a pair"):
        Param("distance", "float[3]", (1.0, 2.0, 3.0), "metres", ordered=True)


TEXTURED = """
[textures.noise]
source = "noise"
size = 256

[materials.ground]
texture = "noise"
"""
# A 256 px texture repeats at most 1/64 / (2^-24 * 256) = 1024 times across one triangle.
LIMIT_REPEATS = 1024


@pytest.mark.parametrize("repeats, refused", [(LIMIT_REPEATS, False), (1100, True)])
def test_ground_cells_spanning_too_many_texture_repeats_are_refused(tmp_path, repeats, refused):
    """A textured ground of 2e9 m (within the geometry bound) rendered noise: float32 texture
    coordinates interpolated across cells of millions of repeats miss the texels. Refused where one
    cell spans more repeats than keep the lookup within 1/64 texel; up to there it is built."""
    table = _object("ground", size=[64.0 * repeats, 64.0 * repeats], cells=64, material="ground")
    config = load_scene_config(write_scene(tmp_path, BASE + TEXTURED + table))
    if not refused:
        groups, _ = scene_meshes(config)
        assert len(groups["ground"].arrays()[1]) == 2 * 64 * 64
        return
    with pytest.raises(InputError) as caught:
        scene_meshes(config)
    assert str(caught.value).endswith(
        "[[objects]] #1 (ground): one triangle spans 1.1e+03 repeats of texture 'noise' (256 px) of "
        "[materials.ground], expected at most 1.02e+03 (the renderer interpolates texture coordinates in "
        "float32, which then miss the texels by more than 1/64 of one); use smaller triangles (more cells, "
        "smaller sizes) or a larger tile")


def test_huge_ground_without_texture_or_with_a_long_tile_is_built(tmp_path):
    """Only the texture's repeats across a triangle count: an untextured ground of 2e9 m is built, and
    a textured one whose material tile makes a cell span few repeats."""
    huge = _object("ground", size=[2e9, 2e9], cells=64, material="painted")
    scene_meshes(load_scene_config(write_scene(tmp_path, BASE + huge)))
    long_tile = TEXTURED + "tile = 4e4\n" + _object("ground", size=[2e9, 2e9], cells=64, material="ground")
    scene_meshes(load_scene_config(write_scene(tmp_path, BASE + long_tile)))  # 3.1e7 m cells: 781 repeats


def test_cli_huge_textured_ground_is_one_line_exit_2(tmp_path, capsys):
    import importlib.util

    if importlib.util.find_spec("mitsuba") is None:
        pytest.skip("mitsuba is not installed (sim extra)")
    from omnisim.cli import main

    table = _object("ground", size=[2e9, 2e9], cells=64, material="ground")
    scene = write_scene(tmp_path, BASE + TEXTURED + table)
    assert main(["render", str(scene), "--out", str(tmp_path / "out"), "--no-progress"]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and err.startswith(f"omnisim render: error: {scene}: [[objects]] #1 (ground): one "
                                              "triangle spans 3.12e+07 repeats of texture 'noise' (256 px)")
    assert not (tmp_path / "out").exists()
