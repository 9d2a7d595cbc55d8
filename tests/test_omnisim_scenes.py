"""Any scene: mesh files, Mitsuba XML scenes and environment maps, written at test time and rendered small."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import numpy as np
import pytest
from scene_files import camera_128_section

# Mitsuba must not be imported here: omnisim.llvm selects drjit's LLVM before the first import.
if importlib.util.find_spec("mitsuba") is None:
    pytest.skip("mitsuba is not installed (sim extra)", allow_module_level=True)

sys.path.insert(0, str(Path(__file__).parent))
from test_omnisim_dataset import _warp_error  # noqa: E402

pytestmark = pytest.mark.render

SIZE = 128
# The same catadioptric calibration as the dataset tests (band 10..61.5 px).
CAMERA = "\n" + camera_128_section()


def _scene_text(*, frames, spp, yaw=4.0, position=(0.3, -0.2, 1.3), extra="", scene=""):
    return f"""
[scene]
seed = 3
{scene}

[render]
resolution = [{SIZE}, {SIZE}]
spp = {spp}
max_depth = 2
{CAMERA}
[trajectory]
frames = {frames}
position = {list(position)}
max_yaw_step_deg = {yaw}
max_roll_deg = 15.0
max_pitch_deg = 15.0
max_tilt_step_deg = 2.0
smoothness_frames = 2.0
{extra}
"""


def _texture_uint8(seed, size=256):
    """A smooth, seeded colour texture, 8-bit sRGB."""
    from omnisim.effects import srgb_uint8_from_linear
    from omnisim.textures import noise_texture

    return srgb_uint8_from_linear(noise_texture(size, seed=seed, octaves=5, base_cells=6,
                                                color_a=(0.05, 0.1, 0.2), color_b=(0.9, 0.7, 0.4)))


def _textured_room_obj(folder: Path, *, size=(6.0, 5.0, 3.0), tile=1.5) -> Path:
    """An OBJ box room (faces inward, metric UVs, one noise texture) written with trimesh."""
    import trimesh
    from PIL import Image

    from omnisim.geometry import box_mesh

    center = (0.0, 0.0, size[2] / 2)
    positions, faces, uvs = box_mesh(center, size, tile=tile, inward=True)
    visual = trimesh.visual.TextureVisuals(uv=uvs, image=Image.fromarray(_texture_uint8(4)))
    mesh = trimesh.Trimesh(positions, faces, visual=visual, process=False)
    path = folder / "room.obj"
    mesh.export(path)
    return path


def _ground_truth_errors(out: Path, frames: int):
    """Photometric error of warping the last frame into frame 0 with R_0k, identity and R_0k^T."""
    import cv2

    from ifmi.geometry.camera import radius_from_pixels
    from ifmi.io.calib import read_calib
    from ifmi.io.tum import read_tum

    model = read_calib(out / "calib_results.txt")
    gt = read_tum(out / "groundtruth.txt")
    gray = [cv2.GaussianBlur(cv2.cvtColor(cv2.imread(str(out / "images" / f"{k:06d}.png")),
                                          cv2.COLOR_BGR2GRAY), (0, 0), 1.0)
            for k in (0, frames - 1)]
    rows, cols = np.mgrid[0:SIZE, 0:SIZE]
    r0 = radius_from_pixels(model, np.stack([rows, cols], axis=-1))
    mask = (r0 > 12.0) & (r0 < 59.5)
    rotation = gt.rotations[frames - 1]
    angle = np.degrees(np.arccos(np.clip((np.trace(rotation) - 1) / 2, -1, 1)))
    errors = [_warp_error(gray[0], gray[1], model, r, mask) for r in (rotation, np.eye(3), rotation.T)]
    return angle, errors, float(np.std(gray[0][mask]))


def test_textured_mesh_room_ground_truth_agrees_with_pixels(tmp_path):
    """A room from an OBJ file (texture on its own UVs) lit by procedural ceiling lights.

    Same criterion as the procedural room: the true rotation aligns the last
    frame with frame 0 three times better than the identity or the transposed
    rotation. The texture must reach the image (no flat grey walls).
    """
    from omnisim.renderer import render_dataset

    _textured_room_obj(tmp_path)
    scene = tmp_path / "mesh_room.toml"
    scene.write_text(_scene_text(frames=6, spp=16, extra="""
[[objects]]
generator = "mesh"
file = "room.obj"

[[objects]]
generator = "ceiling_lights"
room = [6.0, 5.0, 3.0]
grid = [2, 2]
size = [2.0, 1.0]
radiance = [3.0, 3.0, 3.0]
"""))
    out = tmp_path / "out"
    render_dataset(scene, out, progress=False)
    angle, (true_err, identity_err, transposed_err), contrast = _ground_truth_errors(out, 6)
    assert angle > 5.0, angle
    assert contrast > 8.0, contrast
    assert true_err * 3 < identity_err, (true_err, identity_err)
    assert true_err * 3 < transposed_err, (true_err, transposed_err)


XML_SCENE = """<scene version="3.0.0">
  <default name="spp" value="4"/>
  <integrator type="path"><integer name="max_depth" value="2"/></integrator>
  <sensor type="perspective">
    <float name="fov" value="45"/>
    <sampler type="independent"><integer name="sample_count" value="$spp"/></sampler>
    <film type="hdrfilm"><integer name="width" value="32"/><integer name="height" value="24"/></film>
  </sensor>
  <bsdf type="twosided" id="walls">
    <bsdf type="diffuse"><texture type="bitmap" name="reflectance">
      <string name="filename" value="textures/walls.png"/>
    </texture></bsdf>
  </bsdf>
  <shape type="cube">
    <transform name="to_world"><scale value="3, 2.5, 1.5"/><translate value="0, 0, 1.5"/></transform>
    <ref id="walls"/>
  </shape>
  <shape type="rectangle">
    <transform name="to_world"><scale value="1.5, 1.0, 1"/><rotate x="1" angle="180"/>
      <translate value="0, 0, 2.98"/></transform>
    <emitter type="area"><rgb name="radiance" value="4.0"/></emitter>
  </shape>
</scene>
"""


def _xml_scene(tmp_path) -> Path:
    import cv2

    (tmp_path / "textures").mkdir()
    cv2.imwrite(str(tmp_path / "textures" / "walls.png"), _texture_uint8(9, size=128)[..., ::-1])
    (tmp_path / "room.xml").write_text(XML_SCENE)
    scene = tmp_path / "xml_room.toml"
    scene.write_text(_scene_text(frames=6, spp=16, scene='mitsuba_xml = "room.xml"', extra="""
[materials.painted]
vertex_color = true

[[objects]]
generator = "boxes"
count = 4
region = [4.0, 3.0]
clear_radius = 1.2
"""))
    return scene


def test_mitsuba_xml_scene_ground_truth_agrees_with_pixels(tmp_path):
    """A Mitsuba XML room (textured cube, area light, its own integrator and a sensor that must be ignored)
    with procedural boxes added on top: the omni camera renders it at the TOML's size and the
    ground truth aligns the frames as for the procedural room."""
    import cv2

    from omnisim.renderer import render_dataset

    scene = _xml_scene(tmp_path)
    out = tmp_path / "out"
    render_dataset(scene, out, progress=False)
    assert cv2.imread(str(out / "images" / "000000.png")).shape == (SIZE, SIZE, 3)
    angle, (true_err, identity_err, transposed_err), contrast = _ground_truth_errors(out, 6)
    assert angle > 5.0, angle
    assert contrast > 8.0, contrast
    assert true_err * 3 < identity_err, (true_err, identity_err)
    assert true_err * 3 < transposed_err, (true_err, transposed_err)


def test_mitsuba_xml_adds_its_shapes_and_toml_objects_on_top(tmp_path):
    """The loaded scene holds the XML's two shapes, the procedural boxes, the omni sensor only."""
    from omnisim.config import load_scene_config
    from omnisim.renderer import OmniRenderer

    renderer = OmniRenderer(load_scene_config(_xml_scene(tmp_path), spp=1, resolution=32))
    scene = renderer.scene
    # The XML's perspective sensor is gone: the only sensor renders the calibration's 32x32 film.
    assert len(scene.sensors()) == 1
    assert tuple(scene.sensors()[0].film().size()) == (32, 32)
    names = sorted(s.class_name() for s in scene.shapes())
    assert names.count("Cube") == 1 and names.count("Rectangle") == 1, names
    assert len(scene.shapes()) == 3, names  # cube, light, the merged boxes mesh
    assert scene.integrator().class_name() == "PathIntegrator"


def test_mitsuba_xml_without_integrator_uses_the_toml_render_settings(tmp_path):
    from omnisim.config import load_scene_config
    from omnisim.renderer import OmniRenderer

    scene = _xml_scene(tmp_path)
    xml = tmp_path / "room.xml"
    xml.write_text(XML_SCENE.replace('<integrator type="path"><integer name="max_depth" value="2"/></integrator>',
                                     ""))
    text = scene.read_text().replace("max_depth = 2", "max_depth = 5")
    scene.write_text(text)
    renderer = OmniRenderer(load_scene_config(scene, spp=1, resolution=32))
    assert "max_depth = 5" in str(renderer.scene.integrator())


def test_broken_mitsuba_xml_is_one_line_error_before_the_folder_exists(tmp_path):
    from ifmi.errors import InputError
    from omnisim.renderer import render_dataset

    scene = _xml_scene(tmp_path)
    (tmp_path / "room.xml").write_text(XML_SCENE.replace("textures/walls.png", "textures/missing.png"))
    with pytest.raises(InputError, match=r"room.xml: Mitsuba cannot load it"):
        render_dataset(scene, tmp_path / "out", progress=False)
    assert not (tmp_path / "out").exists()
    (tmp_path / "room.xml").write_text("<scene><shape")
    with pytest.raises(InputError, match=r"room.xml: not a readable Mitsuba scene file"):
        render_dataset(scene, tmp_path / "out", progress=False)


@pytest.mark.parametrize("old, new, message", [
    ('<rgb name="radiance" value="4.0"/>', '<rgb name="radiance" value="nan"/>',
     "<emitter> radiance.value: expected values from 0 to 1e+27 (emitted light), got [nan, nan, nan]"),
    ('<bsdf type="diffuse"><texture type="bitmap" name="reflectance">\n      <string name="filename" '
     'value="textures/walls.png"/>\n    </texture></bsdf>', '<bsdf type="diffuse"><rgb name="reflectance" value="nan"/>'
     '</bsdf>', "<bsdf id='walls'> brdf_0.reflectance.value: expected finite values, got [nan, nan, nan]"),
])
def test_mitsuba_xml_nan_light_or_colour_is_one_line_exit_2(tmp_path, capsys, old, new, message):
    """A NaN (or infinite, or negative) radiance or a NaN reflectance in the Mitsuba file rendered
    black pixels with exit 0 (a NaN light: all-black frames, said only as "the camera sees no light")."""
    from omnisim.cli import main

    scene = _xml_scene(tmp_path)
    assert old in XML_SCENE
    (tmp_path / "room.xml").write_text(XML_SCENE.replace(old, new))
    assert main(["render", str(scene), "--out", str(tmp_path / "out"), "--no-progress"]) == 2
    assert capsys.readouterr().err.strip() == f"omnisim render: error: {tmp_path / 'room.xml'}: {message}"
    assert not (tmp_path / "out").exists()


def _render_one(tmp_path, extra, *, position=(0.0, 0.0, 0.0), spp=4, name="one"):
    """Render frame 0 of a scene and return (linear RGB image, model, camera-to-world rotation)."""
    import cv2

    from ifmi.io.calib import read_calib
    from ifmi.io.tum import read_tum
    from omnisim.effects import linear_from_srgb_uint8
    from omnisim.renderer import render_dataset

    scene = tmp_path / f"{name}.toml"
    scene.write_text(_scene_text(frames=1, spp=spp, yaw=0.0, position=position, extra=extra))
    out = tmp_path / name
    render_dataset(scene, out, progress=False)
    image = linear_from_srgb_uint8(cv2.imread(str(out / "images" / "000000.png"))[..., ::-1])
    return image, read_calib(out / "calib_results.txt"), read_tum(out / "poses_world.txt").rotations[0]


def _seen(image, model, rotation, direction):
    """Pixel value seen along a world direction (nearest pixel)."""
    from ifmi.geometry.camera import pixels_from_rays

    direction = np.asarray(direction, dtype=np.float64)
    row, col = np.round(pixels_from_rays(model, (direction / np.linalg.norm(direction)) @ rotation)).astype(int)
    return image[row, col]


@pytest.fixture
def latlong_hdr(tmp_path):
    """A lat-long HDR image whose red channel is the column fraction u and green the row fraction v."""
    import cv2

    height, width = 64, 128
    image = np.zeros((height, width, 3), np.float32)
    image[..., 2] = ((np.arange(width) + 0.5) / width)[None, :]   # red (OpenCV writes BGR)
    image[..., 1] = ((np.arange(height) + 0.5) / height)[:, None]  # green
    image[..., 0] = 0.5
    cv2.imwrite(str(tmp_path / "sky.hdr"), image)
    return tmp_path / "sky.hdr"


# Elevation of the probe directions, radians (inside the mirror band of the test calibration).
PROBE_ELEVATION = -0.2


def _probe(azimuth_deg):
    a = np.radians(azimuth_deg)
    return np.array([np.cos(a) * np.cos(PROBE_ELEVATION), np.sin(a) * np.cos(PROBE_ELEVATION),
                     np.sin(PROBE_ELEVATION)])


@pytest.mark.parametrize("yaw_deg", [0.0, 90.0])
def test_envmap_orientation_and_rotation(tmp_path, latlong_hdr, yaw_deg):
    """The documented lat-long orientation: +x sees column u = 0.25, -y u = 0.5, -x u = 0.75; the row
    fraction is 0.5 - elevation / pi. ``rotation_deg`` turns the map about world z by the yaw.
    Tolerance: RGBE stores about 1 % and the nearest pixel spans about 0.01 in u."""
    image, model, rotation = _render_one(tmp_path, f"""
[[lights]]
type = "envmap"
file = "{latlong_hdr.name}"
rotation_deg = [0.0, 0.0, {yaw_deg}]
""")
    expected_v = 0.5 - PROBE_ELEVATION / np.pi
    for azimuth, expected_u in ((0.0, 0.25), (-90.0, 0.5), (180.0, 0.75)):
        value = _seen(image, model, rotation, _probe(azimuth + yaw_deg))
        assert abs(value[0] - expected_u) < 0.03, (azimuth, value)
        assert abs(value[1] - expected_v) < 0.03, (azimuth, value)


def _quadrant_texture():
    """2x2 image: top-left red, top-right green, bottom-left blue, bottom-right white (8-bit)."""
    image = np.zeros((64, 64, 3), np.uint8)
    image[:32, :32] = (255, 0, 0)
    image[:32, 32:] = (0, 255, 0)
    image[32:, :32] = (0, 0, 255)
    image[32:, 32:] = (255, 255, 255)
    return image


def _floor_quad():
    """A 4 m square floor at z = 0 with u along +x and v along +y (u, v in [0, 1])."""
    positions = np.array([[-2.0, -2.0, 0.0], [2.0, -2.0, 0.0], [2.0, 2.0, 0.0], [-2.0, 2.0, 0.0]])
    faces = np.array([[0, 1, 2], [0, 2, 3]])
    uvs = (positions[:, :2] + 2.0) / 4.0
    return positions, faces, uvs


# Expected colour (channel pattern) seen at floor points (x, y): v up is the image's top row.
QUADRANTS = {(-1.0, 1.0): (1, 0, 0), (1.0, 1.0): (0, 1, 0), (-1.0, -1.0): (0, 0, 1), (1.0, -1.0): (1, 1, 1)}


@pytest.mark.parametrize("suffix", ["obj", "glb"])
def test_mesh_texture_orientation(tmp_path, suffix):
    """A textured floor from an OBJ or GLB file shows each image quadrant where its UVs put it."""
    import trimesh
    from PIL import Image

    positions, faces, uvs = _floor_quad()
    visual = trimesh.visual.TextureVisuals(uv=uvs, image=Image.fromarray(_quadrant_texture()))
    trimesh.Trimesh(positions, faces, visual=visual, process=False).export(tmp_path / f"floor.{suffix}")
    image, model, rotation = _render_one(tmp_path, f"""
[[lights]]
type = "constant"
radiance = [1.0, 1.0, 1.0]

[[objects]]
generator = "mesh"
file = "floor.{suffix}"
""", position=(0.0, 0.0, 1.0))
    for (x, y), pattern in QUADRANTS.items():
        value = _seen(image, model, rotation, [x, y, -1.0])
        bright = value > 0.5 * value.max()
        assert value.max() > 0.2 and tuple(bright.astype(int)) == pattern, ((x, y), value)


def test_mesh_vertex_colours_and_placement(tmp_path):
    """A PLY bar with 8-bit vertex colours, scaled, turned and moved: its colour is the 8-bit value / 255
    times the light, and it spans the directions p_world = R(rpy) (scale p) + position gives it.

    The bar is 2 x 0.4 x 0.4 file units along x; scale 0.5 and yaw 90 deg turn it into a 1 m bar
    along y, 2 m ahead on +x: it covers azimuths within +-14 deg at the camera's height, so the
    probes at +-9 deg see it and those at +-20 deg (inside the unscaled bar, outside the scaled
    one) see the environment.
    """
    import trimesh

    bar = trimesh.creation.box(extents=(2.0, 0.4, 0.4))
    bar.visual.vertex_colors = np.tile([204, 51, 102, 255], (len(bar.vertices), 1)).astype(np.uint8)
    bar.export(tmp_path / "bar.ply")
    image, model, rotation = _render_one(tmp_path, """
[[lights]]
type = "constant"
radiance = [1.0, 1.0, 1.0]

[[objects]]
generator = "mesh"
file = "bar.ply"
position = [2.0, 0.0, 0.0]
rotation_deg = [0.0, 0.0, 90.0]
scale = 0.5
""", spp=16)
    albedo = np.array([204, 51, 102]) / 255.0
    for azimuth in (-9.0, 0.0, 9.0):
        # A diffuse face under uniform unit radiance reflects its albedo (a convex box does not shadow itself).
        a = np.radians(azimuth)
        np.testing.assert_allclose(_seen(image, model, rotation, [np.cos(a), np.sin(a), 0.0]), albedo, atol=0.03)
    for azimuth in (-20.0, 20.0, 90.0):
        a = np.radians(azimuth)
        np.testing.assert_allclose(_seen(image, model, rotation, [np.cos(a), np.sin(a), 0.0]), 1.0, atol=0.03)


def test_example_mesh_script_rebuilds_the_shipped_mesh(tmp_path):
    """scripts/make_example_mesh.py writes a file whose geometry, colours and texture pixels equal the
    shipped scenes/meshes/atelier.glb (compared after decoding, so PNG encoder versions do not matter)."""
    import subprocess

    from omnisim.meshes import mesh_parts_from_file

    root = Path(__file__).resolve().parents[1]
    out = tmp_path / "atelier.glb"
    subprocess.run([sys.executable, str(root / "scripts" / "make_example_mesh.py"), "--out", str(out)],
                   check=True, capture_output=True, env={**__import__("os").environ, "PYTHONPATH": str(root)})
    made, shipped = mesh_parts_from_file(out), mesh_parts_from_file(root / "scenes" / "meshes" / "atelier.glb")
    assert len(made) == len(shipped) == 15
    for a, b in zip(made, shipped):
        np.testing.assert_allclose(a.positions, b.positions, atol=1e-6)
        np.testing.assert_array_equal(a.faces, b.faces)
        np.testing.assert_allclose(a.colors, b.colors, atol=1e-6)
        assert (a.image is None) == (b.image is None)
        if a.image is not None:
            np.testing.assert_array_equal(a.image, b.image)
    assert sum(p.image is not None for p in shipped) == 2  # walls and floor are textured


@pytest.mark.parametrize("integrator", ["ptracer", "aov", "depth"])
def test_mitsuba_xml_integrator_that_renders_no_radiance_image_is_refused(tmp_path, integrator):
    """A light tracer samples the sensor from the scene side, which the omni camera does not offer (it
    crashed in the render, after the folder was made); AOV and depth integrators would be written as
    if they were images."""
    from ifmi.errors import InputError
    from omnisim.renderer import render_dataset

    scene = _xml_scene(tmp_path)
    (tmp_path / "room.xml").write_text(XML_SCENE.replace(
        '<integrator type="path"><integer name="max_depth" value="2"/></integrator>',
        f'<integrator type="{integrator}"/>'))
    with pytest.raises(InputError, match=rf"room.xml: <integrator type='{integrator}'>: expected one that renders "
                                         r"radiance from the camera \(path, direct, "):
        render_dataset(scene, tmp_path / "out", progress=False)
    assert not (tmp_path / "out").exists()


def test_two_environment_lights_are_one_line_before_the_folder_exists(tmp_path, capsys):
    from omnisim.cli import main

    sky = '\n[[lights]]\ntype = "constant"\nradiance = [0.5, 0.5, 0.5]\n\n[[lights]]\ntype = "sky"\n'
    scene = tmp_path / "two.toml"
    scene.write_text(_scene_text(frames=1, spp=1, extra=sky))
    assert main(["render", str(scene), "--out", str(tmp_path / "out"), "--no-progress"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.endswith(
        "two.toml: [[lights]] #1 (constant) and #2 (sky): expected at most one environment light "
        "(sky, constant, envmap); Mitsuba takes one per scene")
    # The same through a Mitsuba file's environment light beside the scene file's: Mitsuba's reason.
    _xml_scene(tmp_path)
    (tmp_path / "room.xml").write_text(XML_SCENE.replace("</scene>", '<emitter type="constant"/></scene>'))
    xml_scene = tmp_path / "xml_room.toml"
    xml_scene.write_text(xml_scene.read_text() + '\n[[lights]]\ntype = "sky"\n')
    assert main(["render", str(xml_scene), "--out", str(tmp_path / "out"), "--no-progress", "--frames", "1"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "xml_room.toml: Mitsuba cannot build the scene: " in err
    assert "Only one environment emitter" in err and not (tmp_path / "out").exists()
