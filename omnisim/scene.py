"""Scene construction: a validated :class:`~omnisim.config.SceneConfig` -> Mitsuba scene dict.

Geometry comes from the ``[[objects]]`` generators (:mod:`omnisim.generators`;
``omnisim generators`` lists them), each drawing its random layout from a
generator seeded by the scene's layout seed and the object's index, so the
same file always gives the same scene. Meshes are merged per appearance into
a few large triangle meshes. A ``[scene] mitsuba_xml`` file contributes its
shapes, materials, emitters and integrator (its sensors are dropped); the
procedural objects and lights are added on top. World frame: metres, z up.
"""

from __future__ import annotations

import xml.etree.ElementTree as ElementTree
from pathlib import Path

import numpy as np

from ifmi.errors import InputError

from .config import SceneConfig
from .generators import GeneratorContext, registered_generators
from .geometry import MeshGroup
from .lights import EnvmapLight, emitter_dict
from .materials import Appearance, bsdf_dict
from .settings import MAX_RADIANCE
from .textures import texture_image, texture_side

# Parameters of a Mitsuba emitter that hold the light it gives (:func:`_check_file_values`).
EMITTED_KEYS = ("radiance.value", "irradiance.value", "intensity.value", "data", "scale")

__all__ = ["scene_meshes", "mitsuba_file_entries", "build_scene_dict", "RADIANCE_INTEGRATORS", "mitsuba_reason"]


def scene_meshes(config: SceneConfig) -> tuple[dict, dict]:
    """Run the scene's generators: merged meshes and their appearances (no Mitsuba needed).

    Returns
    -------
    groups : dict
        Appearance name -> :class:`~omnisim.geometry.MeshGroup`.
    appearances : dict
        Appearance name -> :class:`~omnisim.materials.Appearance` (the
        ``[materials.*]`` entries and those the generators added).
    """
    generators = registered_generators()
    appearances = {name: Appearance(material) for name, material in config.materials.items()}
    groups: dict[str, MeshGroup] = {}
    sides = {name: texture_side(texture) for name, texture in config.textures.items()}
    for spec in config.objects:
        rng = np.random.default_rng([config.layout_seed, spec.index])
        ctx = GeneratorContext(spec, path=config.path, rng=rng, groups=groups, appearances=appearances,
                               texture_sides=sides)
        generators[spec.generator].function(ctx)
    return groups, appearances


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


def mitsuba_reason(exc: Exception) -> str:
    """The line of a Mitsuba error that says what is wrong: its last (the class name when empty)."""
    text = str(exc).strip()
    return text.splitlines()[-1] if text else exc.__class__.__name__


# Mitsuba integrators that trace radiance from the sensor, as the omni camera's images need: light
# tracers sample the sensor from the scene side, which the omni sensor does not offer, and AOV,
# depth or moment integrators write other quantities than an image.
RADIANCE_INTEGRATORS = ("path", "direct", "volpath", "volpathmis", "prb", "prb_basic", "direct_projective",
                        "prb_projective")


def mitsuba_file_entries(mi, xml_path) -> tuple[dict, object | None]:
    """Shapes, non-surface emitters and integrator of a Mitsuba 3 scene file, its sensors dropped.

    Files the scene names are found relative to its folder, as when Mitsuba
    loads it itself.

    Parameters
    ----------
    mi : module
        Imported Mitsuba with its variant set.
    xml_path : path
        The scene file.

    Returns
    -------
    entries : dict
        ``xml_shape_K`` and ``xml_emitter_K`` -> loaded Mitsuba objects, in file order.
    integrator : Mitsuba integrator or None
        The file's integrator, or None when it names none.

    Raises
    ------
    InputError
        Not XML, an integrator not in :data:`RADIANCE_INTEGRATORS`, or Mitsuba
        cannot load it (the message is Mitsuba's last line).
    """
    xml_path = Path(xml_path)
    try:
        root = ElementTree.parse(xml_path).getroot()
    except (ElementTree.ParseError, OSError) as exc:
        raise InputError(xml_path, f"not a readable Mitsuba scene file ({mitsuba_reason(exc)})") from None
    if root.tag != "scene":
        raise InputError(xml_path, f"expected a <scene> root element, got <{root.tag}>")
    for sensor in root.findall("sensor"):
        root.remove(sensor)
    integrator_element = root.find("integrator")
    has_integrator = integrator_element is not None
    if has_integrator and integrator_element.get("type") not in RADIANCE_INTEGRATORS:
        raise InputError(xml_path, f"<integrator type={integrator_element.get('type')!r}>: expected one that "
                                   f"renders radiance from the camera ({', '.join(RADIANCE_INTEGRATORS)}); "
                                   "depth and normals come with --aov")
    resolver = mi.file_resolver()
    saved = [str(resolver[i]) for i in range(len(resolver))]
    resolver.prepend(str(xml_path.resolve().parent))
    try:
        loaded = mi.load_string(ElementTree.tostring(root, encoding="unicode"), parallel=False)
    except RuntimeError as exc:
        raise InputError(xml_path, f"Mitsuba cannot load it: {mitsuba_reason(exc)}") from None
    finally:
        resolver.clear()
        for folder in saved:
            resolver.append(folder)
    _check_file_values(mi, loaded, xml_path)
    entries = {f"xml_shape_{k}": shape for k, shape in enumerate(loaded.shapes())}
    # Area lights come with their shapes; only the others are added on their own.
    emitters = [e for e in loaded.emitters() if not mi.has_flag(e.flags(), mi.EmitterFlags.Surface)]
    entries.update({f"xml_emitter_{k}": emitter for k, emitter in enumerate(emitters)})
    return entries, (loaded.integrator() if has_integrator else None)


def _check_file_values(mi, loaded, xml_path: Path) -> None:
    """Refuse the values of a Mitsuba file's emitters and materials that render as garbage.

    Every number of an emitter's or a shape's BSDF parameters must be finite (a NaN radiance or
    reflectance rendered black pixels with exit 0), and the light an emitter gives (its
    ``EMITTED_KEYS``) at least 0 and at most :data:`~omnisim.settings.MAX_RADIANCE`, as the scene
    file's lights. Transforms are left out (Mitsuba checks them).

    Raises
    ------
    InputError
        Naming the file, the element (with its id if it has one) and the parameter.
    """
    objects = [("emitter", e) for e in loaded.emitters()] + [("bsdf", shape.bsdf()) for shape in loaded.shapes()]
    for kind, obj in objects:
        params = mi.traverse(obj)
        for key in params.keys():
            try:
                values = np.asarray(params[key], dtype=np.float64)
            except (TypeError, ValueError):  # a transform
                continue
            emitted = kind == "emitter" and key.endswith(EMITTED_KEYS)
            if np.isfinite(values).all() and not (emitted and not 0.0 <= values.min() <= values.max() <= MAX_RADIANCE):
                continue
            expected = f"values from 0 to {MAX_RADIANCE:g} (emitted light)" if emitted else "finite values"
            shown = [float(f"{v:.6g}") for v in values.ravel()[:3]]
            element = f"<{kind} id={obj.id()!r}>" if obj.id() else f"<{kind}>"
            raise InputError(xml_path, f"{element} {key}: expected {expected}, got {shown}")


def build_scene_dict(config: SceneConfig, mi, *, sensor: dict) -> dict:
    """Mitsuba scene dict of a scene file, with the given sensor entry.

    Parameters
    ----------
    config : SceneConfig
    mi : module
        Imported Mitsuba with its variant set.
    sensor : dict
        Sensor entry (e.g. from :func:`omnisim.sensor.sensor_dict`).

    Raises
    ------
    InputError
        A file the scene names cannot be loaded, or Mitsuba rejects a material or light.
    """
    path = Path(config.path)
    groups, appearances = scene_meshes(config)
    texture_images = {name: texture_image(texture, seed=config.layout_seed)
                      for name, texture in config.textures.items()}
    scene = {
        "type": "scene",
        "integrator": {"type": "path", "max_depth": int(config.render.max_depth), "hide_emitters": False},
        "sensor": sensor,
    }
    if config.mitsuba_xml:
        entries, integrator = mitsuba_file_entries(mi, config.mitsuba_xml)
        if integrator is not None:
            scene["integrator"] = integrator
        scene.update(entries)
    for name, group in sorted(groups.items()):
        appearance = appearances[name]
        try:
            bsdf = bsdf_dict(mi, appearance, texture_images)
            scene[f"mesh_{name}"] = _mesh(mi, name, group, bsdf, emission=appearance.emission)
        except RuntimeError as exc:
            raise InputError(path, f"[materials.{name}]: {mitsuba_reason(exc)}") from None
    for index, light in enumerate(config.lights):
        # Instantiated one by one, in file order, so the emitter order never changes.
        try:
            scene[f"light_{index}"] = mi.load_dict(emitter_dict(mi, light), parallel=False)
        except RuntimeError as exc:
            source = getattr(light, "file", path)
            raise InputError(source, f"[[lights]] #{index + 1}: {mitsuba_reason(exc)}") from None
        if isinstance(light, EnvmapLight):
            _check_envmap_pixels(mi, scene[f"light_{index}"], light, index=index)
    return scene


def _check_envmap_pixels(mi, emitter, light: EnvmapLight, *, index: int) -> None:
    """Refuse an environment image whose radiance the renderer cannot sum: a pixel that is NaN,
    infinite or negative, or brighter than :data:`~omnisim.settings.MAX_RADIANCE` times its scale.

    Checked on the image Mitsuba loaded, so the file is read once: its ``data`` holds the file's
    rows, each padded with the opposite edge's pixel on either side (wrapping around the azimuth).
    Raises InputError naming the file and the first bad pixel (row, column of the file).
    """
    data = np.asarray(mi.traverse(emitter)["data"], dtype=np.float64)[:, 1:-1]
    bad = ~(np.isfinite(data) & (data >= 0.0) & (data * light.scale <= MAX_RADIANCE))
    if bad.any():
        row, col, _ = np.unravel_index(int(np.argmax(bad)), bad.shape)
        value = [float(f"{v:.6g}") for v in data[row, col]]
        raise InputError(light.file, f"[[lights]] #{index + 1} (envmap): expected finite pixel values >= 0 "
                                     f"(linear radiance; times scale {light.scale:g} at most {MAX_RADIANCE:g}), "
                                     f"got {value} at row {row}, column {col}")
