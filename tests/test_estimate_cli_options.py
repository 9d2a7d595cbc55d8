"""``ifmi estimate`` options and ``--config`` files: what wins, what is refused, which file is named."""

from __future__ import annotations

import json
import os
import shutil
import threading

import numpy as np
import pytest

from ifmi.geometry.camera import paracatadioptric_model
from ifmi.cli import main
from ifmi.io.dataset import read_dataset
from ifmi.spectral.panorama import angular_pixel_size_in_band

pytest.importorskip("skimage")
from ifmi.synthetic import (example_band_px, example_omni_model, synthetic_sequence,  # noqa: E402
                            write_synthetic_dataset)

MODEL = paracatadioptric_model((256, 256), horizon_radius_px=80.0, center=(127.2, 129.7),
                               affine=(1.001, 0.002, -0.001))
# Another camera: a smaller image, a narrower band, another pixel angle.
OTHER_MODEL = example_omni_model(192)
QUIET = ["--no-progress"]


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    seq = synthetic_sequence(MODEL, 4, seed=7, band_px=(30.0, 125.0), noise_std=1.0)
    return write_synthetic_dataset(tmp_path_factory.mktemp("data") / "synthetic", seq)


@pytest.fixture(scope="module")
def other_camera_dataset(tmp_path_factory):
    seq = synthetic_sequence(OTHER_MODEL, 4, seed=3, band_px=example_band_px(OTHER_MODEL))
    return write_synthetic_dataset(tmp_path_factory.mktemp("other") / "other", seq)


@pytest.fixture(scope="module")
def run_file(dataset, tmp_path_factory):
    """NAME.config.json of a default iFMI run on ``dataset``."""
    out = tmp_path_factory.mktemp("run") / "first.txt"
    assert main(["estimate", str(dataset), "--out", str(out), *QUIET]) == 0
    return out.with_name("first.config.json")


def _saved(out):
    return json.loads(out.with_name(out.stem + ".config.json").read_text())


def _one_line_error(capsys) -> str:
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err, err
    return err.strip()


def _write_config(path, edit, base=None):
    """A to_dict() configuration file: ``base`` (default: the defaults) changed by ``edit(dict)``."""
    from ifmi.pipeline import EstimateConfig

    data = EstimateConfig().to_dict() if base is None else base
    edit(data)
    path.write_text(json.dumps(data))
    return path


# --- 1. --calib with a dataset folder ------------------------------------------------

@pytest.mark.parametrize("calib", ["missing.txt", "nan_calib.txt"])
def test_calib_other_than_the_folders_own_is_refused(dataset, tmp_path, capsys, calib):
    path = tmp_path / calib
    if calib == "nan_calib.txt":
        text = (dataset / "calib_results.txt").read_text()
        path.write_text(text.replace("1.001", "nan", 1))
    out = tmp_path / "e.txt"
    assert main(["estimate", str(dataset), "--calib", str(path), "--out", str(out), *QUIET]) == 2
    err = _one_line_error(capsys)
    assert f"{path}: is not the calibration of the dataset folder, {dataset / 'calib_results.txt'}" in err
    assert "--calib is for a video" in err and not out.exists()


def test_calib_naming_the_folders_own_file_is_accepted(dataset, tmp_path):
    out = tmp_path / "e.txt"
    assert main(["estimate", str(dataset), "--calib", str(dataset / "calib_results.txt"), "--out", str(out),
                 *QUIET]) == 0


# --- 2. command line over file; camera-derived values derived again --------------------

def test_pixel_threshold_option_wins_over_the_files_radian_threshold(dataset, run_file, tmp_path):
    out = tmp_path / "px.txt"
    assert main(["estimate", str(dataset), "--config", str(run_file), "--ransac-threshold-px", "5",
                 "--out", str(out), *QUIET]) == 0
    pose = _saved(out)["config"]["relative_pose"]
    pixel = angular_pixel_size_in_band(read_dataset(dataset).model)
    assert pose["ransac_threshold_px"] == 5.0
    assert pose["ransac_threshold_rad"] == pytest.approx(5.0 * pixel)


def test_run_file_records_the_values_it_derived(run_file):
    doc = json.loads(run_file.read_text())
    assert doc["derived"] == ["relative_pose.ransac_threshold_rad", "ifmi.panorama.radius_min_px",
                              "ifmi.panorama.radius_max_px"]
    assert doc["config"]["relative_pose"]["ransac_threshold_rad"] is not None


def test_run_file_on_another_camera_derives_its_values_again(other_camera_dataset, run_file, tmp_path):
    plain, reused = tmp_path / "plain.txt", tmp_path / "reused.txt"
    assert main(["estimate", str(other_camera_dataset), "--out", str(plain), *QUIET]) == 0
    assert main(["estimate", str(other_camera_dataset), "--config", str(run_file), "--out", str(reused),
                 *QUIET]) == 0
    assert _saved(reused)["config"] == _saved(plain)["config"]
    assert reused.read_text() == plain.read_text()


def test_explicit_radii_of_a_to_dict_file_are_kept(dataset, tmp_path):
    config = _write_config(tmp_path / "c.json", lambda d: d["ifmi"]["panorama"].update(
        radius_min_px=40.0, radius_max_px=110.0))
    out = tmp_path / "e.txt"
    assert main(["estimate", str(dataset), "--config", str(config), "--out", str(out), *QUIET]) == 0
    saved = _saved(out)
    assert saved["config"]["ifmi"]["panorama"]["radius_min_px"] == 40.0
    assert saved["config"]["ifmi"]["panorama"]["radius_max_px"] == 110.0
    assert saved["derived"] == ["relative_pose.ransac_threshold_rad"]


# --- 3. the run file's method --------------------------------------------------------

def test_run_file_repeats_its_method_unless_method_is_given(dataset, tmp_path):
    first = tmp_path / "orb.txt"
    assert main(["estimate", str(dataset), "--method", "orb", "--out", str(first), *QUIET]) == 0
    again, other = tmp_path / "again.txt", tmp_path / "other.txt"
    run_config = str(tmp_path / "orb.config.json")
    assert main(["estimate", str(dataset), "--config", run_config, "--out", str(again), *QUIET]) == 0
    assert _saved(again)["method"] == "orb" and again.read_text() == first.read_text()
    assert main(["estimate", str(dataset), "--config", run_config, "--method", "akaze", "--out", str(other),
                 *QUIET]) == 0
    assert _saved(other)["method"] == "akaze"


# --- 4. NaN and infinity on the command line -------------------------------------------

FLOAT_OPTIONS = ["--radius-min", "--radius-max", "--tile-size", "--overlap", "--th-pr", "--th-pnr",
                 "--ransac-threshold", "--ransac-threshold-px", "--keyframe-max-angle"]


@pytest.mark.parametrize("value", ["nan", "inf", "-inf", "1e999"])
@pytest.mark.parametrize("option", FLOAT_OPTIONS)
def test_non_finite_numbers_are_refused(dataset, tmp_path, capsys, option, value):
    out = tmp_path / "e.txt"
    assert main(["estimate", str(dataset), f"{option}={value}", "--out", str(out), *QUIET]) == 2
    assert _one_line_error(capsys).startswith(f"ifmi estimate: error: {option}: expected a finite number, got ")
    assert not out.exists()


# --- 5. values the estimator cannot take: one line naming the option or the file ---------

@pytest.mark.parametrize("size", ["6", "4", "2", "1", "7.9"])
def test_tile_size_below_eight_pixels_is_refused(dataset, tmp_path, capsys, size):
    assert main(["estimate", str(dataset), "--tile-size", size, "--out", str(tmp_path / "e.txt"), *QUIET]) == 2
    err = _one_line_error(capsys)
    assert err.startswith("ifmi estimate: error: --tile-size: tile_size must be a fraction in (0, 1) of the "
                          "panorama width or at least 8 px")


def test_tile_fraction_giving_under_eight_pixels_is_refused(dataset, tmp_path, capsys):
    assert main(["estimate", str(dataset), "--tile-size", "0.01", "--width", "512",
                 "--out", str(tmp_path / "e.txt"), *QUIET]) == 2
    assert _one_line_error(capsys) == (
        "ifmi estimate: error: --tile-size: ifmi.tiling.tile_size: expected a tile of at least 8 px, got 0.01 "
        "of the 512 px panorama width (5.12 px)")


def test_negative_seed_option_is_refused(dataset, tmp_path, capsys):
    assert main(["estimate", str(dataset), "--seed", "-1", "--out", str(tmp_path / "e.txt"), *QUIET]) == 2
    assert _one_line_error(capsys) == "ifmi estimate: error: --seed: seed must be a non-negative integer, got -1"


@pytest.mark.parametrize(("edit", "message"), [
    (lambda d: d["relative_pose"].update(seed=-1),
     "invalid configuration: relative_pose: seed must be a non-negative integer, got -1"),
    (lambda d: d["ifmi"]["registration"].update(refine_passes=10 ** 6),
     "invalid configuration: ifmi.registration: expected 0 <= refine_passes <= 10"),
    (lambda d: d["ifmi"]["registration"].update(th_pnr=float("inf")),
     "invalid configuration: ifmi.registration: th_pnr must be a finite number, got inf"),
    (lambda d: d["ifmi"]["tiling"].update(tile_size=4),
     "invalid configuration: ifmi.tiling: tile_size must be a fraction in (0, 1)"),
], ids=["seed", "refine_passes", "th_pnr", "tile_size"])
def test_bad_values_in_a_config_file_name_the_file(dataset, tmp_path, capsys, edit, message):
    config = _write_config(tmp_path / "c.json", edit)
    out = tmp_path / "e.txt"
    assert main(["estimate", str(dataset), "--config", str(config), "--out", str(out), *QUIET]) == 2
    assert _one_line_error(capsys).startswith(f"ifmi estimate: error: {config}: {message}")
    assert not out.exists()


def test_config_file_with_a_huge_integer_is_one_line(dataset, tmp_path, capsys):
    config = tmp_path / "c.json"
    config.write_text('{"relative_pose": {"seed": ' + "9" * 5000 + "}}")
    assert main(["estimate", str(dataset), "--config", str(config), "--out", str(tmp_path / "e.txt")]) == 2
    assert _one_line_error(capsys) == (f"ifmi estimate: error: {config}: invalid JSON: an integer of 5000 "
                                       f"digits; expected at most 4300")


# --- 6b. --config files that are no JSON text: one line each, never a wait -------------------

def _feed_fifo_once_read(fifo, text: str, stop: threading.Event) -> None:
    """Write ``text`` into ``fifo`` once a reader has opened it, until ``stop``: a reader that
    waits for a writer then gets an answer, and a test without the check fails instead of hanging."""
    while not stop.is_set():
        try:
            fd = os.open(fifo, os.O_WRONLY | os.O_NONBLOCK)
        except OSError:  # no reader yet
            stop.wait(0.05)
            continue
        with os.fdopen(fd, "w") as pipe:
            pipe.write(text)
        return


def _config_path(kind: str, tmp_path):
    """A --config path of the given kind, and the message ``ifmi estimate`` gives for it."""
    path = tmp_path / "c.json"
    if kind == "fifo":
        os.mkfifo(path)
        return path, "is a FIFO, device or socket, not a configuration file; expected a regular file"
    if kind == "device":
        return os.devnull, "is a FIFO, device or socket, not a configuration file; expected a regular file"
    if kind == "folder":
        path.mkdir()
        return path, "is a folder; expected a configuration file"
    if kind == "missing":
        return path, "configuration file not found"
    if kind == "latin-1":
        text = '{"relative_pose": {"seed": 1}, "note": "caf\u00e9"}'
        path.write_bytes(text.encode("latin-1"))
        return path, (f"cannot read configuration file: byte 0xe9 at offset {text.index(chr(0xe9))} is not UTF-8 "
                      "text; expected UTF-8 text")
    path.write_text(json.dumps({"note": "x" * 2 ** 20}))
    return path, f"is {path.stat().st_size} bytes; expected a configuration file of at most 1048576 bytes"


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no FIFOs on this system")
@pytest.mark.parametrize("kind", ["fifo", "device", "folder", "missing", "latin-1", "huge"])
def test_config_that_is_no_json_text_is_one_line(dataset, tmp_path, capsys, kind):
    # Before: a FIFO waited for a writer forever; /dev/null was "invalid JSON at line 1 column 1"; a
    # file of 300 MB was read whole (0.7 GB, 4 s) before its keys were refused.
    config, message = _config_path(kind, tmp_path)
    stop = threading.Event()
    feeder = threading.Thread(target=_feed_fifo_once_read, args=(config, "{}", stop), daemon=True)
    if kind == "fifo":
        feeder.start()
    try:
        code = main(["estimate", str(dataset), "--config", str(config), "--out", str(tmp_path / "e.txt"), *QUIET])
    finally:
        stop.set()
    assert code == 2
    assert _one_line_error(capsys) == f"ifmi estimate: error: {config}: {message}"
    assert not (tmp_path / "e.txt").exists()


# --- 7. outputs never replace the --config file ---------------------------------------------

@pytest.mark.parametrize("out_name", ["run.config.json", "run.txt"])
def test_outputs_never_replace_the_config_file(dataset, run_file, tmp_path, capsys, out_name):
    config = tmp_path / "run.config.json"
    shutil.copyfile(run_file, config)
    before = config.read_bytes()
    out = tmp_path / out_name
    assert main(["estimate", str(dataset), "--config", str(config), "--out", str(out), *QUIET]) == 1
    err = _one_line_error(capsys)
    assert f"would replace the input file {config}" in err
    assert config.read_bytes() == before and sorted(p.name for p in tmp_path.iterdir()) == ["run.config.json"]


# --- 9. camera limits name the configuration file the value came from -----------------------

@pytest.mark.parametrize(("edit", "message"), [
    (lambda d: d["ifmi"]["panorama"].update(width=10 ** 9),
     "ifmi.panorama.width: expected at most 3149 px for this camera"),
    (lambda d: d["ifmi"]["panorama"].update(radius_min_px=10.0, radius_max_px=400.0),
     "ifmi.panorama.radius_max_px: expected a radius under 182.8 px"),
    (lambda d: d["ifmi"]["tiling"].update(tile_size=1e6),
     "ifmi.tiling.tile_size: the 256x256 px image gives a "),
], ids=["width", "radii", "tile_size"])
def test_camera_limits_name_the_config_file(dataset, tmp_path, capsys, edit, message):
    config = _write_config(tmp_path / "c.json", edit)
    assert main(["estimate", str(dataset), "--config", str(config), "--out", str(tmp_path / "e.txt"),
                 *QUIET]) == 2
    assert _one_line_error(capsys).startswith(f"ifmi estimate: error: {config}: {message}")


def test_camera_limits_name_the_option_given_on_the_command_line(dataset, tmp_path, capsys):
    config = _write_config(tmp_path / "c.json", lambda d: d["ifmi"]["panorama"].update(width=512))
    assert main(["estimate", str(dataset), "--config", str(config), "--width", "1000000000",
                 "--out", str(tmp_path / "e.txt"), *QUIET]) == 2
    assert _one_line_error(capsys).startswith("ifmi estimate: error: --width: ifmi.panorama.width: expected at most ")


# --- 10. tile layouts with more tiles than a frame pair's registration memory ---------------

# The limit for 32 px tiles with the default log-polar grid (ifmi.spectral.fourier_mellin.max_tile_count).
TILE_LIMIT_32PX = ("expected at most 12483 tiles per frame (1 GiB to register a frame pair, 84 KiB per 32 px "
                   "tile), got ")


def test_overlap_near_one_is_refused_naming_the_tile_count(dataset, tmp_path, capsys):
    # Before: steps of 1 px between tiles, 31232 tiles of 32 px per frame, 1.6 GiB and about 10 s
    # per frame pair (a 2048 px panorama: hundreds of thousands), with exit 0 in the end.
    out = tmp_path / "e.txt"
    assert main(["estimate", str(dataset), "--overlap", "0.999", "--out", str(out), *QUIET]) == 2
    assert _one_line_error(capsys) == (
        f"ifmi estimate: error: --overlap: ifmi.tiling: {TILE_LIMIT_32PX}31232: 32 px tiles overlapping by 0.999 "
        f"step 1 px across the 92x512 px panorama; an overlap of at most 0.95 keeps within it")
    assert not out.exists()


def test_dense_retry_overlap_near_one_in_a_config_file_names_the_file(dataset, tmp_path, capsys):
    config = _write_config(tmp_path / "c.json", lambda d: d["ifmi"]["recovery"].update(dense_overlap=0.99))
    assert main(["estimate", str(dataset), "--config", str(config), "--out", str(tmp_path / "e.txt"),
                 *QUIET]) == 2
    assert _one_line_error(capsys).startswith(f"ifmi estimate: error: {config}: ifmi.recovery.dense_overlap: "
                                              f"{TILE_LIMIT_32PX}31232: 32 px tiles overlapping by 0.99 ")


def test_a_run_file_of_the_former_flat_layout_is_translated_or_refused_naming_the_key(dataset, tmp_path, capsys):
    # An estimate's NAME.config.json written before the options were grouped: flat iFMI keys, and
    # options that are now fixed (accepted at their value, refused at another).
    former = {"tile_size": None, "overlap": 0.0}
    ifmi = {"tiling": former, "use_prior": True, "dense_retry_fraction": 0.0, "point_spread": 0.1,
            "global_motion": {"confirm_angle_rad": 0.1, "sectors": 12}}
    run = tmp_path / "old.config.json"
    run.write_text(json.dumps({"method": "ifmi", "config": {"ifmi": ifmi}, "derived": []}))
    out = tmp_path / "e.txt"
    assert main(["estimate", str(dataset), "--config", str(run), "--out", str(out), *QUIET]) == 0
    saved = json.loads((tmp_path / "e.config.json").read_text())["config"]["ifmi"]
    assert saved["recovery"]["dense_retry_fraction"] == 0.0 and saved["tracking"]["use_prior"] is True
    assert "point_spread" not in saved and "global_motion" not in saved
    run.write_text(json.dumps({"method": "ifmi", "config": {"ifmi": {**ifmi, "point_spread": 0.2}}, "derived": []}))
    assert main(["estimate", str(dataset), "--config", str(run), "--out", str(out), *QUIET]) == 2
    assert _one_line_error(capsys) == (f"ifmi estimate: error: {run}: invalid configuration: ifmi.point_spread: no "
                                       "longer an option (fixed at 0.1); remove the key")


# --- 8. omnisim degrade: the output folder outside the source -------------------------------

@pytest.mark.parametrize("inside", ["images/sub", "noisy", "images"])
def test_degrade_output_inside_the_source_is_refused(dataset, tmp_path, capsys, inside):
    from omnisim.cli import main as omnisim_main

    source = tmp_path / "source"
    shutil.copytree(dataset, source)
    before = sorted(p.relative_to(source) for p in source.rglob("*"))
    assert omnisim_main(["degrade", str(source), "--out", str(source / inside), "--noise-sigma", "2"]) == 2
    assert _one_line_error(capsys) == (f"omnisim degrade: error: {source / inside}: is inside the source "
                                       f"dataset {source}; choose an output folder outside it")
    assert sorted(p.relative_to(source) for p in source.rglob("*")) == before


def test_degrade_output_inside_the_source_through_a_link_is_refused(dataset, tmp_path, capsys):
    from omnisim.cli import main as omnisim_main

    source = tmp_path / "source"
    shutil.copytree(dataset, source)
    (tmp_path / "link").symlink_to(source / "images")
    assert omnisim_main(["degrade", str(source), "--out", str(tmp_path / "link" / "sub")]) == 2
    assert "is inside the source dataset" in _one_line_error(capsys)
    assert not (source / "images" / "sub").exists()


def test_degrade_next_to_the_source_still_works(dataset, tmp_path):
    from omnisim.cli import main as omnisim_main

    assert omnisim_main(["degrade", str(dataset), "--out", str(tmp_path / "noisy"), "--noise-sigma", "2",
                         "--no-progress"]) == 0
    assert len(list((tmp_path / "noisy" / "images").glob("*.png"))) == len(read_dataset(dataset).image_paths)
    np.testing.assert_equal(read_dataset(tmp_path / "noisy").model.pol, read_dataset(dataset).model.pol)


# --- rolling shutter ------------------------------------------------------------------

def test_rolling_shutter_option_is_saved_with_the_run(dataset, tmp_path):
    out = tmp_path / "rs.txt"
    assert main(["estimate", str(dataset), "--rolling-shutter", "0.4", "--out", str(out), *QUIET]) == 0
    assert _saved(out)["config"]["rolling_shutter"] == {"readout": 0.4, "iterations": 3}


@pytest.mark.parametrize("value", ["1.5", "-0.2"])
def test_rolling_shutter_outside_the_frame_interval_is_refused(dataset, tmp_path, capsys, value):
    assert main(["estimate", str(dataset), "--rolling-shutter", value, "--out", str(tmp_path / "e.txt"),
                 *QUIET]) == 2
    assert _one_line_error(capsys) == (
        f"ifmi estimate: error: --rolling-shutter: readout must be in [0, 1] (a fraction of the frame "
        f"interval), got {float(value)}")


# --- bundle adjustment ----------------------------------------------------------------

def test_bundle_window_option_is_saved_with_the_run(dataset, tmp_path):
    out = tmp_path / "ba.txt"
    assert main(["estimate", str(dataset), "--bundle-window", "3", "--out", str(out), *QUIET]) == 0
    saved = _saved(out)["config"]["bundle_adjustment"]
    assert saved["window"] == 3 and saved["robust_scale_rad"] is None


@pytest.mark.parametrize("extra, message", [
    (["--bundle-window", "1"], "--bundle-window: window must be 0 (off) or at least 2 frames, got 1"),
    (["--bundle-window", "3", "--rolling-shutter", "0.4"],
     "a bundle-adjustment window (3 frames) needs a global shutter, got a read-out time of 0.4"),
])
def test_bad_bundle_window_is_refused(dataset, tmp_path, capsys, extra, message):
    assert main(["estimate", str(dataset), *extra, "--out", str(tmp_path / "e.txt"), *QUIET]) == 2
    assert _one_line_error(capsys).endswith(message)


def test_pixel_threshold_past_half_a_turn_is_refused(dataset, tmp_path, capsys):
    out = tmp_path / "e.txt"
    assert main(["estimate", str(dataset), "--ransac-threshold-px", "1e30", "--out", str(out), *QUIET]) == 2
    assert _one_line_error(capsys).startswith(
        "ifmi estimate: error: --ransac-threshold-px: relative_pose.ransac_threshold_px: expected under ")
    assert not out.exists()


def test_tile_options_given_to_a_keypoint_method_are_named_in_one_warning(dataset, tmp_path, capsys):
    # The estimate is ORB's as without them; the options were dropped without a word before.
    args = ["estimate", str(dataset), "--method", "orb", *QUIET]
    assert main([*args, "--out", str(tmp_path / "plain.txt")]) == 0
    capsys.readouterr()
    assert main([*args, "--out", str(tmp_path / "o.txt"), "--tile-size", "32", "--th-pr", "2", "--seed", "0"]) == 0
    warnings = [line for line in capsys.readouterr().err.splitlines() if "warning" in line]
    assert warnings == ["ifmi estimate: warning: --th-pr, --tile-size only change iFMI's tiles; "
                        "--method orb does not read them"]
    assert (tmp_path / "o.txt").read_text() == (tmp_path / "plain.txt").read_text()
    # iFMI reads them: no warning.
    assert main(["estimate", str(dataset), "--out", str(tmp_path / "i.txt"), "--tile-size", "32", *QUIET]) == 0
    assert "warning" not in capsys.readouterr().err
