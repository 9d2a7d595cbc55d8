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
