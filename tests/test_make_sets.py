"""benchmarks/make_sets.py: the set catalogue expands as written, and derived scenes load as their base."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import pytest

from ifmi.errors import InputError

BENCHMARKS = Path(__file__).resolve().parents[1] / "benchmarks"
ROOT = BENCHMARKS.parent


@pytest.fixture(scope="module")
def make_sets():
    if str(BENCHMARKS) not in sys.path:
        sys.path.append(str(BENCHMARKS))
    spec = importlib.util.spec_from_file_location("make_sets", BENCHMARKS / "make_sets.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules["make_sets"] = module  # dataclasses look their module up
    spec.loader.exec_module(module)
    return module


def test_catalogue_names_every_set_once_and_its_sources_first(make_sets):
    recipes = make_sets.recipes_from_catalogue(make_sets.tomllib.loads(make_sets.CATALOGUE.read_text()))
    names = [r.name for r in recipes]
    assert len(names) == len(set(names))
    position = {name: i for i, name in enumerate(names)}
    for recipe in recipes:
        if recipe.source is not None:
            assert position[recipe.source] < position[recipe.name], recipe.name
        else:
            assert (ROOT / recipe.options["scene"]).is_file(), recipe.options["scene"]


def test_every_catalogue_scene_loads_with_its_files(make_sets):
    # Loading checks every file a scene names (meshes, textures) relative to the scene file.
    pytest.importorskip("trimesh")
    from omnisim.config import load_scene_config
    recipes = make_sets.recipes_from_catalogue(make_sets.tomllib.loads(make_sets.CATALOGUE.read_text()))
    scenes = sorted({r.options["scene"] for r in recipes if r.source is None})
    for scene in scenes:
        load_scene_config(ROOT / scene)


def test_subsample_entry_expands_over_sources_steps_and_starts(make_sets):
    catalogue = {"render": [{"name": "raw/a", "scene": "scenes/office.toml"},
                            {"name": "raw/b", "scene": "scenes/lawn.toml"}],
                 "subsample": [{"sources": ["raw/*"], "name": "f/{source}_x{step}_s{start}",
                                "steps": [3, 5], "starts": [0, 1]}]}
    recipes = make_sets.recipes_from_catalogue(catalogue)
    subsets = [(r.name, r.source, r.options) for r in recipes if r.kind == "subsample"]
    assert len(subsets) == 8
    assert ("f/b_x5_s1", "raw/b", {"step": 5, "start": 1}) in subsets


def test_a_source_pattern_matching_nothing_is_a_one_line_error(make_sets):
    with pytest.raises(InputError, match="no set matches"):
        make_sets.recipes_from_catalogue({"degrade": [{"sources": ["raw/*"], "name": "d/{source}"}]})


def test_only_takes_the_sources_a_set_needs(make_sets):
    recipes = make_sets.recipes_from_catalogue(make_sets.tomllib.loads(make_sets.CATALOGUE.read_text()))
    chosen = [r.name for r in make_sets.needed(recipes, ["warehouse_degraded/warehouse_rot_x5_deg"])]
    assert chosen == ["raw/warehouse_rot", "warehouse/warehouse_rot_x5", "warehouse_degraded/warehouse_rot_x5_deg"]


def test_overridden_scene_loads_with_the_new_value_and_the_base_files(make_sets, tmp_path):
    pytest.importorskip("trimesh")
    from omnisim.config import load_scene_config
    base = ROOT / "scenes" / "atelier.toml"
    derived = make_sets.scene_with_overrides(base, {"trajectory.translation_step_m": 0.05, "render.spp": 4},
                                             tmp_path / "elsewhere" / "atelier_trans.toml")
    config, original = load_scene_config(derived), load_scene_config(base)
    assert config.trajectory.translation_step_m == 0.05 and config.render.spp == 4
    assert original.trajectory.translation_step_m == 0.0
    assert config.trajectory.frames == original.trajectory.frames


def test_an_override_of_a_missing_table_is_refused(make_sets, tmp_path):
    with pytest.raises(InputError, match="no table"):
        make_sets.scene_with_overrides(ROOT / "scenes" / "office.toml", {"nosuch.key": 1}, tmp_path / "s.toml")
