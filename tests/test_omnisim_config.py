"""Scene-file settings: unknown sections and keys, types, bounds, generator declarations (no rendering)."""

from __future__ import annotations

import os
import re

import pytest

from ifmi.errors import InputError
from scene_files import camera_128_section, write_scene

pytest.importorskip("skimage")

from omnisim.config import (CaptureSettings, RenderSettings, load_scene_config)  # noqa: E402
from omnisim.settings import SettingError  # noqa: E402

BASE = """
[scene]
name = "t"
seed = 2

[render]
resolution = [64, 64]
spp = 2

""" + camera_128_section(skewed=False) + """
[trajectory]
frames = 2

[materials.painted]
vertex_color = true

[materials.wood]
color = [0.5, 0.35, 0.2]

[[objects]]
generator = "boxes"
count = 3
"""


def test_base_scene_loads_with_declared_defaults(tmp_path):
    config = load_scene_config(write_scene(tmp_path, BASE))
    assert config.render.spp == 2 and config.render.max_depth == RenderSettings().max_depth
    assert config.capture == CaptureSettings()
    (obj,) = config.objects
    assert obj.generator == "boxes" and obj.params["count"] == 3
    assert obj.params["size_min"] == (0.3, 0.3, 0.3) and obj.params["material"] == "painted"


@pytest.mark.parametrize("edit, message", [
    (("", "[bogus]\nx = 1\n"), r"\[bogus\]: unknown section; accepted sections: scene, render, camera"),
    (("spp = 2", "spp_typo = 2"), r"\[render\] spp_typo: unknown key; accepted keys: resolution, spp, max_depth"),
    (("color = [0.5, 0.35, 0.2]", "colour = [0.5, 0.35, 0.2]"),
     r"\[materials.wood\] colour: unknown key; accepted keys: type, color, texture"),
    (("count = 3", "count = 3\ncolour = 1"),
     r"\[\[objects\]\] #1 \(boxes\) colour: unknown key; accepted keys: generator, count, region"),
    (("count = 3", "count = -3"), r"\[\[objects\]\] #1 \(boxes\) count: expected >= 0, got -3"),
    (("frames = 2", "frames = -1"), r"\[trajectory\] frames: expected >= 1, got -1"),
    (("frames = 2", "frames = 9223372036854775807"),
     r"\[trajectory\] frames: expected <= 1000000, got 9223372036854775807"),
    (("frames = 2", "frames = 2\nsmoothness_frames = 1e6"),
     r"\[trajectory\] smoothness_frames: expected <= 1000.0, got 1000000.0"),
    (("spp = 2", "spp = 9223372036854775807"), r"\[render\] spp: expected <= 1073741824, got 9223372036854775807"),
    (("seed = 2", "seed = 1.5"), r"\[scene\] seed: expected an integer, got 1.5"),
    (("spp = 2", "spp = true"), r"\[render\] spp: expected an integer, got True"),
    (("spp = 2", 'spp = "abc"'), r"\[render\] spp: expected an integer, got 'abc'"),
    (("spp = 2", "spp = 2\nsampler = 'sobol'"), r"\[render\] sampler: expected one of 'multijitter'"),
    (("count = 3", "count = 3\nregion = [1.0]"), r"\(boxes\) region: expected 2 values \[float, float\]"),
    (("count = 3", "count = 3\nmaterial = 'gold'"), r"\(boxes\) material: unknown material 'gold'"),
    (('generator = "boxes"', 'generator = "spaceship"'), r"#1 generator: expected one of boxes, "),
    (("frames = 2", "frames = 2\n[capture]\nexposure = 1.5"), r"\[capture\] exposure: expected <= 1.0, got 1.5"),
    (("frames = 2", "frames = 2\n[effects]\njpeg = 50"), r"\[effects\] jpeg: unknown key; accepted keys: noise_sigma"),
    (("frames = 2", "frames = 2\n[effects]\nnoise_sigma = 1e30"),
     r"\[effects\] noise_sigma: expected <= 255.0, got 1e\+30"),
    (("radius_max = 61.5", "radius_max = 5.0"), r"\[camera\] radius_max: expected > radius_min = 10.0, got 5.0"),
    (("center = [64.35, 63.3]\n", ""), r"\[camera\] center: missing \(give either 'calib' or 'pol'"),
    (("pol = [-20.0, 0.0, 1.28e-2, -1.76e-5, 2.56e-7]", "pol = []"),
     r"\[camera\] pol: expected at least one coefficient \(lowest degree first\), got \[\]"),
    # Its fitted inverse was 20 px off: the dataset rendered with exit 0, its calib_results.txt refused by readers.
    (("pol = [-20.0, 0.0, 1.28e-2, -1.76e-5, 2.56e-7]", "pol = [-1e-30, 0.0, 1e-30]"),
     r"\[camera\] pol: expected an inverse polynomial within 0.1 px of the direct one at the 64x64 rendered \(as "
     r"readers of the dataset check\), got a round-trip error of 19.7 px at radius 3.1 px"),
    # Mitsuba stores scene values as float32: beyond its range a value turns into inf there.
    (("frames = 2", "frames = 2\nposition = [1e300, 0, 1.2]"),
     r"\[trajectory\] position: expected magnitudes <= 3.403e\+38 \(the renderer stores float32\), "
     r"got \[1e\+300, 0.0, 1.2\]"),
    (("count = 3", "count = 3\nregion = [0.5, 1e39]"), r"\(boxes\) region: expected magnitudes <= 3.403e\+38"),
    (("frames = 2", "frames = 20\ntranslation_step_m = 3e38\ntranslation_radius_m = 0"),
     r"\[trajectory\] translation_step_m: expected the camera to stay within 1e\+04 m of the origin "
     r"\(the renderer places it in float32, to 0.5 mm there; move the scene's origin near the camera\), "
     r"got position \[0.0, 0.0, 1.2\] and a walk of up to 5.7e\+39 m"),
    # UTM-like coordinates: float32 places a camera at 5e6 m to 0.25 m, far from its ground truth.
    (("frames = 2", "frames = 2\nposition = [5e6, 4e6, 1.2]"),
     r"\[trajectory\] position: expected the camera to stay within 1e\+04 m of the origin .* got position "
     r"\[5000000.0, 4000000.0, 1.2\] and a walk of up to 0 m from it"),
])
def test_bad_scene_is_one_line_naming_section_and_key(tmp_path, edit, message):
    old, new = edit
    text = BASE.replace(old, new, 1) if old else BASE + new
    with pytest.raises(InputError) as info:
        load_scene_config(write_scene(tmp_path, text))
    assert re.search(message, str(info.value)), str(info.value)
    assert str(info.value).startswith(str(tmp_path / "scene.toml"))
    assert "\n" not in str(info.value)


def test_unknown_texture_source_and_key(tmp_path):
    with pytest.raises(InputError, match=r"\[textures.t\] source: expected one of photo, noise, got 'video'"):
        load_scene_config(write_scene(tmp_path, BASE + '[textures.t]\nsource = "video"\n'))
    with pytest.raises(InputError, match=r"\[textures.t\] octave: unknown key; accepted keys: source, size"):
        load_scene_config(write_scene(tmp_path, BASE + '[textures.t]\nsource = "noise"\noctave = 3\n'))
    with pytest.raises(InputError, match=r"\[textures.t\] name: expected one of 'grass'"):
        load_scene_config(write_scene(tmp_path, BASE + '[textures.t]\nsource = "photo"\nname = "moonlight"\n'))


@pytest.mark.parametrize("table, message", [
    ('[textures.t]\nsource = "noise"\ncolor_b = [1.5, 0.8, 0.8]',
     r"scene.toml: \[textures.t\] color_b: expected <= 1.0, got \[1.5, 0.8, 0.8\]"),
    ('[materials.glow]\ncolor = [0.5, 1.2, 0.5]', r"scene.toml: \[materials.glow\] color: expected <= 1.0, got \[0.5, 1.2"),
])
def test_reflectance_above_one_is_refused(tmp_path, table, message):
    """A surface that reflects more light than reaches it makes light; the render gave no sign."""
    with pytest.raises(InputError, match=message):
        load_scene_config(write_scene(tmp_path, BASE + table + "\n"))


@pytest.mark.parametrize("keys, message", [
    ("size = 100000", r"\[textures.t\] size: expected <= 8192, got 100000"),
    ("cells = 100000000\noctaves = 16", r"\[textures.t\] cells: expected cells \* 2\^\(octaves - 1\) <= size = 256 "
                                        r"\(the finest lattice no finer than the pixels\), got 100000000 \* 2\^15"),
])
def test_noise_texture_too_large_to_make_is_one_line(tmp_path, keys, message):
    with pytest.raises(InputError) as info:
        load_scene_config(write_scene(tmp_path, BASE + f'[textures.t]\nsource = "noise"\n{keys}\n'))
    assert re.search(message, str(info.value)), str(info.value)
    assert "\n" not in str(info.value)


@pytest.mark.parametrize("table, message", [
    # Radiance past MAX_RADIANCE overflowed the film's float32 sums to NaN: black sky, exit 0.
    ('type = "constant"\nradiance = [3e38, 3e38, 3e38]',
     r"\[\[lights\]\] #1 \(constant\) radiance: expected <= 1e\+27, got \[3e\+38, 3e\+38, 3e\+38\]"),
    ('type = "sun"\nirradiance = [1e30, 1, 1]', r"\[\[lights\]\] #1 \(sun\) irradiance: expected <= 1e\+27"),
    ('type = "sky"\nscale = 1e20\nzenith = [1e10, 1, 1]',
     r"\[\[lights\]\] #1 \(sky\) scale: expected scale times the brightest radiance <= 1e\+27 \(the renderer "
     r"sums samples in float32\), got 1e\+30"),
    ('type = "envmap"\nfile = "scene.toml"\nscale = 3e38', r"\[\[lights\]\] #1 \(envmap\) scale: expected <= 1e\+27"),
])
def test_light_brighter_than_the_film_can_sum_is_one_line(tmp_path, table, message):
    with pytest.raises(InputError) as info:
        load_scene_config(write_scene(tmp_path, BASE + f"[[lights]]\n{table}\n"))
    assert re.search(message, str(info.value)), str(info.value)
    assert str(info.value).startswith(str(tmp_path / "scene.toml")) and "\n" not in str(info.value)


def test_material_tile_shorter_than_a_micrometre_is_one_line(tmp_path):
    """tile = 1e-30 passed (> 0) and lost every texel: black pixels where the texture was, exit 0."""
    table = '[textures.t]\nsource = "noise"\n[materials.wood]\ntexture = "t"\ntile = 1e-30\n'
    with pytest.raises(InputError) as info:
        load_scene_config(write_scene(tmp_path, BASE.replace("[materials.wood]\ncolor = [0.5, 0.35, 0.2]\n", "")
                                      + table))
    assert str(info.value) == f"{tmp_path / 'scene.toml'}: [materials.wood] tile: expected >= 1e-06, got 1e-30"


def test_photo_gain_past_white_is_one_line(tmp_path):
    """tint 3e38 and brightness 3e38 overflowed float32 to NaN texels (a numpy warning, exit 0)."""
    table = '[textures.t]\nsource = "photo"\nname = "grass"\nbrightness = 3e38\ntint = [3e38, 1, 1]\n'
    with pytest.raises(InputError) as info:
        load_scene_config(write_scene(tmp_path, BASE + table))
    assert str(info.value) == (f"{tmp_path / 'scene.toml'}: [textures.t] brightness: expected brightness times "
                               "the largest tint <= 3294.6 (beyond it every non-black pixel is white), got 9e+76")


def test_unknown_photo_and_missing_mesh_file_are_found_before_rendering(tmp_path):
    posters = BASE + '[[objects]]\ngenerator = "posters"\nphotos = ["astronaut", "selfie"]\n'
    with pytest.raises(InputError, match=r"#2 \(posters\) photos: unknown photo 'selfie'"):
        load_scene_config(write_scene(tmp_path, posters))
    mesh = BASE + '[[objects]]\ngenerator = "mesh"\nfile = "chair.obj"\n'
    with pytest.raises(InputError, match=r"#2 \(mesh\) file: file not found: .*chair.obj"):
        load_scene_config(write_scene(tmp_path, mesh))
    with pytest.raises(InputError, match=r"#2 \(mesh\) file: missing \(required\)"):
        load_scene_config(write_scene(tmp_path, BASE + '[[objects]]\ngenerator = "mesh"\n'))


def test_light_keys_and_envmap_file_are_checked(tmp_path):
    with pytest.raises(InputError, match=r"\[\[lights\]\] #1 \(sun\) colour: unknown key; accepted keys: type, "
                                         r"azimuth_deg"):
        load_scene_config(write_scene(tmp_path, BASE + '[[lights]]\ntype = "sun"\ncolour = [1, 1, 1]\n'))
    with pytest.raises(InputError, match=r"\[\[lights\]\] #1 type: expected one of sky, sun, constant, envmap"):
        load_scene_config(write_scene(tmp_path, BASE + '[[lights]]\ntype = "laser"\n'))
    with pytest.raises(InputError, match=r"\[\[lights\]\] #1 \(envmap\) file: file not found"):
        load_scene_config(write_scene(tmp_path, BASE + '[[lights]]\ntype = "envmap"\nfile = "sky.exr"\n'))


def test_command_line_override_is_named_as_the_option(tmp_path):
    with pytest.raises(InputError, match=r"scene.toml: --spp: expected >= 1, got 0"):
        load_scene_config(write_scene(tmp_path, BASE), spp=0)
    with pytest.raises(InputError, match=r"--variant: expected one of '', 'llvm_ad_rgb', 'cuda_ad_rgb', got 'bogus'"):
        load_scene_config(write_scene(tmp_path, BASE), variant="bogus")


@pytest.mark.parametrize("edit, override, message", [
    (("spp = 2", 'spp = "sixteen"'), {"spp": 1}, r"\[render\] spp: expected an integer, got 'sixteen'"),
    (("resolution = [64, 64]", "resolution = [512]"), {"resolution": 64},
     r"\[render\] resolution: expected 2 values \[int, int\], got \[512\]"),
    (("frames = 2", "frames = 0"), {"frames": 1}, r"\[trajectory\] frames: expected >= 1, got 0"),
    (("spp = 2", "spp = 2\nvariant = 'bogus'"), {"variant": "llvm_ad_rgb"},
     r"\[render\] variant: expected one of '', 'llvm_ad_rgb', 'cuda_ad_rgb', got 'bogus'"),
])
def test_bad_file_value_is_refused_even_where_an_option_overrides_it(tmp_path, edit, override, message):
    with pytest.raises(InputError) as info:
        load_scene_config(write_scene(tmp_path, BASE.replace(*edit, 1)), **override)
    assert re.search(message, str(info.value)), str(info.value)
    assert str(info.value).startswith(str(tmp_path / "scene.toml") + ": ")


def test_resolution_of_another_aspect_is_named_as_the_option(tmp_path):
    with pytest.raises(InputError, match=r"scene.toml: --resolution: expected the calibration's aspect 128x128 "
                                         r"\(height x width\), got 64x32"):
        load_scene_config(write_scene(tmp_path, BASE), resolution=(64, 32))


@pytest.mark.parametrize("text, expected", [("64", (64, 64)), ("64x48", (64, 48)), ("64,48", (64, 48)),
                                            (" 64 x 48 ", (64, 48)), ("64x", None), ("x64", None),
                                            ("64xx48", None), ("64 48", None), ("64x48x2", None)])
def test_cli_resolution_is_one_number_or_two_with_nothing_left_out(text, expected):
    import argparse

    from omnisim.cli import _resolution

    if expected is not None:
        assert _resolution(text) == expected
    else:
        with pytest.raises(argparse.ArgumentTypeError, match="expected N or HEIGHTxWIDTH"):
            _resolution(text)


def test_cli_bad_file_value_under_overriding_options_is_one_line_exit_2(tmp_path, capsys):
    from omnisim.cli import main

    scene = write_scene(tmp_path, BASE.replace("spp = 2", 'spp = "sixteen"'))
    code = main(["render", str(scene), "--out", str(tmp_path / "out"), "--no-progress", "--frames", "1",
                 "--spp", "1", "--resolution", "64"])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1
    assert err.endswith("scene.toml: [render] spp: expected an integer, got 'sixteen'")
    assert not (tmp_path / "out").exists()


def test_cli_negative_seed_is_named_as_the_option(tmp_path, capsys):
    from omnisim.cli import main

    code = main(["render", str(write_scene(tmp_path, BASE)), "--out", str(tmp_path / "out"), "--no-progress",
                 "--seed", "-3"])
    err = capsys.readouterr().err.strip()
    assert code == 2 and err.endswith("scene.toml: --seed: expected a non-negative integer, got -3")
    assert not (tmp_path / "out").exists()


def test_asset_files_are_part_of_the_identity(tmp_path):
    (tmp_path / "m.ply").write_bytes(b"not read here")
    text = BASE + '[[objects]]\ngenerator = "mesh"\nfile = "m.ply"\n'
    first = load_scene_config(write_scene(tmp_path, text)).settings_dict()
    (tmp_path / "m.ply").write_bytes(b"changed")
    second = load_scene_config(write_scene(tmp_path, text)).settings_dict()
    assert first["assets"][0][0] == "m.ply" and first["assets"] != second["assets"]


@pytest.mark.parametrize("edited", ["a.mtl", "wood.png", "b.bin"])
def test_mesh_side_files_are_part_of_the_identity(tmp_path, edited):
    """An OBJ's material library and texture, a glTF's buffer: editing one between an interrupted
    render and its resume left the identity as it was, and the resumed frames used the new file."""
    (tmp_path / "a.obj").write_text("mtllib a.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nusemtl m\nf 1/1 2/1 3/1\n")
    (tmp_path / "a.mtl").write_text("newmtl m\nmap_Kd wood.png\n")
    (tmp_path / "wood.png").write_bytes(b"texture")
    (tmp_path / "b.gltf").write_text('{"buffers": [{"uri": "b.bin", "byteLength": 3}]}')
    (tmp_path / "b.bin").write_bytes(b"abc")
    text = BASE + "".join(f'[[objects]]\ngenerator = "mesh"\nfile = "{name}"\n' for name in ("a.obj", "b.gltf"))
    first = load_scene_config(write_scene(tmp_path, text)).settings_dict()["assets"]
    (tmp_path / edited).write_bytes(b"changed")
    second = load_scene_config(write_scene(tmp_path, text)).settings_dict()["assets"]
    assert [name for name, _ in first] == ["a.obj", "a.mtl", "wood.png", "b.gltf", "b.bin"]
    assert first != second


def test_files_a_mitsuba_scene_names_are_part_of_the_identity(tmp_path):
    """A mesh a [scene] mitsuba_xml file names: editing it between an interrupted render and its
    resume left the identity as it was, and the resumed frames used the new mesh."""
    (tmp_path / "room.xml").write_text('<scene version="3.0.0"><shape type="ply">'
                                       '<string name="filename" value="wall.ply"/></shape></scene>')
    (tmp_path / "wall.ply").write_bytes(b"first")
    text = BASE.replace('name = "t"', 'name = "t"\nmitsuba_xml = "room.xml"')
    first = load_scene_config(write_scene(tmp_path, text)).settings_dict()["assets"]
    (tmp_path / "wall.ply").write_bytes(b"changed")
    second = load_scene_config(write_scene(tmp_path, text)).settings_dict()["assets"]
    assert [name for name, _ in first] == ["room.xml", "wall.ply"] and first != second


def test_settings_check_themselves_when_built_in_code():
    with pytest.raises(SettingError, match=r"rolling_shutter: expected <= 1.0, got 2.0"):
        CaptureSettings(rolling_shutter=2.0)
    assert RenderSettings(resolution=96).resolution == (96, 96)
    with pytest.raises(SettingError, match="resolution: expected >= 8"):
        RenderSettings(resolution=(4, 4))
    with pytest.raises(SettingError, match="resolution: expected <= 16384, got \\[1000000000, 1000000000\\]"):
        RenderSettings(resolution=1_000_000_000)


def test_register_generator_declares_and_checks_parameters(tmp_path, monkeypatch):
    from omnisim import generators
    from omnisim.generators import Param, register_generator

    monkeypatch.setattr(generators, "_REGISTRY", dict(generators._REGISTRY))

    @register_generator("pyramid", Param("height", "float", 1.0, "apex height, metres", minimum=0.0),
                        Param("material", "material", "wood", "material"))
    def _pyramid(ctx):
        """A test pyramid."""

    config = load_scene_config(write_scene(tmp_path, BASE + '[[objects]]\ngenerator = "pyramid"\nheight = 2\n'))
    assert config.objects[1].params == {"height": 2.0, "material": "wood"}
    with pytest.raises(InputError, match=r"\(pyramid\) width: unknown key; accepted keys: generator, height, "
                                         r"material"):
        load_scene_config(write_scene(tmp_path, BASE + '[[objects]]\ngenerator = "pyramid"\nwidth = 2\n'))
    with pytest.raises(ValueError, match="already registered"):
        register_generator("pyramid")(_pyramid)
    assert "pyramid: A test pyramid." in generators.describe_generators()


def test_cli_generators_lists_every_generator_with_parameter_docs(capsys):
    from omnisim.cli import main
    from omnisim.generators import registered_generators

    assert main(["generators"]) == 0
    out = capsys.readouterr().out
    for name, gen in registered_generators().items():
        assert f"{name}: {gen.doc}" in out
        for p in gen.params:
            assert f"    {p.name} ({p.kind}, " in out
    assert "file (file, required): OBJ, PLY, STL, glTF or GLB file" in out


def test_cli_bad_scene_key_is_one_line_exit_2_and_nothing_created(tmp_path, capsys):
    from omnisim.cli import main

    scene = write_scene(tmp_path, BASE.replace("spp = 2", "spp_typo = 2"))
    code = main(["render", str(scene), "--out", str(tmp_path / "out"), "--no-progress"])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1 and "[render] spp_typo: unknown key" in err
    assert not (tmp_path / "out").exists()


def test_cli_bogus_variant_is_one_line_exit_2(tmp_path, capsys):
    from omnisim.cli import main

    code = main(["render", str(write_scene(tmp_path, BASE)), "--out", str(tmp_path / "out"), "--variant", "bogus"])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1 and "--variant: expected one of" in err
    assert not (tmp_path / "out").exists()


def test_cli_more_workers_than_cpus_is_refused(tmp_path, capsys):
    """``--workers 1000000`` started that many local Dask processes, each loading Mitsuba."""
    from omnisim.cli import main

    code = main(["render", str(write_scene(tmp_path, BASE)), "--out", str(tmp_path / "out"), "--workers", "1000000"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and "--workers: expected >= 1 and at most" in err[0]
    assert err[0].endswith("(the CPUs this process may use), got 1000000") and not (tmp_path / "out").exists()


def test_mesh_parts_keep_each_file_appearance(tmp_path):
    """STL: mid grey; PLY face colours: each face its own vertices and colour; vertex colours / 255."""
    import numpy as np

    trimesh = pytest.importorskip("trimesh")

    from omnisim.meshes import DEFAULT_GREY, mesh_parts_from_file

    box = trimesh.creation.box(extents=(1.0, 2.0, 3.0))
    box.export(tmp_path / "box.stl")
    (stl,) = mesh_parts_from_file(tmp_path / "box.stl")
    np.testing.assert_allclose(stl.colors, np.broadcast_to(DEFAULT_GREY, stl.colors.shape))
    np.testing.assert_allclose(np.ptp(stl.positions, axis=0), [1.0, 2.0, 3.0])

    faces = box.copy()
    face_colors = np.zeros((len(faces.faces), 4), np.uint8)
    face_colors[:, 3] = 255
    face_colors[:, 0] = np.arange(len(faces.faces)) * 20
    faces.visual.face_colors = face_colors
    faces.export(tmp_path / "faces.ply")
    (part,) = mesh_parts_from_file(tmp_path / "faces.ply")
    assert part.positions.shape == (3 * len(box.faces), 3)
    np.testing.assert_allclose(part.colors[::3, 0], face_colors[:, 0] / 255.0)
    np.testing.assert_allclose(part.colors[1::3], part.colors[::3])

    verts = box.copy()
    verts.visual.vertex_colors = np.tile([255, 128, 0, 255], (len(box.vertices), 1)).astype(np.uint8)
    verts.export(tmp_path / "verts.ply")
    (part,) = mesh_parts_from_file(tmp_path / "verts.ply")
    np.testing.assert_allclose(part.colors, np.broadcast_to([1.0, 128 / 255, 0.0], part.colors.shape))


def test_unreadable_mesh_file_is_one_line_error(tmp_path):
    pytest.importorskip("trimesh")
    from omnisim.meshes import mesh_parts_from_file

    (tmp_path / "empty.ply").write_text("ply\nformat ascii 1.0\nelement vertex 0\nend_header\n")
    with pytest.raises(InputError, match=r"empty.ply: (mesh file holds no triangles|cannot read mesh file)"):
        mesh_parts_from_file(tmp_path / "empty.ply")
    (tmp_path / "junk.glb").write_bytes(b"\x00\x01junk")
    with pytest.raises(InputError, match=r"junk.glb: cannot read mesh file"):
        mesh_parts_from_file(tmp_path / "junk.glb")


@pytest.mark.parametrize("vertex, key, message", [
    ("nan 0 0", None, r"tri.obj: geometry 0 vertex 0: expected finite coordinates, got \[nan, 0.0, 0.0\]"),
    ("inf 0 0", None, r"tri.obj: geometry 0 vertex 0: expected finite coordinates, got \[inf, 0.0, 0.0\]"),
    ("1e37 0 0", "scale = 100", r"scene.toml: \[\[objects\]\] #2 \(mesh\) scale: expected at most 3.4e\+38 / 1e\+37 "
                                r"\(the mesh's reach in file units; the renderer stores float32 metres\), got 100"),
    ("3e38 0 0", "position = [3e38, 0, 0]", r"scene.toml: \[\[objects\]\] #2 \(mesh\) position: expected the placed "
                                          r"mesh within 1e\+09 m of the origin \(float32 ray tracing loses larger "
                                          r"surfaces\), got 6e\+38 m"),
    ("0 0 0", "position = [4e9, 0, 0]", r"\(mesh\) position: expected the placed mesh within 1e\+09 m .*got 4e\+09 m"),
    ("1 0 0", "scale = 1e30", r"\(mesh\) scale: expected the placed mesh within 1e\+09 m .*got 1e\+30 m"),
    ("0 0 0", "scale = 1e300", r"scene.toml: \[\[objects\]\] #2 \(mesh\) scale: expected magnitudes <= 3.403e\+38 "
                               r"\(the renderer stores float32\), got 1e\+300"),
])
def test_cli_mesh_the_renderer_cannot_hold_is_one_line_exit_2(tmp_path, capsys, vertex, key, message):
    pytest.importorskip("trimesh")
    from omnisim.cli import main

    (tmp_path / "tri.obj").write_text(f"v {vertex}\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    scene = write_scene(tmp_path, BASE + f'[[objects]]\ngenerator = "mesh"\nfile = "tri.obj"\n{key or ""}\n')
    code = main(["render", str(scene), "--out", str(tmp_path / "out"), "--no-progress"])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1 and re.search(message, err), err
    assert not (tmp_path / "out").exists()


def _ascii_ply(vertices, faces) -> str:
    header = ["ply", "format ascii 1.0", f"element vertex {len(vertices)}", "property float x", "property float y",
              "property float z", f"element face {len(faces)}", "property list uchar int vertex_indices", "end_header"]
    return "\n".join(header + [" ".join(map(str, v)) for v in vertices]
                     + [" ".join(map(str, [len(f), *f])) for f in faces]) + "\n"


@pytest.mark.parametrize("name, text, message", [
    ("far.ply", _ascii_ply([(0, 0, 0), (1, 0, 0), (0, 1, 0)], [(0, 1, 2), (0, 1, 57)]),
     r"far.ply: geometry 0 face 1: vertex indices \[0, 1, 57\], expected 0 to 2 \(the mesh has 3 vertices\)"),
    ("negative.ply", _ascii_ply([(0, 0, 0), (1, 0, 0), (0, 1, 0)], [(0, 1, -5)]),
     r"negative.ply: geometry 0 face 0: vertex indices \[0, 1, -5\], expected 0 to 2"),
    ("flat.obj", "v 0 0\nv 1 0\nv 0 1\nf 1 2 3\n",
     r"flat.obj: geometry 0: expected 3 coordinates per vertex, got an array of shape \(3, 2\)"),
])
def test_mesh_faces_naming_missing_vertices_are_refused(tmp_path, name, text, message):
    """Readers pass such faces on, and Mitsuba rendered them (with exit 0) or raised a traceback."""
    pytest.importorskip("trimesh")
    from omnisim.meshes import mesh_parts_from_file

    (tmp_path / name).write_text(text)
    with pytest.raises(InputError, match=message):
        mesh_parts_from_file(tmp_path / name)


def test_cli_obj_with_a_nan_texture_coordinate_is_one_line_exit_2(tmp_path, capsys):
    """``vt nan 0`` passed the reader; the NaN texture lookups rendered black pixels with exit 0."""
    pytest.importorskip("trimesh")
    from omnisim.cli import main

    (tmp_path / "tri.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nvt nan 0\nvt 1 0\nvt 0 1\nf 1/1 2/2 3/3\n")
    scene = write_scene(tmp_path, BASE + '[[objects]]\ngenerator = "mesh"\nfile = "tri.obj"\n')
    code = main(["render", str(scene), "--out", str(tmp_path / "out"), "--no-progress"])
    assert code == 2
    assert capsys.readouterr().err.strip() == (f"omnisim render: error: {tmp_path / 'tri.obj'}: geometry 0 vertex 0: "
                                               "expected finite texture coordinates, got [nan, 0.0]")
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("content", ["[]", "{\"images\": []}", "{broken"])
def test_meta_json_that_is_not_a_dataset_record_is_refused_in_one_line(tmp_path, content):
    from omnisim.renderer import check_output_folder

    (tmp_path / "meta.json").write_text(content)
    with pytest.raises(InputError, match=r"meta.json: (expected a JSON object|unreadable meta.json)"):
        check_output_folder(tmp_path, {"seed": 1})


def test_hand_written_obj_with_two_materials_gives_two_base_coloured_parts(tmp_path):
    """An OBJ written by hand (not by trimesh): each `usemtl` group keeps its Kd (stored as 8 bits)."""
    import numpy as np

    pytest.importorskip("trimesh")
    from omnisim.meshes import mesh_parts_from_file

    (tmp_path / "two.mtl").write_text("newmtl red\nKd 0.8 0.1 0.1\nnewmtl blue\nKd 0.1 0.2 0.9\n")
    (tmp_path / "two.obj").write_text("mtllib two.mtl\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 0 0 1\nv 1 0 1\n"
                                      "usemtl red\nf 1 2 3\nf 1 3 4\nusemtl blue\nf 1 2 6\nf 1 6 5\n")
    parts = mesh_parts_from_file(tmp_path / "two.obj")
    colors = sorted(tuple(np.round(p.colors[0], 2)) for p in parts)
    assert colors == [(0.1, 0.2, 0.9), (0.8, 0.1, 0.1)]
    assert all(len(p.faces) == 2 and np.allclose(p.colors, p.colors[0], atol=1 / 255) for p in parts)


def test_obj_checks_before_the_reader_share_one_read_of_the_file(tmp_path, monkeypatch):
    """The face-index scan and the material-library scan each read the OBJ again before the reader did."""
    import pathlib

    pytest.importorskip("trimesh")
    from omnisim.meshes import mesh_parts_from_file

    (tmp_path / "two.mtl").write_text("newmtl red\nKd 0.8 0.1 0.1\n")
    (tmp_path / "two.obj").write_text("mtllib two.mtl\nv 0 0 0\nv 1 0 0\nv 1 1 0\nusemtl red\nf 1 2 3\n")
    reads, read_bytes = [], pathlib.Path.read_bytes
    monkeypatch.setattr(pathlib.Path, "read_bytes", lambda self: reads.append(self.name) or read_bytes(self))
    (part,) = mesh_parts_from_file(tmp_path / "two.obj")
    assert reads.count("two.obj") == 1 and len(part.faces) == 1


def test_obj_whose_material_files_are_missing_warns_in_one_line(tmp_path):
    import warnings

    import cv2
    import numpy as np

    pytest.importorskip("trimesh")
    from ifmi.errors import InputWarning
    from omnisim.meshes import mesh_parts_from_file

    (tmp_path / "a.obj").write_text("mtllib a.mtl\nmtllib gone.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\n"
                                    "vt 0 0\nvt 1 0\nvt 0 1\nusemtl m\nf 1/1 2/2 3/3\n")
    (tmp_path / "a.mtl").write_text("newmtl m\nKd 0.5 0.5 0.5\nmap_Kd wood grain.png\n")
    with pytest.warns(InputWarning) as record:
        mesh_parts_from_file(tmp_path / "a.obj")
    assert [str(w.message) for w in record] == [
        f"{tmp_path / 'a.obj'}: texture wood grain.png (named by a.mtl) not found, material library gone.mtl "
        "not found; the geometries that use them render with their base colour or grey"]
    # With the files there (a name with a space, after options), nothing is said.
    (tmp_path / "a.obj").write_text((tmp_path / "a.obj").read_text().replace("mtllib gone.mtl\n", ""))
    (tmp_path / "a.mtl").write_text("newmtl m\nKd 0.5 0.5 0.5\nmap_Kd -s 1 1 1 wood grain.png\n")
    cv2.imwrite(str(tmp_path / "wood grain.png"), np.full((4, 4, 3), 128, np.uint8))
    with warnings.catch_warnings():
        warnings.simplefilter("error", InputWarning)
        mesh_parts_from_file(tmp_path / "a.obj")
    # A texture that is there but holds no image was dropped by the reader without a word.
    import struct
    import zlib

    def chunk(kind, body):
        return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))

    # A PNG whose header claims 20000 x 20000 pixels: the reader's guard against decompression bombs drops it.
    bomb = (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", 20000, 20000, 8, 2, 0, 0, 0))
            + chunk(b"IDAT", zlib.compress(bytes(64))) + chunk(b"IEND", b""))
    for content, problem in ((b"", "is empty"), (b"not a picture", "is no image file"),
                             (b"\x89PNG\r\n\x1a\ngarbage!", "is a damaged image file"),  # a header Pillow cannot parse
                             (bomb, r"is too large to be read \(more than \d+ pixels\)")):
        (tmp_path / "wood grain.png").write_bytes(content)
        # (after options the name is shown as its last word)
        with pytest.warns(InputWarning, match=rf"a.obj: texture grain.png \(named by a.mtl\) {problem}; the "
                                              r"geometries that use it render with their base colour or grey"):
            mesh_parts_from_file(tmp_path / "a.obj")


def test_obj_that_is_not_utf8_is_read(tmp_path):
    """Exporters write comments and names in their locale's encoding (here Latin-1 'für')."""
    import numpy as np

    pytest.importorskip("trimesh")
    from omnisim.meshes import mesh_parts_from_file

    (tmp_path / "latin.obj").write_bytes(b"# Modell f\xfcr Tests\nv 0 0 0\nv 2 0 0\nv 0 3 0\nf 1 2 3\n")
    (part,) = mesh_parts_from_file(tmp_path / "latin.obj")
    np.testing.assert_allclose(np.ptp(part.positions, axis=0), [2.0, 3.0, 0.0])


@pytest.mark.parametrize("line, shown", [("v 0 1 0 0.5 -0.25 0.5", "-0.25"), ("v 0 1 0 nan 0.5 0.5", "nan"),
                                         ("v 0 1 0 0.5 0.5 255", "255")])
def test_obj_vertex_colour_outside_0_1_is_refused(tmp_path, line, shown):
    """The reader stored vertex colours as 8 bits: a negative value or NaN became 0 (black) and 255
    became 1, with exit 0."""
    pytest.importorskip("trimesh")
    from omnisim.meshes import mesh_parts_from_file

    (tmp_path / "c.obj").write_text(f"# colours\nv 0 0 0 0 0 0\nv 1 0 0 1 1 1\n{line}\nf 1 2 3\n")
    with pytest.raises(InputError) as caught:
        mesh_parts_from_file(tmp_path / "c.obj")
    assert str(caught.value) == (f"{tmp_path / 'c.obj'}: line 4 ({line!r}): expected vertex colour values in [0, 1] "
                                 f"(linear reflectance), got {shown}")


def test_obj_vertex_colours_in_0_1_are_kept(tmp_path):
    import numpy as np

    pytest.importorskip("trimesh")
    from omnisim.meshes import mesh_parts_from_file

    (tmp_path / "c.obj").write_text("v 0 0 0 0 0 0\nv 1 0 0 1 1 1\nv 0 1 0 0.2 0.6 1.0\nf 1 2 3\n")
    (part,) = mesh_parts_from_file(tmp_path / "c.obj")
    np.testing.assert_allclose(part.colors, [[0, 0, 0], [1, 1, 1], [0.2, 0.6, 1.0]], atol=0.5 / 255)


@pytest.mark.parametrize("kd, shown", [("Kd -0.3 0.5 0.5", "-0.3"), ("Kd 0.3 nan 0.5", "nan"),
                                       ("kd 0.3 0.5 1.5", "1.5")])
def test_mtl_diffuse_colour_outside_0_1_is_one_line_exit_2(tmp_path, capsys, kd, shown):
    """A material's Kd was stored as 8 bits: -0.3 and NaN became 0, 1.5 became 1, and the render
    finished with exit 0."""
    pytest.importorskip("trimesh")
    from omnisim.cli import main

    (tmp_path / "m.mtl").write_text(f"newmtl ok\nKd 0 0.5 1\nnewmtl bad\n{kd}\n")
    (tmp_path / "m.obj").write_text("mtllib m.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nusemtl bad\nf 1 2 3\n")
    scene = write_scene(tmp_path, BASE + '[[objects]]\ngenerator = "mesh"\nfile = "m.obj"\n')
    code = main(["render", str(scene), "--out", str(tmp_path / "out"), "--no-progress"])
    assert code == 2
    assert capsys.readouterr().err.strip() == (f"omnisim render: error: {tmp_path / 'm.mtl'}: line 4 ({kd!r}): "
                                               "expected diffuse colour (Kd) values in [0, 1] (linear reflectance), "
                                               f"got {shown}")
    assert not (tmp_path / "out").exists()


OBJ_HEAD = "v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 0 1\nvn 0 0 1\n"


@pytest.mark.parametrize("face", ["f 0 1 2", "f 1/1 2/2 0/3", "f 1//1 0//1 2//1", "f 1/1/1 2/0/1 3/3/1"])
def test_obj_face_index_zero_is_refused(tmp_path, face):
    """OBJ counts from 1: the reader took index 0 for the last vertex (or dropped it) and the render
    finished with exit 0."""
    pytest.importorskip("trimesh")
    from omnisim.meshes import mesh_parts_from_file

    (tmp_path / "zero.obj").write_text(OBJ_HEAD + face + "\n")
    with pytest.raises(InputError, match=rf"zero.obj: line 8 \('{face}'\): expected face indices from 1 \(OBJ "
                                         r"counts from 1, negative ones back from the last\), got 0"):
        mesh_parts_from_file(tmp_path / "zero.obj")


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no FIFOs on this system")
@pytest.mark.parametrize("name, text", [
    ("box.obj", "mtllib side.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n"),
    ("box.gltf", '{"asset": {"version": "2.0"}, "images": [{"uri": "side.mtl"}]}'),
])
def test_side_file_that_is_a_fifo_is_refused(tmp_path, name, text):
    """A material library or texture that is a FIFO made the reader wait forever."""
    pytest.importorskip("trimesh")
    from omnisim.meshes import mesh_parts_from_file

    os.mkfifo(tmp_path / "side.mtl")
    (tmp_path / name).write_text(text)
    with pytest.raises(InputError, match=rf"{name}: names side.mtl, which is not a regular file"):
        mesh_parts_from_file(tmp_path / name)


def test_obj_negative_face_indices_are_read(tmp_path):
    import numpy as np

    pytest.importorskip("trimesh")
    from omnisim.meshes import mesh_parts_from_file

    (tmp_path / "back.obj").write_text(OBJ_HEAD + "f -3/-3 -2/-2 -1/-1\n")
    (part,) = mesh_parts_from_file(tmp_path / "back.obj")
    np.testing.assert_allclose(part.positions[part.faces[0]], [[0, 0, 0], [1, 0, 0], [0, 1, 0]])


@pytest.mark.parametrize("lines, partial, rows", [(8 + 5, "", "8 vertex and 5 face"),
                                                  (8 + 5, "3 4", "8 vertex and 6 face"),
                                                  (5, "", "5 vertex and 0 face")])
def test_ascii_ply_that_ends_early_is_refused(tmp_path, lines, partial, rows):
    """The reader kept the rows that were there: a box cut after 5 of its 12 faces rendered with exit 0."""
    trimesh = pytest.importorskip("trimesh")
    from omnisim.meshes import mesh_parts_from_file

    box = trimesh.creation.box()
    header, body = _ascii_ply(box.vertices.tolist(), box.faces.tolist()).split("end_header\n")
    (tmp_path / "cut.ply").write_text(header + "end_header\n" + "".join(body.splitlines(True)[:lines]) + partial)
    with pytest.raises(InputError, match=rf"cut.ply: expected 8 vertex and 12 face rows \(as its header says\), "
                                         rf"the file ends after {rows} rows"):
        mesh_parts_from_file(tmp_path / "cut.ply")


def test_ascii_ply_cut_inside_its_last_row_is_refused(tmp_path):
    """The reader dropped a face whose row the file ended inside (its last index gone), and the row
    counts matched the header: the mesh rendered with a face missing and exit 0."""
    trimesh = pytest.importorskip("trimesh")
    from omnisim.meshes import mesh_parts_from_file

    box = trimesh.creation.box()
    text = _ascii_ply(box.vertices.tolist(), box.faces.tolist())
    last = text.rstrip("\n").rsplit("\n", 1)[1]
    (tmp_path / "cut.ply").write_text(text.rstrip("\n")[:-len(last)] + last.rsplit(" ", 1)[0] + "\n")
    with pytest.raises(InputError, match=r"cut.ply: its last face row holds 3 of the 4 values its properties "
                                         r"take: the file ends inside that row"):
        mesh_parts_from_file(tmp_path / "cut.ply")
    (tmp_path / "whole.ply").write_text(text)
    assert len(mesh_parts_from_file(tmp_path / "whole.ply")) == 1


def test_binary_ply_that_ends_early_is_refused(tmp_path):
    """The binary reader finds the file too short itself."""
    trimesh = pytest.importorskip("trimesh")
    from omnisim.meshes import mesh_parts_from_file

    (tmp_path / "cut.ply").write_bytes(trimesh.creation.box().export(file_type="ply")[:-40])
    with pytest.raises(InputError, match=r"cut.ply: cannot read mesh file"):
        mesh_parts_from_file(tmp_path / "cut.ply")


def test_gltf_webp_texture_is_read_without_a_warning(tmp_path):
    """Pillow reads WebP, and so the mesh reader took the texture, but it was warned about as no image file."""
    import json
    import warnings

    import numpy as np

    trimesh = pytest.importorskip("trimesh")
    from PIL import Image, features

    from ifmi.errors import InputWarning
    from omnisim.meshes import mesh_parts_from_file

    if not features.check("webp"):
        pytest.skip("this Pillow reads no WebP")
    image = Image.fromarray(np.full((4, 4, 3), 200, np.uint8))
    image.save(tmp_path / "wood.webp")
    quad = trimesh.Trimesh([[0, 0, 0], [1, 0, 0], [1, 1, 0]], [[0, 1, 2]], process=False,
                           visual=trimesh.visual.TextureVisuals(uv=[[0, 0], [1, 0], [1, 1]], image=image))
    files = quad.export(file_type="gltf")
    for file, data in files.items():
        (tmp_path / file).write_bytes(data)
    tree = json.loads(files["model.gltf"])
    tree["images"] = [{"uri": "wood.webp"}]
    (tmp_path / "quad.gltf").write_text(json.dumps(tree))
    with warnings.catch_warnings():
        warnings.simplefilter("error", InputWarning)
        (part,) = mesh_parts_from_file(tmp_path / "quad.gltf")
    assert part.image is not None


@pytest.mark.parametrize("name, uri, content, problem", [
    ("quad.gltf", "gone.png", None, "texture gone.png not found"),
    ("quad.gltf", "wood grain.png", b"not a picture", "texture wood grain.png is no image file"),
    ("quad.gltf", "cut.png", b"\x89PNG\r\n\x1a\ngarbage!", "texture cut.png is a damaged image file"),
    ("quad.glb", None, b"not a picture", "texture image 0 is no image file"),
])
def test_gltf_texture_that_cannot_be_read_warns_in_one_line(tmp_path, name, uri, content, problem):
    """The reader dropped such a texture without a word; the quad renders with its base colour."""
    import json
    import warnings

    import numpy as np

    trimesh = pytest.importorskip("trimesh")
    from PIL import Image

    from ifmi.errors import InputWarning
    from omnisim.meshes import mesh_parts_from_file

    image = Image.fromarray(np.full((4, 4, 3), 200, np.uint8))
    quad = trimesh.Trimesh([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], [[0, 1, 2], [0, 2, 3]], process=False,
                           visual=trimesh.visual.TextureVisuals(uv=[[0, 0], [1, 0], [1, 1], [0, 1]], image=image))
    files = quad.export(file_type="gltf")  # the image is a buffer of its own
    for file, data in files.items():
        (tmp_path / file).write_bytes(data)
    tree = json.loads(files["model.gltf"])
    png = files[tree["buffers"][tree["bufferViews"][tree["images"][0]["bufferView"]]["buffer"]]["uri"]]
    glb = quad.export(file_type="glb")
    (tmp_path / "quad.glb").write_bytes(glb.replace(png, content.ljust(len(png), b" ")) if uri is None else glb)
    tree["images"] = [{"uri": uri}]
    (tmp_path / "quad.gltf").write_text(json.dumps(tree))
    if uri is not None:  # first the intact image at that name: nothing is said
        (tmp_path / uri).write_bytes(png)
        with warnings.catch_warnings():
            warnings.simplefilter("error", InputWarning)
            (part,) = mesh_parts_from_file(tmp_path / name)
        assert part.image is not None
        (tmp_path / uri).unlink()
        if content is not None:
            (tmp_path / uri).write_bytes(content)
    with pytest.warns(InputWarning, match=rf"{name}: {problem}; the geometries that use it render with their "
                                          r"base colour or grey"):
        (part,) = mesh_parts_from_file(tmp_path / name)
    assert part.image is None


def test_capture_must_end_by_the_next_frame(tmp_path):
    with pytest.raises(SettingError, match=r"exposure \+ rolling_shutter: expected <= 1"):
        CaptureSettings(exposure=0.7, rolling_shutter=0.5)
    assert CaptureSettings(exposure=0.5).timed and not CaptureSettings(vignetting=0.3).timed


def test_identity_of_a_plain_scene_is_unchanged_by_the_new_tables(tmp_path):
    """Folders rendered before [capture] and asset hashes existed keep their identity."""
    settings = load_scene_config(write_scene(tmp_path, BASE)).settings_dict()
    assert set(settings) == {"render", "trajectory", "effects", "camera"}


def test_camera_table_lists_kalibr_among_its_keys(tmp_path):
    with pytest.raises(InputError, match=r"\[camera\] kalibrr: unknown key; accepted keys: kalibr, calib, pol"):
        load_scene_config(write_scene(tmp_path, BASE.replace("[camera]\n", '[camera]\nkalibrr = "c.yaml"\n')))


def test_a_tum_trajectory_keeps_its_positions_unless_position_is_written(tmp_path):
    """A render's own poses_world.txt fed back as [trajectory] tum gave a camera 1.2 m higher than the
    file says (the default position was added); now the positions are the file's, and an explicit
    position is still an offset."""
    import numpy as np

    from ifmi.io.tum import write_tum
    from omnisim.motion import poses_for_settings, world_trajectory

    walking = BASE.replace("frames = 2", "frames = 3\ntranslation_step_m = 0.05")
    walked = load_scene_config(write_scene(tmp_path, walking))
    original = poses_for_settings(walked.trajectory, seed=2)
    write_tum(tmp_path / "poses_world.txt", world_trajectory(original))
    with_tum = BASE.replace("frames = 2", 'frames = 3\ntum = "poses_world.txt"')
    replayed = load_scene_config(write_scene(tmp_path, with_tum, "replay.toml"))
    assert replayed.trajectory.position == (0.0, 0.0, 0.0)
    poses = poses_for_settings(replayed.trajectory, seed=2)
    np.testing.assert_allclose(poses.positions, original.positions, atol=1e-9)  # TUM text keeps 9 decimals
    np.testing.assert_allclose(poses.rotations, original.rotations, atol=1e-8)
    with_offset = with_tum.replace("frames = 3", "frames = 3\nposition = [0, 0, 1.2]")
    shifted = load_scene_config(write_scene(tmp_path, with_offset, "shifted.toml"))
    np.testing.assert_allclose(poses_for_settings(shifted.trajectory, seed=2).positions,
                               original.positions + [0.0, 0.0, 1.2], atol=1e-9)
