"""The whole configuration of an estimate (:class:`EstimateConfig`), saved as JSON beside each result.

One frozen dataclass groups the options of every part: the iFMI front end
(``ifmi``), the feature front ends (``features``), the relative-pose back end,
keyframes, rolling-shutter compensation and bundle adjustment. A method's
factory receives the whole configuration and reads the part that concerns it.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any, Mapping

from ifmi.backend.bundle_adjustment import BundleAdjustmentOptions
from ifmi.backend.plane_twin import PlaneTwinOptions
from ifmi.backend.relative_pose import RelativePoseOptions
from ifmi.backend.rolling_shutter import RollingShutterOptions
from ifmi.features import FeatureConfig
from ifmi.options import options_from_dict
from ifmi.spectral.ifmi_front_end import IfmiConfig, translated_ifmi_options
from ifmi.tracking.odometry import KeyframeOptions

__all__ = ["EstimateConfig"]


@dataclass(frozen=True)
class EstimateConfig:
    """Everything that determines an estimate, saved as JSON beside each result.

    Attributes
    ----------
    ifmi : IfmiConfig
        Options of the ``"ifmi"`` front end.
    features : FeatureConfig or None
        Options of the ``"orb"``/``"akaze"`` front ends (:mod:`ifmi.features`);
        ``None`` means :class:`FeatureConfig`'s defaults.
    relative_pose : RelativePoseOptions
    keyframe : KeyframeOptions
    rolling_shutter : RollingShutterOptions
        The camera's row read-out time; a global shutter by default.
    bundle_adjustment : BundleAdjustmentOptions
        Refinement of the trajectory over the points frames share
        (:mod:`ifmi.backend.bundle_adjustment`); off by default.
    plane_twin : PlaneTwinOptions
        Settling a plane's two-fold ambiguity over the sequence
        (:mod:`ifmi.backend.plane_twin`); on by default.
    """

    ifmi: IfmiConfig = field(default_factory=IfmiConfig)
    features: FeatureConfig | None = None
    relative_pose: RelativePoseOptions = field(default_factory=RelativePoseOptions)
    keyframe: KeyframeOptions = field(default_factory=KeyframeOptions)
    rolling_shutter: RollingShutterOptions = field(default_factory=RollingShutterOptions)
    bundle_adjustment: BundleAdjustmentOptions = field(default_factory=BundleAdjustmentOptions)
    plane_twin: PlaneTwinOptions = field(default_factory=PlaneTwinOptions)

    def to_dict(self) -> dict:
        """JSON-serialisable nested dict (inverse of :meth:`from_dict`)."""
        return {
            "ifmi": asdict(self.ifmi),
            "features": None if self.features is None else asdict(self.features),
            "relative_pose": asdict(self.relative_pose),
            "keyframe": asdict(self.keyframe),
            "rolling_shutter": asdict(self.rolling_shutter),
            "bundle_adjustment": asdict(self.bundle_adjustment),
            "plane_twin": asdict(self.plane_twin),
        }

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> "EstimateConfig":
        """Build a config from :meth:`to_dict` output; missing keys take defaults.

        Every value of every section is type-checked against its field
        (:func:`ifmi.options.options_from_dict`).

        Raises
        ------
        ifmi.options.OptionError
            An unknown key, a value of the wrong type or out of range; the
            message names the key path (``ifmi.tiling.overlap``), what was
            expected and what was got. An ``ifmi`` section of the former
            flat layout is translated, and one of its former options now
            fixed is refused when it holds another value
            (:func:`ifmi.spectral.ifmi_front_end.translated_ifmi_options`).
        """
        if isinstance(data, Mapping) and "ifmi" in data:
            data = {**data, "ifmi": translated_ifmi_options(data["ifmi"])}
        return options_from_dict(cls, data, what="")
