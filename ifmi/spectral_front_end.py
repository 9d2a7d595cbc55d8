"""The extended-iFMI front end: panorama, tiles, per-tile iFMI, flow, rays.

``prepare`` unwarps a frame into the panorama, cuts the tiles and computes
their spectra once (a keyframe is prepared once and matched many times);
``correspondences`` registers the tile pairs, rejects bad tiles with the
noise filters and returns ray pairs from the flow equation.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any, Mapping

import numpy as np

from .camera import OcamModel
from .options import options_from_dict
from .flow import flow_from_tile_motion, flow_sample_points
from .fourier_mellin import REJECT_REASONS, FourierMellin, FourierMellinConfig, TileSpectra
from .tiling import TileLayout, TilingConfig, tile_layout, tiles_from_panorama
from .unwarp import (PanoramaConfig, PanoramaMapping, panorama_from_omni, panorama_from_rays,
                     panorama_mapping, rays_from_panorama)

__all__ = ["IfmiConfig", "IfmiFrameState", "IfmiFrontEnd"]


@dataclass(frozen=True)
class IfmiConfig:
    """Options of the iFMI front end.

    Attributes
    ----------
    panorama : PanoramaConfig
    tiling : TilingConfig
    registration : FourierMellinConfig
        Includes the noise-filter thresholds ``th_pr`` and ``th_pnr``.
    points_per_tile : int
        Flow points per kept tile: 1, 5 or 9.
    point_spread : float
        Offset of the outer flow points from the tile centre, fraction of the tile size.
    min_tiles : int
        Fewer kept tiles than this fails the frame pair.
    use_prior : bool
        When the odometry passes a predicted rotation, cut each tile of
        frame b where the prediction moves tile a's content, so that the
        registration measures only the small residual motion (more overlap,
        less window bias, keyframes that last longer).
    """

    panorama: PanoramaConfig = field(default_factory=PanoramaConfig)
    tiling: TilingConfig = field(default_factory=TilingConfig)
    registration: FourierMellinConfig = field(default_factory=FourierMellinConfig)
    points_per_tile: int = 5
    point_spread: float = 0.1
    min_tiles: int = 3
    use_prior: bool = True

    def __post_init__(self) -> None:
        if self.points_per_tile not in (1, 5, 9):
            raise ValueError(f"points_per_tile must be 1, 5 or 9, got {self.points_per_tile}")
        if not 0 <= self.point_spread < 0.5 or self.min_tiles < 1:
            raise ValueError(f"expected 0 <= point_spread < 0.5 and min_tiles >= 1, got "
                             f"{self.point_spread}, {self.min_tiles}")

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> "IfmiConfig":
        """Inverse of ``dataclasses.asdict``; missing keys take defaults."""
        data = dict(data)
        nested = {"panorama": PanoramaConfig, "tiling": TilingConfig, "registration": FourierMellinConfig}
        for key, kind in nested.items():
            if key in data and isinstance(data[key], Mapping):
                data[key] = options_from_dict(kind, data[key], what=f"ifmi.{key} options")
        return options_from_dict(cls, data, what="ifmi options")

    def to_dict(self) -> dict:
        """Nested dict of plain values (inverse of :meth:`from_dict`)."""
        return asdict(self)


class IfmiFrameState:
    """Prepared frame: wrap-padded panorama (float32) and, computed once on first use, its tile spectra.

    The spectra are needed when the frame is a reference (or matched without
    a prediction); in keyframe mode most frames are neither, and skip them.
    """

    def __init__(self, padded_panorama: np.ndarray, tiles: np.ndarray, engine: FourierMellin):
        self.padded_panorama = padded_panorama
        self._tiles = tiles
        self._engine = engine
        self._spectra: TileSpectra | None = None

    @property
    def spectra(self) -> TileSpectra:
        """Tile spectra (:class:`~ifmi.fourier_mellin.TileSpectra`), computed on first access."""
        if self._spectra is None:
            self._spectra = self._engine.spectra(self._tiles)
            self._tiles = None
        return self._spectra


class IfmiFrontEnd:
    """Extended-iFMI correspondences between omni images of one calibrated camera.

    The panorama's radius band is detected from the first prepared image
    (unless the configuration fixes it) and then kept for the sequence.
    ``correspondences`` accepts a predicted rotation ``R_ab``
    (``uses_prior_rotation`` tells the odometry so).

    Parameters
    ----------
    model : OcamModel
    config : IfmiConfig
    """

    def __init__(self, model: OcamModel, config: IfmiConfig = IfmiConfig()):
        self.model = model
        self.config = config
        self.mapping: PanoramaMapping | None = None
        self.layout: TileLayout | None = None
        self.engine: FourierMellin | None = None
        self._points_b: np.ndarray | None = None

    @property
    def uses_prior_rotation(self) -> bool:
        """True when ``correspondences`` makes use of a predicted rotation (``config.use_prior``)."""
        return self.config.use_prior

    def _setup(self, image: np.ndarray) -> None:
        self.mapping = panorama_mapping(self.model, image, config=self.config.panorama)
        self.layout = tile_layout((self.mapping.height, self.mapping.width), config=self.config.tiling)
        self.engine = FourierMellin(self.layout.tile_size, self.layout.count,
                                    config=self.config.registration)
        self._points_b = flow_sample_points(self.layout.tile_size,
                                            points_per_tile=self.config.points_per_tile,
                                            spread=self.config.point_spread)

    def prepare(self, image: np.ndarray) -> IfmiFrameState:
        """Panorama and tiles of one frame (tile spectra follow on first use).

        Parameters
        ----------
        image : (H, W) or (H, W, 3) uint8 ndarray
            Omni image of the calibration's size.
        """
        if self.mapping is None:
            self._setup(image)
        panorama = panorama_from_omni(image, self.mapping)
        pad = self._pad
        padded = np.concatenate([panorama[:, -pad:], panorama, panorama[:, :pad]], axis=1)
        tiles = np.ascontiguousarray(tiles_from_panorama(panorama, self.layout))
        return IfmiFrameState(padded, tiles, self.engine)

    @property
    def _pad(self) -> int:
        # Columns wrapped onto each side of the panorama: a tile rotated about its centre
        # reaches 0.71 N beyond it, and predicted origins may sit anywhere in [0, width).
        return 2 * self.layout.tile_size

    def predicted_origins(self, prior_rotation: np.ndarray) -> np.ndarray:
        """Panorama ``(row, col)`` in frame b of each tile's first pixel under ``R_ab``.

        Tile a's centre ray ``r_a`` is seen in frame b along ``R_ab^T r_a``.
        """
        return self.predicted_tiles(prior_rotation)[0]

    def predicted_tiles(self, prior_rotation: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Predicted tile-b origins and the local similarity ``(s, theta)`` of each tile under ``R_ab``.

        The panorama map ``p_b -> p_a`` of the rotation is differentiated at
        each predicted tile centre (one-pixel differences); its Jacobian's
        similarity part gives the tile motion's scale and angle.

        Returns
        -------
        origins_b : (T, 2) ndarray
        scale, angle : (T,) ndarray
        """
        rotation = np.asarray(prior_rotation, dtype=np.float64)
        c = (self.layout.tile_size - 1) / 2.0
        rays_a = rays_from_panorama(self.mapping, self.layout.origins + c)
        centres_b = panorama_from_rays(self.mapping, rays_a @ rotation)
        probes = centres_b[:, None, :] + np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])
        in_a = panorama_from_rays(self.mapping, rays_from_panorama(self.mapping, probes) @ rotation.T)
        width = self.mapping.width
        d_row = in_a[:, 1] - in_a[:, 0]
        d_col = in_a[:, 2] - in_a[:, 0]
        d_row[:, 1] = np.mod(d_row[:, 1] + width / 2, width) - width / 2
        d_col[:, 1] = np.mod(d_col[:, 1] + width / 2, width) - width / 2
        # Jacobian columns: d p_a / d row_b and d p_a / d col_b.
        alpha = (d_row[:, 0] + d_col[:, 1]) / 2.0
        beta = (d_row[:, 1] - d_col[:, 0]) / 2.0
        return centres_b - c, np.hypot(alpha, beta), np.arctan2(beta, alpha)

    def register(self, state_a: IfmiFrameState, state_b: IfmiFrameState, *,
                 prior_rotation: np.ndarray | None = None):
        """Tile motions of frame b against frame a (:class:`~ifmi.fourier_mellin.TileMotion`).

        With ``prior_rotation`` (a predicted ``R_ab``) frame b's tiles are cut
        where the prediction moves tile a's content, with its local rotation
        and scale undone; the motion is then relative to those origins.

        Returns
        -------
        motion : TileMotion
        origins_b : (T, 2) ndarray
            Panorama ``(row, col)`` of tile b's first pixel.
        """
        shift = np.array([0.0, self._pad])
        if prior_rotation is None:
            motion = self.engine.register(state_a.spectra, state_b.spectra, state_b.padded_panorama,
                                          self.layout.origins + shift)
            return motion, self.layout.origins.astype(np.float64)
        origins_b, scale, angle = self.predicted_tiles(prior_rotation)
        motion = self.engine.register(state_a.spectra, None, state_b.padded_panorama, origins_b + shift,
                                      prior_scale=scale, prior_angle=angle)
        return motion, origins_b

    def correspondences(self, state_a: IfmiFrameState, state_b: IfmiFrameState, *,
                        prior_rotation: np.ndarray | None = None):
        """Ray pairs of frame a (reference) and frame b from the kept tiles.

        Parameters
        ----------
        state_a, state_b : IfmiFrameState
        prior_rotation : (3, 3) ndarray, optional, keyword-only
            Predicted ``R_ab``; used when ``config.use_prior``.

        Returns
        -------
        Correspondences
        """
        from .pipeline import Correspondences

        if not self.config.use_prior:
            prior_rotation = None
        motion, origins_b = self.register(state_a, state_b, prior_rotation=prior_rotation)
        counts = np.bincount(motion.reason, minlength=len(REJECT_REASONS))
        valid = motion.valid
        diagnostics = {
            "n_tiles": int(self.layout.count),
            "n_tiles_kept": int(valid.sum()),
            **{f"n_tiles_{name.replace(' ', '_').replace('-', '_')}": int(counts[i])
               for i, name in enumerate(REJECT_REASONS) if i > 0},
            "median_peak_ratio": float(np.median(motion.peak_ratio)),
            "median_peak_to_noise": float(np.median(motion.peak_to_noise)),
        }
        if valid.sum() < self.config.min_tiles:
            return Correspondences.failed(
                f"only {int(valid.sum())} of {self.layout.count} tiles passed the noise filters "
                f"(need {self.config.min_tiles})", diagnostics)
        pairs = flow_from_tile_motion(motion, self.layout, self.mapping, points_b=self._points_b,
                                      origins_b=origins_b)
        return Correspondences(pixels_a=pairs.pixels_a, pixels_b=pairs.pixels_b,
                               rays_a=pairs.rays_a, rays_b=pairs.rays_b, diagnostics=diagnostics)
