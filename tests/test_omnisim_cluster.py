"""Rendering on a Dask cluster gives the same files as one process."""

from __future__ import annotations

import importlib.util
import json

import pytest

# Mitsuba must not be imported here: omnisim.llvm selects drjit's LLVM before the first import.
if importlib.util.find_spec("mitsuba") is None or importlib.util.find_spec("distributed") is None:
    pytest.skip("mitsuba or dask.distributed is not installed", allow_module_level=True)

from test_omnisim_aov import _scene  # noqa: E402  (the box room scene)

pytestmark = pytest.mark.render


def _files(folder):
    return {p.relative_to(folder): p.read_bytes() for p in folder.rglob("*")
            if p.is_file() and p.name != "meta.json"}


def test_workers_write_the_same_bytes_as_one_process(tmp_path):
    """Two worker processes render a timed capture with AOVs; every file equals the single-process one."""
    from omnisim.renderer import render_dataset

    scene = _scene(tmp_path, frames=3, exposure=0.3, rolling=0.2, size=16)
    single, parallel = tmp_path / "single", tmp_path / "parallel"
    render_dataset(scene, single, progress=False, aovs="depth,normal")
    result = render_dataset(scene, parallel, progress=False, aovs="depth,normal", workers=2)
    assert result.rendered == 3
    files = _files(single)
    assert len(files) == 3 * 3 + 3 + 3  # images, depth, normal; rows; calib and two trajectories
    assert _files(parallel) == files
    meta_single, meta_parallel = (json.loads((f / "meta.json").read_text()) for f in (single, parallel))
    for kind in ("images", "depth", "normal", "rolling_shutter"):
        assert meta_parallel[kind] == meta_single[kind]
    assert meta_parallel["complete"]


def test_existing_scheduler_renders_the_same_bytes(tmp_path):
    """--scheduler ADDRESS: a cluster started elsewhere (here: in this test) renders the same files."""
    from distributed import LocalCluster

    from omnisim.renderer import render_dataset

    scene = _scene(tmp_path, frames=2, size=16)
    render_dataset(scene, tmp_path / "single", progress=False, aovs="depth")
    with LocalCluster(n_workers=1, threads_per_worker=1, processes=True, dashboard_address=None) as cluster:
        result = render_dataset(scene, tmp_path / "remote", progress=False, aovs="depth",
                                scheduler=cluster.scheduler_address)
    assert result.rendered == 2
    assert _files(tmp_path / "remote") == _files(tmp_path / "single")


def test_scheduler_address_dask_cannot_use_is_one_line(tmp_path, capsys):
    """--scheduler nonsense://x ended in Dask's ValueError traceback (an unreachable one, after 30 s,
    in an OSError traceback)."""
    from omnisim.cli import main

    scene = _scene(tmp_path, frames=1, size=16)
    assert main(["render", str(scene), "--out", str(tmp_path / "out"), "--no-progress",
                 "--scheduler", "nonsense://x"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("omnisim render: error: --scheduler: cannot connect to a Dask scheduler at "
                          "'nonsense://x': unknown address scheme 'nonsense'") and "\n" not in err
    assert not (tmp_path / "out").exists()  # was left behind: calibration, ground truth, meta.json


@pytest.mark.parametrize("address", ["", "  "])
def test_blank_scheduler_address_is_one_line(tmp_path, capsys, address):
    """--scheduler "" (an unset variable) rendered in this process as if no option were given."""
    from omnisim.cli import main

    scene = _scene(tmp_path, frames=1, size=16)
    assert main(["render", str(scene), "--out", str(tmp_path / "out"), "--no-progress",
                 "--scheduler", address]) == 2
    assert capsys.readouterr().err.strip() == ("omnisim render: error: --scheduler: expected the address of a "
                                               f"Dask scheduler (e.g. tcp://HOST:8786), got {address!r}")
    assert not (tmp_path / "out").exists()


def test_finished_render_needs_no_scheduler(tmp_path, capsys):
    """A rerun with nothing left to render connects to no cluster, as before."""
    from omnisim.cli import main

    scene = _scene(tmp_path, frames=1, size=16)
    out = tmp_path / "out"
    assert main(["render", str(scene), "--out", str(out), "--no-progress"]) == 0
    files = {p: p.read_bytes() for p in out.rglob("*") if p.is_file() and p.name != "meta.json"}
    assert main(["render", str(scene), "--out", str(out), "--no-progress", "--scheduler", "nonsense://x"]) == 0
    assert "0 rendered now" in capsys.readouterr().out
    assert {p: p.read_bytes() for p in out.rglob("*") if p.is_file() and p.name != "meta.json"} == files


def test_scheduler_that_never_answers_is_one_line_within_the_connect_timeout(tmp_path, capsys):
    """A listener that accepts and stays silent hung the render with no output (past 400 s)."""
    import socket

    from omnisim.cli import main

    scene = _scene(tmp_path, frames=1, size=16)
    with socket.socket() as listener:
        listener.bind(("127.0.0.1", 0))
        listener.listen(4)
        address = f"tcp://127.0.0.1:{listener.getsockname()[1]}"
        assert main(["render", str(scene), "--out", str(tmp_path / "out"), "--scheduler", address,
                     "--connect-timeout", "1"]) == 2
    err = capsys.readouterr().err
    assert err == (f"omnisim render: error: --scheduler: cannot connect to a Dask scheduler at {address!r}: no Dask "
                   f"answer within 1 s (nothing listening, a server of another protocol such as the dashboard's "
                   f"HTTP, or a stuck scheduler; --connect-timeout SECONDS changes the wait)\n")
    assert not (tmp_path / "out").exists()


def test_a_worker_killed_mid_render_is_replaced_and_the_render_completes(tmp_path):
    """SIGKILL to one of two workers once the first frame is stored: Dask reruns its frames on the
    replacement worker and every file equals the single-process render."""
    import signal
    import threading
    import time

    import psutil

    from omnisim.renderer import render_dataset

    # Enough frames that the kill at the first stored frame lands mid-run on any machine: eight 32 px
    # frames could all be stored between two looks of the killer (frames are stored in bursts).
    frames = 40
    scene = _scene(tmp_path, frames=frames, size=32)
    render_dataset(scene, tmp_path / "single", progress=False)
    out = tmp_path / "parallel"
    killed = {}

    def kill_one_worker():
        for _ in range(2400):  # 120 s at most
            stored = sorted((out / "images").glob("*.png")) if (out / "images").is_dir() else []
            workers = [p for p in psutil.Process().children(recursive=True)
                       if "spawn_main" in " ".join(p.cmdline())]
            if stored and workers:
                killed["frames_stored"] = len(stored)
                workers[0].send_signal(signal.SIGKILL)
                return
            time.sleep(0.05)

    killer = threading.Thread(target=kill_one_worker, daemon=True)
    killer.start()
    result = render_dataset(scene, out, progress=False, workers=2)
    killer.join(timeout=130)
    assert killed and killed["frames_stored"] < frames  # the kill came mid-run
    assert result.rendered == frames
    assert _files(out) == _files(tmp_path / "single")
    assert json.loads((out / "meta.json").read_text())["complete"]
