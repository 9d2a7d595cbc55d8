"""Type-checked configuration: options_from_dict and the one configuration-file reader."""

from __future__ import annotations

import dataclasses
import json
import typing
from typing import Any, Literal

import pytest

from ifmi.errors import InputError
from ifmi.features import FeatureConfig
from ifmi.io.config import read_estimate_config, read_json_object
from ifmi.options import OptionError, options_from_dict
from ifmi.pipeline import EstimateConfig


@dataclasses.dataclass(frozen=True)
class Inner:
    size: int = 3
    scale: float = 1.0

    def __post_init__(self):
        if self.size < 1:
            raise ValueError(f"size must be >= 1, got {self.size}")


@dataclasses.dataclass(frozen=True)
class Outer:
    flag: bool = False
    count: int = 1
    ratio: float = 0.5
    name: str = "a"
    limit: int | None = None
    band: tuple[float, float] | None = None
    values: tuple[float, ...] = ()
    mode: Literal["x", "y"] = "x"
    anything: Any = None
    inner: Inner = dataclasses.field(default_factory=Inner)


@pytest.mark.parametrize(("data", "expected"), [
    ({}, Outer()),
    ({"ratio": 2}, Outer(ratio=2.0)),
    ({"limit": None, "band": [1, 2.5]}, Outer(band=(1.0, 2.5))),
    ({"values": [1, 2, 3]}, Outer(values=(1.0, 2.0, 3.0))),
    ({"mode": "y", "anything": [1, {"a": 2}]}, Outer(mode="y", anything=[1, {"a": 2}])),
    ({"inner": {"size": 4}}, Outer(inner=Inner(size=4))),
    ({"ratio": float("inf")}, Outer(ratio=float("inf"))),
])
def test_accepted_values(data, expected):
    result = options_from_dict(Outer, data, what="opts")
    assert result == expected
    assert type(result.ratio) is float


@pytest.mark.parametrize(("data", "message"), [
    ({"flag": "yes"}, "opts.flag: expected true or false, got string 'yes'"),
    ({"flag": 1}, "opts.flag: expected true or false, got integer 1"),
    ({"count": 1.5}, "opts.count: expected an integer, got number 1.5"),
    ({"count": 2.0}, "opts.count: expected an integer, got number 2.0"),
    ({"count": True}, "opts.count: expected an integer, got boolean true"),
    ({"count": "3"}, "opts.count: expected an integer, got string '3'"),
    ({"ratio": "abc"}, "opts.ratio: expected a number, got string 'abc'"),
    ({"ratio": False}, "opts.ratio: expected a number, got boolean false"),
    ({"ratio": float("nan")}, "opts.ratio: expected a number, got number nan"),
    ({"name": 5}, "opts.name: expected a string, got integer 5"),
    ({"limit": 1.5}, "opts.limit: expected an integer or null, got number 1.5"),
    ({"band": [1]}, "opts.band: expected a list of 2 values (a number, a number) or null, got list [1]"),
    ({"band": [1, "b"]}, "opts.band[1]: expected a number, got string 'b'"),
    ({"band": {"a": 1}}, "opts.band: expected a list of 2 values (a number, a number) or null, got object"),
    ({"values": [1, None]}, "opts.values[1]: expected a number, got null"),
    ({"mode": "z"}, "opts.mode: expected one of 'x', 'y', got string 'z'"),
    ({"inner": [1, 2]}, "opts.inner: expected an object with keys size, scale, got list [1, 2]"),
    ({"inner": {"size": "big"}}, "opts.inner.size: expected an integer, got string 'big'"),
    ({"inner": {"size": 0}}, "opts.inner: size must be >= 1, got 0"),
    ({"inner": {"sise": 2}}, "opts.inner: unknown key sise; expected size, scale"),
    ({"bogus": 1, "other": 2}, "opts: unknown keys bogus, other; expected flag, count"),
])
def test_rejected_values_name_key_expected_and_got(data, message):
    with pytest.raises(OptionError) as info:
        options_from_dict(Outer, data, what="opts")
    assert str(info.value).startswith(message)
    assert "\n" not in str(info.value)


def test_not_a_mapping_at_the_top():
    with pytest.raises(OptionError, match=r"^expected an object with keys flag, .*, got list \[\]$"):
        options_from_dict(Outer, [], what="")


def _config_fields(cls, prefix=""):
    """(dotted key, type hint) of every leaf field of a config dataclass tree."""
    hints = typing.get_type_hints(cls)
    if cls is EstimateConfig:
        hints["features"] = FeatureConfig
    for f in dataclasses.fields(cls):
        hint = hints[f.name]
        key = f"{prefix}{f.name}"
        if dataclasses.is_dataclass(hint):
            yield from _config_fields(hint, key + ".")
        else:
            yield key, hint


def _nested(key: str, value) -> dict:
    data: dict = value
    for part in reversed(key.split(".")):
        data = {part: data}
    return data


ALL_FIELDS = list(_config_fields(EstimateConfig))


def test_every_config_field_is_covered():
    keys = [k for k, _ in ALL_FIELDS]
    assert "relative_pose.seed" in keys and "ifmi.tiling.overlap" in keys
    assert "features.radius_band" in keys and "keyframe.enabled" in keys
    assert len(keys) > 50


@pytest.mark.parametrize(("key", "hint"), ALL_FIELDS, ids=[k for k, _ in ALL_FIELDS])
def test_every_config_field_rejects_a_wrong_type(key, hint):
    wrong = {"x": [1, 2]} if hint is str else "not a value"
    with pytest.raises(OptionError) as info:
        EstimateConfig.from_dict(_nested(key, wrong))
    assert str(info.value).startswith(f"{key}: expected ")
    assert "got " in str(info.value)


def test_estimate_config_round_trips_through_json():
    config = EstimateConfig.from_dict({"features": {"n_features": 100, "radius_band": [10, 90]},
                                       "ifmi": {"tiling": {"tile_size": 48}}})
    assert EstimateConfig.from_dict(json.loads(json.dumps(config.to_dict()))) == config
    assert EstimateConfig.from_dict(EstimateConfig().to_dict()) == EstimateConfig()


# --- the configuration-file reader --------------------------------------------------

def test_read_estimate_config_takes_both_forms(tmp_path):
    config = EstimateConfig.from_dict({"relative_pose": {"seed": 5}})
    (tmp_path / "plain.json").write_text(json.dumps(config.to_dict()))
    (tmp_path / "run.config.json").write_text(json.dumps({"method": "ifmi", "config": config.to_dict(),
                                                          "dataset": "/x"}))
    assert read_estimate_config(tmp_path / "plain.json") == config
    assert read_estimate_config(tmp_path / "run.config.json") == config


@pytest.mark.parametrize(("content", "message"), [
    (None, "configuration file not found"),
    ("{not json", "invalid JSON at line 1 column 2"),
    ("[]", "expected a JSON object {...} at the top level, got an array"),
    ("3", "expected a JSON object {...} at the top level, got a number"),
    ("null", "expected a JSON object {...} at the top level, got null"),
    ('{"keyframe": {"enabled": "yes"}}',
     "invalid configuration: keyframe.enabled: expected true or false, got string 'yes'"),
])
def test_read_estimate_config_errors_are_one_line(tmp_path, content, message):
    path = tmp_path / "c.json"
    if content is not None:
        path.write_text(content)
    with pytest.raises(InputError) as info:
        read_estimate_config(path)
    assert str(info.value).startswith(f"{path}: {message}")
    assert "\n" not in str(info.value)


def test_read_json_object_of_a_folder(tmp_path):
    with pytest.raises(InputError, match="is a folder; expected a meta file"):
        read_json_object(tmp_path, what="meta file")


# --- values derived from a camera, the run's method, huge numbers ---------------------------

def _run_document(config, **more):
    return {"method": "orb", "config": config.to_dict(), "dataset": "/x", **more}


def test_run_file_values_derived_from_its_camera_are_cleared(tmp_path):
    from ifmi.io.config import read_config_file

    config = EstimateConfig.from_dict({"relative_pose": {"ransac_threshold_rad": 0.01, "seed": 3},
                                       "ifmi": {"panorama": {"radius_min_px": 30.0, "radius_max_px": 90.0}}})
    (tmp_path / "old.config.json").write_text(json.dumps(_run_document(config)))
    (tmp_path / "new.config.json").write_text(json.dumps(_run_document(
        config, derived=["ifmi.panorama.radius_max_px"])))
    (tmp_path / "plain.json").write_text(json.dumps(config.to_dict()))
    old = read_config_file(tmp_path / "old.config.json")
    assert old.method == "orb" and old.config.relative_pose.seed == 3
    assert old.config.relative_pose.ransac_threshold_rad is None
    assert old.config.ifmi.panorama.radius_min_px is None and old.config.ifmi.panorama.radius_max_px is None
    new = read_config_file(tmp_path / "new.config.json").config
    assert new.relative_pose.ransac_threshold_rad == 0.01 and new.ifmi.panorama.radius_min_px == 30.0
    assert new.ifmi.panorama.radius_max_px is None
    plain = read_config_file(tmp_path / "plain.json")
    assert plain.config == config and plain.method is None


@pytest.mark.parametrize(("extra", "message"), [
    ({"method": 3}, "invalid configuration: method: expected a method name (a string), got 3"),
    ({"derived": ["relative_pose.seed"]}, "invalid configuration: derived: expected a list of "
                                          "relative_pose.ransac_threshold_rad, "),
    ({"derived": "all"}, "invalid configuration: derived: expected a list of "),
])
def test_bad_run_file_entries_are_one_line(tmp_path, extra, message):
    path = tmp_path / "run.config.json"
    path.write_text(json.dumps(_run_document(EstimateConfig(), **extra)))
    with pytest.raises(InputError) as info:
        read_estimate_config(path)
    assert str(info.value).startswith(f"{path}: {message}")


def test_an_integer_of_too_many_digits_is_one_line(tmp_path):
    path = tmp_path / "c.json"
    path.write_text('{"ifmi": {"panorama": {"width": ' + "1" * 5000 + "}}}")
    with pytest.raises(InputError) as info:
        read_estimate_config(path)
    assert str(info.value) == f"{path}: invalid JSON: an integer of 5000 digits; expected at most 4300"


@pytest.mark.parametrize(("data", "message"), [
    ({"relative_pose": {"seed": -1}}, "relative_pose: seed must be a non-negative integer, got -1"),
    ({"relative_pose": {"refine_iterations": 10 ** 6}}, "relative_pose: expected 0 <= refine_iterations <= 100"),
    ({"relative_pose": {"robust_iterations": 101}}, "relative_pose: expected 0 <= refine_iterations <= 100 and "
                                                    "robust_iterations <= 100, got 3, 101"),
    ({"relative_pose": {"ransac_threshold_rad": float("inf")}},
     "relative_pose: ransac_threshold_rad must be a finite number, got inf"),
    ({"relative_pose": {"robust_scale": float("inf")}}, "relative_pose: robust_scale must be a finite number"),
    ({"relative_pose": {"ransac_threshold_rad": 1e9}},
     "relative_pose: ransac_threshold_rad must be in (0, pi) or None, got 1000000000.0"),
    ({"ifmi": {"global_motion": {"sectors": 1000}}},
     "ifmi.global_motion.sectors: no longer an option (fixed at 12); remove the key"),
    ({"ifmi": {"coarse": {"confirm_angle_rad": float("inf")}}},
     "ifmi.coarse: confirm_angle_rad must be a finite number"),
    ({"ifmi": {"registration": {"refine_passes": 11}}},
     "ifmi.registration: expected 0 <= refine_passes <= 10 and workers >= 1, got 11, 1"),
    ({"ifmi": {"registration": {"phase_plane_iterations": 51}}},
     "ifmi.registration.phase_plane_iterations: no longer an option (fixed at 3); remove the key"),
    ({"ifmi": {"registration": {"th_pnr": float("inf")}}}, "ifmi.registration: th_pnr must be a finite number"),
    ({"ifmi": {"registration": {"th_pr": float("inf")}}}, "ifmi.registration: th_pr must be a finite number"),
    ({"ifmi": {"point_spread": 0.2, "use_prior": False}},
     "ifmi.point_spread: no longer an option (fixed at 0.1); remove the key"),
    ({"ifmi": {"use_prior": False, "tracking": {"use_prior": True}}},
     "ifmi.use_prior: given twice, here and as ifmi.tracking.use_prior (its new key)"),
    ({"ifmi": {"tiling": {"tile_size": float("inf")}}}, "ifmi.tiling: tile_size must be a fraction in (0, 1)"),
    ({"ifmi": {"tiling": {"tile_size": 6}}}, "ifmi.tiling: tile_size must be a fraction in (0, 1) of the "
                                             "panorama width or at least 8 px, got 6.0"),
])
def test_estimator_bounds(data, message):
    with pytest.raises(OptionError) as info:
        EstimateConfig.from_dict(data)
    assert str(info.value).startswith(message)


def test_a_configuration_of_the_former_flat_layout_is_translated():
    # An estimate's NAME.config.json of the former layout holds every option; those now fixed at
    # their value are dropped, the moved ones go to their group.
    former = EstimateConfig.from_dict({"ifmi": {"use_prior": False, "coarse_to_fine": False, "min_tiles": 5,
                                                "point_spread": 0.1, "flow_at_energy_centroid": False,
                                                "global_motion": {"confirm_angle_rad": 0.2, "sectors": 12},
                                                "registration": {"th_pr": 2.0, "phase_plane_iterations": 3},
                                                "half_turn_check_rad": 1.0, "refit_passes": 0}})
    ifmi = former.ifmi
    assert not ifmi.tracking.use_prior and not ifmi.coarse.enabled and ifmi.rays.min_tiles == 5
    assert not ifmi.rays.at_energy_centroid and ifmi.coarse.confirm_angle_rad == 0.2
    assert ifmi.registration.th_pr == 2.0 and ifmi.recovery.half_turn_check_rad == 1.0
    assert ifmi.refinement.refit_passes == 0
    # The saved layout reads back as it is, and the default configuration's own dict does too.
    assert EstimateConfig.from_dict(former.to_dict()) == former
    assert EstimateConfig.from_dict(EstimateConfig().to_dict()) == EstimateConfig()


def test_the_former_name_of_the_sharp_panorama_width_is_translated():
    # refinement.min_width_curved (nested, as saved) and min_width_curved (flat layout) are now
    # refinement.min_width_sharp; both names at once are refused, naming the old key.
    nested = EstimateConfig.from_dict({"ifmi": {"refinement": {"min_width_curved": 1024, "refit_passes": 2}}})
    assert nested.ifmi.refinement.min_width_sharp == 1024 and nested.ifmi.refinement.refit_passes == 2
    assert EstimateConfig.from_dict({"ifmi": {"min_width_curved": 800}}).ifmi.refinement.min_width_sharp == 800
    with pytest.raises(OptionError, match="min_width_curved: given twice"):
        EstimateConfig.from_dict({"ifmi": {"min_width_curved": 800, "refinement": {"min_width_sharp": 900}}})


def test_the_saved_configuration_has_at_most_40_ifmi_options():
    def leaves(value):
        return sum(leaves(v) for v in value.values()) if isinstance(value, dict) else 1

    assert leaves(EstimateConfig().to_dict()["ifmi"]) <= 40


def test_estimator_bounds_keep_the_limits_themselves():
    config = EstimateConfig.from_dict({"relative_pose": {"seed": 2 ** 70, "refine_iterations": 100},
                                       "ifmi": {"registration": {"refine_passes": 10},
                                                "tiling": {"tile_size": 8}}})
    assert config.ifmi.tiling.tile_size == 8.0 and config.relative_pose.seed == 2 ** 70
