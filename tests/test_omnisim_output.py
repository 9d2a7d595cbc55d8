"""Output folders of render and degrade: nothing made on a scene error, reuse of empty folders,
refusals that name the setting, write failures and interrupts as one line."""

from __future__ import annotations

import importlib.util
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from ifmi.errors import InputError, OutputError
from scene_files import camera_128_section, write_scene

# Mitsuba must not be imported here: omnisim.llvm selects drjit's LLVM before the first import.
if importlib.util.find_spec("mitsuba") is None:
    pytest.skip("mitsuba is not installed (sim extra)", allow_module_level=True)

pytestmark = pytest.mark.render

ROOT = Path(__file__).resolve().parents[1]
SCENE = """
[scene]
seed = 4

[render]
resolution = [32, 32]
spp = {spp}
max_depth = 2

""" + camera_128_section(skewed=False) + """
[trajectory]
frames = {frames}

[materials.painted]
vertex_color = true

[[lights]]
type = "constant"

[[objects]]
generator = "boxes"
count = 4
"""


def _scene(tmp_path, *, spp=1, frames=2, extra="", name="scene.toml"):
    return write_scene(tmp_path, SCENE.format(spp=spp, frames=frames) + extra, name)


def _run_cli(argv, capsys):
    from omnisim.cli import main

    code = main(argv)
    return code, capsys.readouterr().err.strip()


def test_broken_mesh_file_fails_before_the_output_folder_exists(tmp_path):
    from omnisim.renderer import render_dataset

    (tmp_path / "chair.obj").write_text("v 0 0 0\nf 1 2 9\nthis is not obj\n")
    scene = _scene(tmp_path, extra='\n[[objects]]\ngenerator = "mesh"\nfile = "chair.obj"\n')
    with pytest.raises(InputError, match=r"chair.obj: (cannot read mesh file|mesh file holds no triangles)"):
        render_dataset(scene, tmp_path / "out", progress=False)
    assert not (tmp_path / "out").exists()


def test_folder_with_no_frames_is_reused_whatever_it_was_started_with(tmp_path):
    """A folder left by a run that stopped before its first frame (meta with no images, or only an
    empty images/ from older versions) is not refused."""
    from omnisim.renderer import render_dataset

    scene = _scene(tmp_path)
    started = tmp_path / "started"
    (started / "images").mkdir(parents=True)
    (started / "meta.json").write_text(json.dumps({"identity": {"format": 1, "seed": 99}, "images": {},
                                                   "complete": False}))
    assert render_dataset(scene, started, progress=False).rendered == 2
    empty = tmp_path / "empty"
    (empty / "images").mkdir(parents=True)
    assert render_dataset(scene, empty, progress=False).rendered == 2


@pytest.mark.parametrize("meta", [{"camera": "my real rig"}, {}, {"identity": "x", "images": {}}])
def test_folder_with_a_meta_json_omnisim_did_not_write_is_refused_and_kept(tmp_path, meta):
    from omnisim.renderer import render_dataset

    scene = _scene(tmp_path)
    mine = tmp_path / "rig"
    mine.mkdir()
    files = {"meta.json": json.dumps(meta), "calib_results.txt": "my calibration\n", "groundtruth.txt": "0 0 0 0 0 0 0 1\n"}
    for name, text in files.items():
        (mine / name).write_text(text)
    with pytest.raises(InputError, match=r"rig/meta.json: is not an omnisim dataset's"):
        render_dataset(scene, mine, progress=False)
    assert {p.name: p.read_text() for p in mine.iterdir()} == files


def test_refusal_names_the_setting_that_differs(tmp_path):
    from omnisim.renderer import render_dataset

    scene = _scene(tmp_path)
    render_dataset(scene, tmp_path / "out", progress=False)
    with pytest.raises(InputError, match=r"different settings.render.spp \(folder: 1, now: 3\)"):
        render_dataset(scene, tmp_path / "out", spp=3, progress=False)
    with pytest.raises(InputError, match=r"settings.trajectory.frames \(folder: 2, now: 5\)"):
        render_dataset(scene, tmp_path / "out", frames=5, progress=False)


def test_render_out_below_a_regular_file_is_one_line_exit_1(tmp_path, capsys):
    (tmp_path / "file").write_text("mine")
    code, err = _run_cli(["render", str(_scene(tmp_path)), "--out", str(tmp_path / "file" / "out"),
                          "--no-progress"], capsys)
    assert code == 1 and len(err.splitlines()) == 1, err
    assert f"cannot write {tmp_path / 'file' / 'out'}: Not a directory" in err
    assert (tmp_path / "file").read_text() == "mine"


def test_render_into_unwritable_folder_is_one_line_exit_1(tmp_path, capsys, monkeypatch):
    """A folder the process may not write in (simulated: the tests may run as root, who may write anywhere)."""
    real_mkdir = Path.mkdir

    def refusing_mkdir(self, *args, **kwargs):
        if self.is_relative_to(tmp_path / "locked"):
            raise PermissionError(13, "Permission denied", str(self))
        return real_mkdir(self, *args, **kwargs)

    (tmp_path / "locked").mkdir()
    monkeypatch.setattr(Path, "mkdir", refusing_mkdir)
    code, err = _run_cli(["render", str(_scene(tmp_path)), "--out", str(tmp_path / "locked" / "out"),
                          "--no-progress"], capsys)
    assert code == 1 and len(err.splitlines()) == 1, err
    assert f"cannot write {tmp_path / 'locked' / 'out'}: Permission denied" in err
    assert list((tmp_path / "locked").iterdir()) == []


@pytest.mark.skipif(hasattr(os, "geteuid") and os.geteuid() == 0, reason="root may write into read-only folders")
def test_render_into_read_only_folder_is_one_line_exit_1(tmp_path, capsys):
    locked = tmp_path / "locked"
    locked.mkdir()
    locked.chmod(0o555)
    try:
        code, err = _run_cli(["render", str(_scene(tmp_path)), "--out", str(locked / "out"), "--no-progress"],
                             capsys)
    finally:
        locked.chmod(0o755)
    assert code == 1 and len(err.splitlines()) == 1 and "Permission denied" in err


def test_degrade_out_below_a_regular_file_is_one_line_exit_1(tmp_path, capsys):
    from omnisim.renderer import render_dataset

    render_dataset(_scene(tmp_path), tmp_path / "src", progress=False)
    (tmp_path / "file").write_text("mine")
    code, err = _run_cli(["degrade", str(tmp_path / "src"), "--out", str(tmp_path / "file" / "out"),
                          "--noise-sigma", "2", "--no-progress"], capsys)
    assert code == 1 and len(err.splitlines()) == 1, err
    assert f"cannot write {tmp_path / 'file' / 'out'}: Not a directory" in err


def test_open_output_folder_raises_output_error_naming_the_folder(tmp_path):
    from omnisim.renderer import open_output_folder

    (tmp_path / "file").write_text("mine")
    with pytest.raises(OutputError, match=r"cannot write .*file/out: Not a directory"):
        open_output_folder(tmp_path / "file" / "out", {"seed": 1})


def _cli_process(args, tmp_path):
    """``python -m omnisim ARGS`` with SIGINT as a terminal gives it (the runner may ignore SIGINT)."""
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    return subprocess.Popen([sys.executable, "-m", "omnisim", *args], cwd=tmp_path, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))


def _cli_run(args, tmp_path):
    """Exit status and stderr lines of ``python -m omnisim ARGS`` run to its end (killed after 120 s)."""
    process = _cli_process(args, tmp_path)
    try:
        _, err = process.communicate(timeout=120)
    finally:
        process.kill()
    return process.returncode, err.strip().splitlines()


@pytest.mark.parametrize("kind", ["folder", "fifo"])
def test_frame_file_replaced_by_a_folder_or_fifo_is_one_line_exit_2(tmp_path, kind):
    """A frame's file in the output folder that is no regular file: the resume gave a traceback
    (a folder) or waited forever reading it (a FIFO)."""
    from omnisim.renderer import render_dataset

    scene = _scene(tmp_path)
    render_dataset(scene, tmp_path / "out", progress=False)
    frame = tmp_path / "out" / "images" / "000001.png"
    frame.unlink()
    frame.mkdir() if kind == "folder" else os.mkfifo(frame)
    status, lines = _cli_run(["render", str(scene), "--out", str(tmp_path / "out"), "--no-progress"], tmp_path)
    assert status == 2 and lines == [
        f"omnisim render: error: {frame}: is {'a folder' if kind == 'folder' else 'a FIFO, device or socket'} "
        "where the output folder's frame file belongs; remove it or choose another --out"], lines
    assert frame.is_dir() if kind == "folder" else frame.is_fifo()


def test_frame_file_linked_to_another_file_is_refused_and_that_file_kept(tmp_path):
    """A frame file that was a symbolic link to another file: the resume wrote the frame through
    the link, replacing the file it led to (outside the output folder)."""
    from omnisim.renderer import render_dataset

    scene = _scene(tmp_path)
    render_dataset(scene, tmp_path / "out", progress=False)
    (tmp_path / "mine.png").write_bytes(b"mine")
    frame = tmp_path / "out" / "images" / "000001.png"
    frame.unlink()
    frame.symlink_to(tmp_path / "mine.png")
    with pytest.raises(InputError, match=r"000001.png: is a symbolic link to .*mine.png, which does not hold "
                                         r"the frame meta.json records; refusing to write through it"):
        render_dataset(scene, tmp_path / "out", progress=False)
    assert (tmp_path / "mine.png").read_bytes() == b"mine" and frame.is_symlink()


def test_meta_json_that_is_a_fifo_is_one_line_exit_2(tmp_path):
    """A FIFO named meta.json in the output folder made the run wait forever reading it."""
    (tmp_path / "out").mkdir()
    os.mkfifo(tmp_path / "out" / "meta.json")
    status, lines = _cli_run(["render", str(_scene(tmp_path)), "--out", str(tmp_path / "out"), "--no-progress"],
                             tmp_path)
    assert status == 2 and lines == [
        f"omnisim render: error: {tmp_path / 'out' / 'meta.json'}: is a FIFO, device or socket, not a "
        "meta.json file; remove it or choose another --out"], lines
    assert (tmp_path / "out" / "meta.json").is_fifo()


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no FIFOs on this system")
def test_scene_file_that_is_a_fifo_is_one_line_exit_2(tmp_path):
    """omnisim render FIFO waited forever reading the scene file."""
    os.mkfifo(tmp_path / "scene.toml")
    status, lines = _cli_run(["render", str(tmp_path / "scene.toml"), "--out", str(tmp_path / "out"),
                              "--no-progress"], tmp_path)
    assert status == 2 and lines == [
        f"omnisim render: error: {tmp_path / 'scene.toml'}: is a FIFO, device or socket, not a scene file; "
        "expected a regular file"], lines
    assert not (tmp_path / "out").exists()


@pytest.mark.skipif(importlib.util.find_spec("ctypes") is None or __import__("ctypes.util").util.find_library("cuda")
                    is not None, reason="a CUDA driver is present")
def test_cuda_variant_without_gpu_is_one_line_exit_1(tmp_path):
    status, lines = _cli_run(["render", str(_scene(tmp_path)), "--out", str(tmp_path / "out"),
                              "--variant", "cuda_ad_rgb", "--no-progress"], tmp_path)
    assert status == 1 and len(lines) == 1 and "cuda_ad_rgb needs a working CUDA GPU" in lines[0], lines
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("delay", [0.4, 0.6, 1.2])
def test_sigint_during_import_or_first_frame_is_one_line_exit_130(tmp_path, delay):
    """SIGINT while the modules and Mitsuba are imported (0.4, 0.6 s after the interpreter's own
    start-up) or the scene is loaded / the first frame renders (1.2 s): one 'interrupted' line and
    status 130, never a traceback. The render is long enough (many frames) that it cannot finish
    before the signal.

    Before SIGINT was deferred while drjit builds its modules, 16 of 151 tries between 0.3 and
    1.8 s were aborted (status -6); 151 of 151 now end with status 130. One try in CI ran on to
    the end (status 0), most likely because the child inherited an ignored SIGINT from the runner
    (``_cli_process`` now gives it the default). The tests below pin the mechanisms without timing.
    """
    scene = _scene(tmp_path, frames=500)
    # The delays count from the end of the interpreter's own start-up, which takes longer on a
    # slow machine; a SIGINT inside it gets Python's traceback before any project code runs.
    start = time.perf_counter()
    subprocess.run([sys.executable, "-c", "pass"], check=True)
    startup = time.perf_counter() - start
    process = _cli_process(["render", str(scene), "--out", str(tmp_path / "out"), "--no-progress"], tmp_path)
    time.sleep(startup + delay)
    process.send_signal(signal.SIGINT)
    _, err = process.communicate(timeout=120)
    assert process.returncode == 130, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].endswith(": interrupted (rerun the same command to resume)"), err


def test_interrupt_swallowed_by_library_code_still_exits_130(monkeypatch, capsys, default_sigint):
    from omnisim import cli

    def swallowing_command(args):
        try:
            signal.raise_signal(signal.SIGINT)
        except KeyboardInterrupt:
            pass
        return 0

    monkeypatch.setitem(cli.COMMANDS, "generators", swallowing_command)
    code, err = _run_cli(["generators"], capsys)
    assert code == 130 and err == "omnisim generators: interrupted (rerun the same command to resume)"


def test_broken_envmap_file_fails_before_the_output_folder_exists(tmp_path):
    from omnisim.renderer import render_dataset

    (tmp_path / "sky.exr").write_bytes(b"not an image")
    scene = _scene(tmp_path)  # its constant light replaced by the envmap: a scene holds one environment light
    scene.write_text(scene.read_text().replace('type = "constant"', 'type = "envmap"\nfile = "sky.exr"'))
    with pytest.raises(InputError, match=r"sky.exr: \[\[lights\]\] #1"):
        render_dataset(scene, tmp_path / "out", progress=False)
    assert not (tmp_path / "out").exists()


def _png_header_only(width: int, height: int) -> bytes:
    """A PNG signature and IHDR chunk claiming ``width`` x ``height`` 8-bit RGB, then an empty IDAT and IEND."""
    import struct
    import zlib

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    header = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header) + chunk(b"IDAT", zlib.compress(b"")) + chunk(b"IEND", b"")


@pytest.mark.parametrize("content, problem", [
    # Before: Mitsuba's "seek to offset 18446744073709551608".
    (b"this is a note, not an image\n", "is no image file (expected EXR, HDR, PFM, PNG or JPEG)"),
    # Before: read by Mitsuba, which allocated the pixels (std::bad_alloc under a memory limit).
    (_png_header_only(50000, 50000), "is too large to be read (more than 178956970 pixels)"),
])
def test_envmap_that_is_no_image_or_too_large_is_one_line_from_its_header(tmp_path, capsys, content, problem):
    (tmp_path / "sky.png").write_bytes(content)
    scene = _scene(tmp_path)
    scene.write_text(scene.read_text().replace('type = "constant"', 'type = "envmap"\nfile = "sky.png"'))
    code, err = _run_cli(["render", str(scene), "--out", str(tmp_path / "out"), "--no-progress"], capsys)
    assert code == 2
    assert err == f"omnisim render: error: {tmp_path / 'sky.png'}: [[lights]] #1 (envmap) of {scene}: {problem}"
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("extension", ["exr", "hdr", "pfm"])
def test_envmap_header_sizes_of_the_high_dynamic_range_formats(tmp_path, extension):
    """The size is read from the header of each format Mitsuba writes; a header without one is damaged."""
    import numpy as np

    from omnisim.lights import envmap_file_problem
    from omnisim.llvm import import_mitsuba

    path = tmp_path / f"sky.{extension}"
    import_mitsuba().Bitmap(np.full((8, 16, 3), 0.5, np.float32)).write(str(path))
    assert envmap_file_problem(path) == ""
    path.write_bytes(path.read_bytes()[:6])
    assert envmap_file_problem(path) == "is a damaged image file (its header gives no size)"


def test_envmap_with_a_nan_pixel_is_one_line_before_the_output_folder_exists(tmp_path, capsys):
    """An EXR whose top half is NaN rendered black frames with exit 0 (NaN spreads through the
    light sampling); inf, negative and too bright pixels likewise made black or dark pixels."""
    import numpy as np

    from omnisim.llvm import import_mitsuba

    image = np.full((8, 16, 3), 0.5, np.float32)
    image[2, 5] = np.nan
    import_mitsuba().Bitmap(image).write(str(tmp_path / "sky.exr"))
    scene = _scene(tmp_path)
    scene.write_text(scene.read_text().replace('type = "constant"', 'type = "envmap"\nfile = "sky.exr"'))
    code, err = _run_cli(["render", str(scene), "--out", str(tmp_path / "out"), "--no-progress"], capsys)
    assert code == 2
    assert err == (f"omnisim render: error: {tmp_path / 'sky.exr'}: [[lights]] #1 (envmap): expected finite pixel "
                   "values >= 0 (linear radiance; times scale 1 at most 1e+27), got [nan, nan, nan] at row 2, "
                   "column 5")
    assert not (tmp_path / "out").exists()


def test_resumed_folder_whose_meta_depth_is_no_table_is_one_line(tmp_path, capsys):
    """A meta.json edited to "depth": [] (its own identity kept) ended a resume in an AttributeError traceback."""
    scene, out = _scene(tmp_path, frames=1), tmp_path / "out"
    assert _run_cli(["render", str(scene), "--out", str(out), "--no-progress", "--aov", "depth"], capsys)[0] == 0
    meta = json.loads((out / "meta.json").read_text())
    meta["depth"] = []
    (out / "meta.json").write_text(json.dumps(meta))
    code, err = _run_cli(["render", str(scene), "--out", str(out), "--no-progress", "--aov", "depth"], capsys)
    assert code == 2
    assert err == (f"omnisim render: error: {out / 'meta.json'}: expected its 'depth' entry to be a table (file name: "
                   "sha256), got list; remove the folder or choose another --out")
    assert json.loads((out / "meta.json").read_text()) == meta  # the user's folder is left as it is


def test_spp_the_sampler_rounds_up_is_rendered_as_the_rounded_count_and_recorded(tmp_path):
    """multijitter renders 6 samples when asked for 5: said once, recorded, and the images are those
    of spp 6 (Mitsuba is asked for the rounded count, so it does not log the rounding per frame)."""
    from ifmi.errors import InputWarning
    from omnisim.renderer import render_dataset

    with pytest.warns(InputWarning, match=r"\[render\] spp 5: the multijitter sampler renders 6 samples per pixel"):
        render_dataset(_scene(tmp_path, spp=5, frames=1, name="five.toml"), tmp_path / "five", progress=False)
    render_dataset(_scene(tmp_path, spp=6, frames=1, name="six.toml"), tmp_path / "six", progress=False)
    meta = json.loads((tmp_path / "five" / "meta.json").read_text())
    assert (meta["spp"], meta["spp_rendered"]) == (5, 6)
    assert json.loads((tmp_path / "six" / "meta.json").read_text())["spp_rendered"] == 6
    image = Path("images") / "000000.png"
    assert (tmp_path / "five" / image).read_bytes() == (tmp_path / "six" / image).read_bytes()


def test_frames_with_no_light_are_warned_about(tmp_path):
    """A scene whose camera sees no light renders black frames; that is said once, not left silent."""
    import warnings

    from ifmi.errors import InputWarning
    from omnisim.renderer import render_dataset

    dark = _scene(tmp_path, name="dark.toml")
    dark.write_text(dark.read_text().replace('[[lights]]\ntype = "constant"\n', ""))
    with pytest.warns(InputWarning, match=r"dark.toml: 2 of the 2 frames rendered now are black \(every pixel 0\)"):
        render_dataset(dark, tmp_path / "dark", progress=False)
    with warnings.catch_warnings():
        warnings.simplefilter("error", InputWarning)
        render_dataset(_scene(tmp_path), tmp_path / "lit", progress=False)


def test_refusal_names_the_asset_file_that_changed(tmp_path):
    from omnisim.renderer import check_output_folder

    identity = {"format": 1, "settings": {"assets": [["a.obj", "1" * 64], ["wood.png", "2" * 64]]}}
    (tmp_path / "meta.json").write_text(json.dumps({"identity": identity, "images": {"000000.png": "0" * 64}}))
    edited = {"format": 1, "settings": {"assets": [["a.obj", "1" * 64], ["wood.png", "3" * 64]]}}
    with pytest.raises(InputError, match=r"different settings.assets.wood.png \(folder: \"2222"):
        check_output_folder(tmp_path, edited)


def test_resuming_a_finished_render_writes_nothing(tmp_path, capsys):
    """A finished dataset on a read-only mount: the resume rewrote calib_results.txt (same bytes) and
    failed with exit 1. Now no file is replaced (same inode, same mtime), so it needs no write access."""
    scene, out = _scene(tmp_path, frames=2), tmp_path / "out"
    assert _run_cli(["render", str(scene), "--out", str(out), "--no-progress"], capsys)[0] == 0

    def files():
        return {p: (p.stat().st_ino, p.stat().st_mtime_ns) for p in out.rglob("*") if p.is_file()}

    before = files()
    assert {"calib_results.txt", "groundtruth.txt", "meta.json"} <= {p.name for p in before}
    assert _run_cli(["render", str(scene), "--out", str(out), "--no-progress"], capsys)[0] == 0
    assert files() == before


def test_an_atomic_write_of_the_same_bytes_leaves_the_file_untouched(tmp_path):
    from ifmi.io.atomic import atomic_write_bytes, atomic_write_files

    path = tmp_path / "calib_results.txt"
    atomic_write_bytes(path, b"same")
    inode = path.stat().st_ino
    atomic_write_files({path: b"same", tmp_path / "other.txt": b"new"})
    assert path.stat().st_ino == inode and (tmp_path / "other.txt").read_bytes() == b"new"
    atomic_write_bytes(path, b"changed")
    assert path.stat().st_ino != inode and path.read_bytes() == b"changed"
