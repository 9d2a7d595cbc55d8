"""A third-party front end that breaks the contract: one line naming it, or the one frame failed.

Each plugin wraps the built-in ORB front end and spoils its result in one way, on a synthetic
160-px sequence whose ORB estimate is good (so any damage shows).
"""

from __future__ import annotations

import csv
import dataclasses

import numpy as np
import pytest

from ifmi.tracking.checked_front_end import RAY_SAMPLE_SIZE, checked_correspondences
from ifmi.cli import main
from ifmi.errors import InputError
from ifmi.front_end import Correspondences
from ifmi.io.tum import read_tum
from ifmi.backend.relative_pose import RelativePoseOptions, relative_pose_from_rays
from ifmi.synthetic import example_band_px, example_omni_model, synthetic_sequence, write_synthetic_dataset

FRAMES = 6

PLUGIN = '''
import sys
from dataclasses import replace

import numpy as np

from ifmi.tracking.methods import create_front_end


class Spoiled:
    """ORB with its result passed through ``spoil(corr, pair)``; ``prepare`` may fail on a frame."""

    def __init__(self, model, config, spoil, prepare_fails_on=None):
        self.inner, self.spoil, self.fails_on, self.frames = create_front_end("orb", model, config), spoil, \\
            prepare_fails_on, 0

    def prepare(self, image):
        frame, self.frames = self.frames, self.frames + 1
        if frame == self.fails_on:
            raise RuntimeError("no keypoints:\\nsensor saturated")
        return frame, self.inner.prepare(image)

    def correspondences(self, a, b):
        return self.spoil(self.inner.correspondences(a[1], b[1]), b[0])


def _make(spoil, **kw):
    return lambda model, config: Spoiled(model, config, spoil, **kw)


pixels_as_rays = _make(lambda c, k: replace(c, rays_a=np.c_[c.pixels_a, np.ones(len(c.pixels_a))],
                                            rays_b=np.c_[c.pixels_b, np.ones(len(c.pixels_b))]))
nan_ray = _make(lambda c, k: replace(c, rays_b=np.r_[np.full((1, 3), np.nan), c.rays_b[1:]]))
short_b = _make(lambda c, k: replace(c, rays_b=c.rays_b[:-5]))
group_of_7 = _make(lambda c, k: replace(c, rays_a=c.rays_a[:7 * (len(c.rays_a) // 7) + 1],
                                        rays_b=c.rays_b[:7 * (len(c.rays_b) // 7) + 1],
                                        pixels_a=c.pixels_a[:7 * (len(c.pixels_a) // 7) + 1],
                                        pixels_b=c.pixels_b[:7 * (len(c.pixels_b) // 7) + 1],
                                        rays_per_measurement=7))
success_text = _make(lambda c, k: replace(c, success="no"))
returns_none = _make(lambda c, k: None)
complex_rays = _make(lambda c, k: replace(c, rays_a=c.rays_a + 0j))
array_diagnostic = _make(lambda c, k: replace(c, diagnostics={"scores": np.arange(100)}))
two_line_diagnostic = _make(lambda c, k: replace(c, diagnostics={"note": "first\\n# second"}))
huge_int_diagnostic = _make(lambda c, k: replace(c, diagnostics={"big": 10 ** 5000}))
spaced_key_diagnostic = _make(lambda c, k: replace(c, diagnostics={" seconds": 1.0}))
tuple_key_diagnostic = _make(lambda c, k: replace(c, diagnostics={("a", "b"): 1}))
seconds_key_diagnostic = _make(lambda c, k: replace(c, diagnostics={"seconds": 5.0}))
success_key_diagnostic = _make(lambda c, k: replace(c, diagnostics={"success": False}))
empty_key_diagnostic = _make(lambda c, k: replace(c, diagnostics={"": 1}))
# Unit rays, but not those of their pixels: before, accepted (ATE 2.43 rad on a SIFT front end).
negated_rays = _make(lambda c, k: replace(c, rays_a=-c.rays_a))
col_row_pixels = _make(lambda c, k: replace(c, pixels_b=c.pixels_b[:, ::-1]))
float16_rays = _make(lambda c, k: replace(c, rays_a=c.rays_a.astype(np.float16), rays_b=c.rays_b.astype(np.float16)))


def _raise_on_3(c, k):
    if k == 3:
        raise MemoryError("matcher ran out of memory\\non this pair")
    return c


raises_on_3 = _make(_raise_on_3)


def _pair_half_shifted_on_3(c, k):
    if k != 3:
        return c
    # Each ray of a paired with the ray of b half the list away: OpenCV lists keypoints found near
    # each other together, so a neighbour's ray would still nearly fit the motion.
    order = np.roll(np.arange(len(c.rays_b)), len(c.rays_b) // 2)
    return replace(c, rays_b=c.rays_b[order], pixels_b=c.pixels_b[order])


half_shifted_on_3 = _make(_pair_half_shifted_on_3)
prepare_fails_on_2 = _make(lambda c, k: c, prepare_fails_on=2)
prepare_fails_on_0 = _make(lambda c, k: c, prepare_fails_on=0)


def _exit(c, k):
    sys.exit(0)


exits = _make(_exit)


def returns_class(model, config):
    return Spoiled


class _Accepting(Spoiled):
    def accept_pose(self, state, rotation):
        raise ValueError("pose store is full")


def accept_raises(model, config):
    return _Accepting(model, config, lambda c, k: c)


class _Refining(Spoiled):
    """Refines a pair by spoiling its first matches with ``refine_spoil(first, pair)``."""

    def refine_correspondences(self, a, b, first, *, rotation_ab):
        return self.refine_spoil(first, b[0])


def _refining(refine_spoil):
    def factory(model, config):
        front_end = _Refining(model, config, lambda c, k: c)
        front_end.refine_spoil = refine_spoil
        return front_end
    return factory


def _refine_raise_on_3(c, k):
    if k == 3:
        raise ValueError("no second look")
    return None


refine_raises_on_3 = _refining(_refine_raise_on_3)
refine_pixels_as_rays = _refining(lambda c, k: replace(c, rays_a=np.c_[c.pixels_a, np.ones(len(c.pixels_a))]))
refine_negated_rays_b = _refining(lambda c, k: replace(c, rays_b=-c.rays_b))
refine_half = _refining(lambda c, k: replace(c, diagnostics={**c.diagnostics, "refined": True}))


def refine_not_callable(model, config):
    front_end = Spoiled(model, config, lambda c, k: c)
    front_end.refine_correspondences = 3
    return front_end
'''


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    model = example_omni_model(160)
    sequence = synthetic_sequence(model, FRAMES, seed=3, max_step_rad=0.04, band_px=example_band_px(model))
    return write_synthetic_dataset(tmp_path_factory.mktemp("checked") / "ds", sequence)


@pytest.fixture
def plugin(tmp_path, monkeypatch):
    (tmp_path / "spoiled_orb.py").write_text(PLUGIN)
    monkeypatch.syspath_prepend(str(tmp_path))
    return "spoiled_orb"


def _estimate(dataset, method, out, capsys):
    code = main(["estimate", str(dataset), "--method", method, "--out", str(out), "--no-progress"])
    return code, capsys.readouterr().err.strip()


@pytest.mark.parametrize("factory, problem", [
    ("pixels_as_rays", "correspondences() returned rays_a that are not unit vectors (norms"),
    ("nan_ray", "correspondences() returned rays_b with 1 of"),
    ("short_b", "correspondences() returned rays_a, rays_b, pixels_a, pixels_b of"),
    ("group_of_7", "expected an integer >= 1 that divides the number of matches"),
    ("success_text", "correspondences() returned success='no'; expected True or False"),
    ("returns_none", "correspondences() returned NoneType without pixels_a"),
    ("exits", "correspondences() called sys.exit(0)"),
    ("returns_class", "factory returned the class Spoiled; expected an instance"),
    ("accept_raises", "accept_pose() raised ValueError: pose store is full"),
    ("refine_not_callable", "refine_correspondences is not callable (got int); expected "
                            "refine_correspondences(state_a, state_b, first, *, rotation_ab) or none"),
    ("refine_pixels_as_rays", "returned rays_a that are not unit vectors (norms"),
    ("negated_rays", "correspondences() returned rays_a that are not the rays of their pixels: 16 of 16 "
                     "sampled matches off the camera model's ray, by up to"),
    ("col_row_pixels", "correspondences() returned rays_b that are not the rays of their pixels:"),
    ("refine_negated_rays_b", "correspondences() returned rays_b that are not the rays of their pixels: 16 of "
                              "16 sampled matches"),
    ("prepare_fails_on_0", "prepare() of the first frame raised RuntimeError: no keypoints: ..."),
    # Before: the imaginary parts were dropped with a NumPy warning and the run went on.
    ("complex_rays", "correspondences() returned rays_a that is no numeric array (TypeError: values of type "
                     "complex128); expected (N, 3) real numbers"),
    # Before: written into frames.csv as text over lines (a line of it starting with # made evaluate
    # read the file short), or a ValueError traceback for the integer.
    ("array_diagnostic", "correspondences() returned diagnostics entry 'scores': a value of type ndarray; "
                         "expected a float, an integer of at most 64 bits, true/false, null or one line of "
                         "text (a column of frames.csv)"),
    ("two_line_diagnostic", "correspondences() returned diagnostics entry 'note': text of 2 lines; expected"),
    ("huge_int_diagnostic", "correspondences() returned diagnostics entry 'big': an integer of 16610 bits; "
                            "expected"),
    ("tuple_key_diagnostic", "correspondences() returned a diagnostics key of type tuple; expected one line "
                             "of text without surrounding spaces (a column name of frames.csv)"),
    # Read back as the seconds column (frames.csv strips column names), then refused as one named twice.
    ("spaced_key_diagnostic", "correspondences() returned a diagnostics key ' seconds'; expected one line "
                              "of text without surrounding spaces"),
    # Before: dropped without a word (the tracker's own column won), or a column without a name.
    ("seconds_key_diagnostic", "correspondences() returned a diagnostics key 'seconds': a column frames.csv "
                               "has already, so its values would be lost; expected a non-empty name other "
                               "than frame, reference_frame, success,"),
    ("success_key_diagnostic", "diagnostics key 'success': a column frames.csv has already"),
    ("empty_key_diagnostic", "diagnostics key '': an empty column name, so its values would be lost"),
])
@pytest.mark.slow
def test_breach_of_the_contract_is_one_line_naming_the_method(dataset, plugin, tmp_path, capsys, factory,
                                                              problem):
    method = f"{plugin}:{factory}"
    code, err = _estimate(dataset, method, tmp_path / "e.txt", capsys)
    assert code == 2 and len(err.splitlines()) == 1, err
    assert err.startswith(f"ifmi estimate: error: method {method}: ") and problem in err
    assert not (tmp_path / "e.txt").exists()


def _frames(path):
    with open(path.with_name(path.stem + ".frames.csv"), newline="") as f:
        return list(csv.DictReader(f))


@pytest.mark.parametrize("factory, failed, reason", [
    ("raises_on_3", ["3"], "correspondences() raised MemoryError: matcher ran out of memory ..."),
    ("prepare_fails_on_2", ["2"], "prepare() raised RuntimeError: no keypoints: ..."),
])
def test_exception_of_the_plugin_fails_that_frame_only(dataset, plugin, tmp_path, capsys, factory, failed,
                                                       reason):
    method = f"{plugin}:{factory}"
    out = tmp_path / "e.txt"
    code, _ = _estimate(dataset, method, out, capsys)
    assert code == 0
    rows = _frames(out)
    assert [r["frame"] for r in rows if r["success"] != "true"] == failed
    assert rows[int(failed[0])]["reason"] == f"method {method}: {reason}"
    assert len(read_tum(out)) == FRAMES


def test_refined_matches_of_the_plugin_are_solved_again_and_its_exception_kept_as_a_diagnostic(
        dataset, plugin, tmp_path, capsys):
    # The refinement returns the first matches (marked): solved again, the same estimate as ORB's.
    code, _ = _estimate(dataset, f"{plugin}:refine_half", tmp_path / "r.txt", capsys)
    assert code == 0 and all(r["refined"] == "true" for r in _frames(tmp_path / "r.txt")[1:])
    code, _ = _estimate(dataset, "orb", tmp_path / "o.txt", capsys)
    assert np.array_equal(read_tum(tmp_path / "r.txt").rotations, read_tum(tmp_path / "o.txt").rotations)
    # An exception in the refinement keeps the pair's first solution, and says why in frames.csv.
    method = f"{plugin}:refine_raises_on_3"
    code, _ = _estimate(dataset, method, tmp_path / "x.txt", capsys)
    rows = _frames(tmp_path / "x.txt")
    assert code == 0 and all(r["success"] == "true" for r in rows)
    assert [r["refine_failure"] for r in rows] == ["", "", "", f"method {method}: refine_correspondences() "
                                                               "raised ValueError: no second look", "", ""]
    assert np.array_equal(read_tum(tmp_path / "x.txt").rotations, read_tum(tmp_path / "o.txt").rotations)


def test_matches_paired_with_unrelated_rays_fail_that_frame_as_chance(dataset, plugin, tmp_path, capsys):
    # Unrelated pairs of rays: a few fit a 5-point model by chance, which was taken far off the
    # true step before the back end checked a consensus against chance.
    out = tmp_path / "e.txt"
    code, _ = _estimate(dataset, f"{plugin}:half_shifted_on_3", out, capsys)
    rows = _frames(out)
    assert code == 0 and [r["frame"] for r in rows if r["success"] != "true"] == ["3"]
    assert rows[3]["reason"].startswith("relative pose: inliers look like chance (")


def test_float16_rays_are_read_as_unit_rays(dataset, plugin, tmp_path, capsys):
    code, _ = _estimate(dataset, f"{plugin}:float16_rays", tmp_path / "h.txt", capsys)
    assert code == 0 and all(r["success"] == "true" for r in _frames(tmp_path / "h.txt"))
    code, _ = _estimate(dataset, "orb", tmp_path / "o.txt", capsys)
    # float16 keeps 11 bits: a ray moves by up to 5e-4 rad, about a tenth of this camera's pixel.
    from ifmi.geometry.rotations import geodesic_angle

    half, full = read_tum(tmp_path / "h.txt").rotations, read_tum(tmp_path / "o.txt").rotations
    assert geodesic_angle(half, full).max() < 2e-3


def test_failed_result_keeps_one_line_of_reason():
    failed = Correspondences.failed("too\nfew\n  matches")
    assert checked_correspondences(failed, method="m").reason == "method m: too few matches"
    silent = Correspondences.failed("")
    assert checked_correspondences(silent, method="m").reason == "method m: no reason given"
    with pytest.raises(InputError, match="diagnostics of type list; expected a dict"):
        checked_correspondences(Correspondences(np.zeros((0, 2)), np.zeros((0, 2)), np.zeros((0, 3)),
                                                np.zeros((0, 3)), [], False, "x"), method="m")


def test_repeated_matches_are_too_few_distinct_correspondences():
    rng = np.random.default_rng(0)
    rays = rng.normal(size=(2, 3))
    rays /= np.linalg.norm(rays, axis=1, keepdims=True)
    rays_a = np.repeat(rays, 50, axis=0)
    pose, info = relative_pose_from_rays(rays_a, rays_a.copy(),
                                         options=RelativePoseOptions(ransac_threshold_rad=0.01))
    assert not info.success and info.reason == "too few distinct correspondences (2 of 100 differ; < 8)"
    np.testing.assert_array_equal(pose.rotation, np.eye(3))


@pytest.mark.slow
@pytest.mark.parametrize("method", ["ifmi", "orb", "akaze"])
def test_rays_of_the_built_in_methods_pass_the_pixel_check_on_every_camera_model(method):
    """The check holds on every model: iFMI's rays (lifted from its panorama, not from the pixels it
    reports) differ from the model's rays of those pixels by at most 2.4e-6 pixels' angle (OCamCalib's
    inverse polynomial), the keypoint methods' by 1e-13; the tolerance is RAY_PIXEL_TOLERANCE_PX."""
    from camera_examples import EXAMPLES

    from ifmi.geometry.camera import valid_mask
    from ifmi.tracking.methods import load_factory
    from ifmi.pipeline import EstimateConfig
    from ifmi.synthetic import environment_texture, omni_from_environment, rotation_sequence

    environment = environment_texture(height=512, seed=1)
    for name, example in sorted(EXAMPLES.items()):
        model = example.scaled(1.6) if name == "equirectangular" else example.scaled(0.5)
        valid = valid_mask(model)
        images = []
        for rotation in rotation_sequence(2, max_step_rad=0.03, seed=2):
            image = omni_from_environment(environment, model, rotation)
            image[~valid] = 0
            images.append(image)
        front_end = load_factory(method)(model, EstimateConfig())
        first, second = (front_end.prepare(image) for image in images)
        result = front_end.correspondences(first, second)
        assert result.success and len(result.rays_a) >= RAY_SAMPLE_SIZE, name
        # The subject is the rays: iFMI's own diagnostics carry the timing columns a plugin may not set.
        result = dataclasses.replace(result, diagnostics={})
        checked = checked_correspondences(result, method=method, model=model)
        np.testing.assert_array_equal(checked.rays_a, result.rays_a / np.linalg.norm(result.rays_a, axis=1)[:, None])


def test_a_ray_just_beyond_the_pixel_tolerance_is_refused_and_one_within_accepted():
    """The check measures in pixels' angle: rays lifted 0.7 px away pass, 1.5 px away fail."""
    model = example_omni_model(160)
    rng = np.random.default_rng(4)
    inner, outer = example_band_px(model)
    angle = rng.uniform(0, 2 * np.pi, 40)
    radius = rng.uniform(inner + 3, outer - 3, 40)
    pixels = np.asarray(model.center) + np.c_[radius * np.sin(angle), radius * np.cos(angle)]
    rays = model.rays_from_pixels(pixels)
    for shift, accepted in ((0.7, True), (1.5, False)):
        moved = model.rays_from_pixels(pixels + [0.0, shift])
        result = Correspondences(pixels, pixels, rays, moved)
        if accepted:
            checked_correspondences(result, method="m", model=model)
        else:
            with pytest.raises(InputError, match=r"^method m: correspondences\(\) returned rays_b that are not the "
                                                 r"rays of their pixels: \d+ of 16 sampled matches"):
                checked_correspondences(result, method="m", model=model)
