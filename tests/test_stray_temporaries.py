"""Temporaries and backups a killed writer leaves are removed by the next run that writes there."""

from __future__ import annotations

import importlib.util
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from ifmi.cli import main
from ifmi.io.atomic import atomic_write_bytes, remove_leftovers

# A process that writes FILES (path=text pairs) as one set and is killed (SIGKILL) at its first
# rename, as a writer killed mid-write: temporaries of every file, the backup of the first (if it existed).
_KILLED_WRITER = textwrap.dedent("""
    import os, signal, sys
    from ifmi.io.atomic import atomic_write_files
    os.replace = lambda *args: os.kill(os.getpid(), signal.SIGKILL)
    atomic_write_files({path: text.encode() for path, text in (arg.split("=", 1) for arg in sys.argv[1:])})
""")


def _killed_writer(*files: Path) -> None:
    """Run :data:`_KILLED_WRITER` on ``files``."""
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(sys.path))
    process = subprocess.run([sys.executable, "-c", _KILLED_WRITER, *(f"{f}=partial" for f in files)],
                             env=env, timeout=120)
    assert process.returncode == -9


def _hidden(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir() if p.name.startswith("."))


def test_a_killed_writer_leaves_temporaries_named_by_its_process(tmp_path):
    atomic_write_bytes(tmp_path / "a.txt", b"old")
    _killed_writer(tmp_path / "a.txt", tmp_path / "b.txt")
    hidden = _hidden(tmp_path)
    assert len(hidden) == 3  # two temporaries, the backup of a.txt (renamed first)
    assert sum(name.startswith(".a.txt.") and name.endswith(".old") for name in hidden) == 1
    assert (tmp_path / "a.txt").read_bytes() == b"old" and not (tmp_path / "b.txt").exists()


def test_leftovers_are_removed_by_name_and_only_those_of_gone_writers(tmp_path):
    _killed_writer(tmp_path / "a.txt", tmp_path / "b.txt")
    alive = tmp_path / f".a.txt.{os.getpid()}-abcdefgh.tmp"  # this process is writing it
    earlier = tmp_path / ".a.txt.k2j4_x9q.tmp"  # an earlier version's name, without a process id
    unrelated = [tmp_path / ".a.txt.tmp", tmp_path / ".c.txt.notes", tmp_path / "a.txt.12-abcdefgh.tmp"]
    for path in [alive, earlier, *unrelated]:
        path.write_bytes(b"x")
    expected = [n for n in _hidden(tmp_path) if n.startswith(".a.txt.") and n not in (alive.name, ".a.txt.tmp")]
    assert len(expected) == 2  # the killed writer's temporary and the earlier version's
    removed = remove_leftovers(tmp_path, names={"a.txt"})
    assert sorted(p.name for p in removed) == expected
    assert alive.exists() and not earlier.exists() and all(p.exists() for p in unrelated)
    assert [n for n in _hidden(tmp_path) if n.startswith(".b.txt.")]  # not named: kept
    remove_leftovers(tmp_path)
    assert _hidden(tmp_path) == sorted([alive.name, ".a.txt.tmp", ".c.txt.notes"])


def test_estimate_removes_the_leftovers_of_its_outputs(tmp_path):
    pytest.importorskip("skimage")
    from ifmi.synthetic import example_band_px, example_omni_model, synthetic_sequence, write_synthetic_dataset

    model = example_omni_model(160)
    dataset = write_synthetic_dataset(tmp_path / "set", synthetic_sequence(model, 3, seed=3, max_step_rad=0.04,
                                                                           band_px=example_band_px(model)))
    out = tmp_path / "runs" / "e.txt"
    assert main(["estimate", str(dataset), "--method", "orb", "--out", str(out), "--no-progress"]) == 0
    written = {p.name: p.read_bytes() for p in out.parent.iterdir()}
    _killed_writer(out.with_name("e.config.json"), out.with_name("e.frames.csv"), out)
    (out.parent / "notes.txt").write_text("mine")
    assert len(_hidden(out.parent)) == 4  # three temporaries, the backup of the first file renamed
    assert main(["estimate", str(dataset), "--method", "orb", "--out", str(out), "--no-progress"]) == 0
    assert _hidden(out.parent) == []
    assert {p.name: p.read_bytes() for p in out.parent.iterdir() if p.name != "notes.txt"}.keys() == written.keys()


@pytest.mark.render
@pytest.mark.skipif(importlib.util.find_spec("mitsuba") is None, reason="mitsuba is not installed")
def test_render_resume_removes_a_frame_temporary_left_by_a_kill(tmp_path):
    sys.path.insert(0, str(Path(__file__).parent))
    from test_omnisim_aov import _scene

    from omnisim.cli import main as omnisim_main

    scene = _scene(tmp_path, frames=2, size=16)
    out = tmp_path / "out"
    assert omnisim_main(["render", str(scene), "--out", str(out), "--no-progress"]) == 0
    frames = {p.name: p.read_bytes() for p in (out / "images").iterdir()}
    (out / "images" / "000001.png").unlink()
    _killed_writer(out / "images" / "000001.png")
    assert len(_hidden(out / "images")) == 1
    assert omnisim_main(["render", str(scene), "--out", str(out), "--no-progress"]) == 0
    assert _hidden(out / "images") == []
    assert {p.name: p.read_bytes() for p in (out / "images").iterdir()} == frames
