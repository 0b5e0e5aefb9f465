"""Faults on the paths a farm uses, each with what the user sees.

- ``render --frames`` killed (SIGKILL, SIGTERM) at chosen points inside a frame's writes and at
  random times, then run again until it finishes: the same images and masks as an uninterrupted
  run (SHA-256 of every file), a stats list with every frame, and nothing staged left behind.
- A final render's (F12's, and the command line's) renderer process killed in the bake or in a
  pass: the frame is rendered again in a new process, the same image and files; killed twice:
  one line naming the stage.
- A renderer that hangs (SIGSTOP): ended after its deadline (``HYBRID_SHADOWS_DEADLINE_S``),
  the frame rendered again. In the viewport a renderer killed (while the caller exports, in a
  bake, in a pass) or hung is one status line, and the next frame renders in a new process.
- An output disk that fills during ``--frames``: one line (exit code 74), the frames before it
  complete, nothing of the failing one; a rerun finishes with the same files. A truncated or
  foreign ``.blend``: one line (exit code 2), nothing written.
- A message that cannot be pickled: one line, at once; a channel closed mid-message: the child
  ends, the next render starts a new one; renders queued for a dead child's scene are dropped
  (no crash in the next child); no child outlives ``close()``.
"""
from __future__ import annotations

import hashlib
import json
import os
import random
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from hybrid_shadow_addon.core.runtime.channel import RendererError
from hybrid_shadow_addon.core.settings import Settings

pytestmark = [pytest.mark.blender, pytest.mark.gpu]

REPO = Path(__file__).resolve().parents[1]
FRAMES = "1-4"
ARGS = ["animated", "--frames", FRAMES, "--resolution", "96x72", "--quality", "high"]

# the CLI, with the process ended (signal ``sig``) as it is about to make its ``at``-th rename
_KILLED_AT_RENAME = """
import os, runpy, signal, sys
real, n = os.replace, [0]
def replace(a, b):
    n[0] += 1
    if n[0] == {at}:
        os.kill(os.getpid(), {sig})
    return real(a, b)
os.replace = replace
sys.argv = ["hybrid_shadow_addon"] + {args!r}
runpy.run_module("hybrid_shadow_addon", run_name="__main__")
"""


def _args(out: Path) -> list:
    return ["render", *ARGS, "--output", str(out / "f_####.png"), "--masks-dir", str(out / "masks"),
            "--stats", str(out / "stats.json")]


def _cli(out: Path, timeout=300):
    return subprocess.run([sys.executable, "-m", "hybrid_shadow_addon", *_args(out)], cwd=REPO, capture_output=True,
                          text=True, timeout=timeout)


def _digests(out: Path) -> dict:
    """SHA-256 of every image and mask (the stats hold times: their frames are compared)."""
    return {str(p.relative_to(out)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(out.rglob("*")) if p.is_file() and p.suffix in (".png", ".npy")}


def _finish(out: Path, attempts=6) -> int:
    """Run the CLI again until it succeeds; the runs it took."""
    for k in range(1, attempts + 1):
        p = _cli(out)
        if p.returncode == 0:
            return k
    raise AssertionError(p.stderr[-2000:])


def _check_same(out: Path, want: dict) -> None:
    assert _digests(out) == want
    assert [e["frame"] for e in json.loads((out / "stats.json").read_text())] == [1, 2, 3, 4]
    assert not [p for p in out.rglob(".*")], "staged files left behind"


# the CLI, with the disk full from the ``at``-th image on
_DISK_FULL = """
import errno, runpy, sys
from hybrid_shadow_addon.tools import render
real, n = render.write_image, [0]
def write_image(path, rgba):
    n[0] += 1
    if n[0] >= {at}:
        with open(path, "wb") as f:
            f.write(b"half an image")
        raise OSError(errno.ENOSPC, "No space left on device", str(path))
    real(path, rgba)
render.write_image = write_image
sys.argv = ["hybrid_shadow_addon"] + {args!r}
sys.exit(__import__("hybrid_shadow_addon.__main__", fromlist=["main"]).main(sys.argv[1:]))
"""


# the CLI, with its renderer process sent ``sig`` at the first "Baking" of frame ``frame``
_CLI_RENDERER_FAULT = """
import os, runpy, signal, sys
from hybrid_shadow_addon.core.runtime import remote
real, calls, hit = remote.FinalRenderer.render, [0], []
def render(self, *a, on_progress=None, **k):
    calls[0] += 1
    def progress(done, total, label):
        if calls[0] == {frame} and not hit and label == "Baking":
            hit.append(self.pid)
            os.kill(self.pid, {sig})
        if on_progress is not None:
            on_progress(done, total, label)
    return real(self, *a, on_progress=progress, **k)
remote.FinalRenderer.render = render
sys.argv = ["hybrid_shadow_addon"] + {args!r}
sys.exit(__import__("hybrid_shadow_addon.__main__", fromlist=["main"]).main(sys.argv[1:]))
"""


@pytest.fixture(scope="module")
def uninterrupted(tmp_path_factory):
    out = tmp_path_factory.mktemp("whole")
    t0 = time.monotonic()
    p = _cli(out)
    assert p.returncode == 0, p.stderr[-2000:]
    want = _digests(out)
    lights = len(list((out / "masks" / "0001").glob("*.npy")))
    assert lights >= 1 and len(want) == 4 * (1 + lights)
    # renames per frame: its masks, the stats list, the image
    return want, lights + 2, time.monotonic() - t0


@pytest.mark.slow
@pytest.mark.parametrize("sig", [signal.SIGKILL, signal.SIGTERM])
def test_frames_killed_between_a_frames_renames_resume_to_the_same_files(tmp_path, uninterrupted, sig):
    want, per_frame, _ = uninterrupted
    # in frame 2: before its first mask, before its image, or just before frame 3's image
    for at in (per_frame + 1, 2 * per_frame - 1, 2 * per_frame, 3 * per_frame):
        out = tmp_path / f"at{at}"
        out.mkdir()
        code = _KILLED_AT_RENAME.format(at=at, sig=int(sig), args=_args(out))
        p = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, timeout=300)
        assert p.returncode == -int(sig), (at, p.returncode, p.stderr[-2000:])
        done = (at - 1) // per_frame  # frames whose image was put in place
        assert sorted(x.name for x in out.glob("f_*.png")) == [f"f_{f:04d}.png" for f in range(1, done + 1)]
        _finish(out)
        _check_same(out, want)


@pytest.mark.parametrize("sig", [signal.SIGKILL, signal.SIGSTOP])
def test_frames_whose_renderer_dies_or_hangs_render_that_frame_again(tmp_path, uninterrupted, sig):
    """``render --frames`` renders in a renderer process: killed (or stopped: ended after its
    deadline) in frame 2's bake, frame 2 is rendered again in a new one; the same files."""
    want = uninterrupted[0]
    out = tmp_path / "cli"
    out.mkdir()
    code = _CLI_RENDERER_FAULT.format(frame=2, sig=int(sig), args=_args(out))
    env = dict(os.environ, HYBRID_SHADOWS_DEADLINE_S="4")
    p = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, timeout=300, env=env)
    assert p.returncode == 0, p.stderr[-2000:]
    said = "ended unexpectedly" if sig == signal.SIGKILL else "stopped answering"
    assert f"{said}" in p.stderr and "in 'Baking'; rendering the frame again" in p.stderr, p.stderr[-2000:]
    _check_same(out, want)


def test_a_disk_that_fills_during_frames_is_one_line_and_a_rerun_finishes(tmp_path, uninterrupted):
    want = uninterrupted[0]
    out = tmp_path / "full"
    out.mkdir()
    code = _DISK_FULL.format(at=3, args=_args(out))
    p = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, timeout=300)
    assert p.returncode == 74, p.stderr[-2000:]
    last = p.stderr.strip().splitlines()[-1]
    assert last.startswith("error: cannot write") and "No space left on device" in last, last
    assert sorted(x.name for x in out.glob("f_*.png")) == ["f_0001.png", "f_0002.png"]
    assert not (out / "masks" / "0003").exists() and not [q for q in out.rglob(".*")]
    assert [e["frame"] for e in json.loads((out / "stats.json").read_text())] == [1, 2]
    _finish(out)
    _check_same(out, want)


@pytest.mark.parametrize("keep", [1000, 200_000, None])
def test_a_truncated_or_foreign_blend_is_one_line(tmp_path, keep):
    import bpy

    whole = tmp_path / "whole.blend"
    bpy.ops.wm.read_homefile(use_empty=True)
    bpy.ops.wm.save_as_mainfile(filepath=str(whole))
    bad = tmp_path / "bad.blend"
    data = whole.read_bytes()
    bad.write_bytes(data[:keep] if keep else b"not a blend file")
    p = subprocess.run([sys.executable, "-m", "hybrid_shadow_addon", "render", str(bad), "--output",
                        str(tmp_path / "x.png")], cwd=REPO, capture_output=True, text=True, timeout=120)
    assert p.returncode == 2, p.stderr[-2000:]
    last = p.stderr.strip().splitlines()[-1]
    assert last.startswith(f"error: cannot open {bad}"), last
    assert not (tmp_path / "x.png").exists()


@pytest.mark.slow
def test_frames_killed_at_random_times_resume_to_the_same_files(tmp_path, uninterrupted):
    want, _, seconds = uninterrupted
    rng = random.Random(50)
    out = tmp_path / "random"
    out.mkdir()
    for _ in range(3):
        proc = subprocess.Popen([sys.executable, "-m", "hybrid_shadow_addon", *_args(out)], cwd=REPO,
                                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        time.sleep(rng.uniform(0.3, 1.0) * seconds)
        if proc.poll() is None:
            os.kill(proc.pid, signal.SIGKILL)
        proc.wait(60)
    _finish(out)
    _check_same(out, want)


# -- the renderer process ----------------------------------------------------------------------
SIZE = (160, 90)


def _alive(pid) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    try:  # (a zombie is gone for our purposes)
        return Path(f"/proc/{pid}/stat").read_text().split(")")[-1].split()[0] != "Z"
    except OSError:
        return False


@pytest.fixture
def final_renderer(monkeypatch):
    from hybrid_shadow_addon.core.runtime.remote import FinalRenderer

    monkeypatch.setenv("HYBRID_SHADOWS_DEADLINE_S", "4")
    made = []

    def make():
        made.append(FinalRenderer())
        return made[-1]

    yield make
    for r in made:
        r.close()


def _fault_on(renderer, when, sig=signal.SIGKILL, times=1):
    """An ``on_progress`` that sends ``sig`` to the renderer at the first progress whose label
    ``when(label)`` accepts, ``times`` times (once per process)."""
    hit = []

    def on_progress(done, total, label):
        pid = renderer.pid
        if len(hit) < times and when(label) and pid not in hit:
            hit.append(pid)
            os.kill(pid, sig)

    return on_progress, hit


@pytest.mark.parametrize("stage", ["Baking", "a pass"])
def test_a_final_renderer_killed_renders_the_frame_again(loaded, final_renderer, stage, capfd):
    scene = loaded("cube_on_plane")
    settings = Settings(samples=4)
    want = final_renderer().render(scene, settings, *SIZE).image
    r = final_renderer()
    on_progress, hit = _fault_on(r, (lambda lb: lb == "Baking") if stage == "Baking" else (lambda lb: lb != "Baking"))
    got = r.render(scene, settings, *SIZE, on_progress=on_progress)
    assert len(hit) == 1 and r.starts == 2
    assert np.array_equal(got.image, want)
    err = capfd.readouterr().err
    assert "ended unexpectedly" in err and "rendering the frame again" in err


def test_a_final_renderer_killed_twice_is_one_line_naming_the_stage(loaded, final_renderer):
    r = final_renderer()
    on_progress, hit = _fault_on(r, lambda lb: lb == "Baking", times=2)
    with pytest.raises(RendererError) as info:
        r.render(loaded("cube_on_plane"), Settings(hard=True), *SIZE, on_progress=on_progress)
    msg = str(info.value)
    assert len(hit) == 2 and "\n" not in msg
    assert "ended unexpectedly" in msg and "in 'Baking', twice" in msg, msg


@pytest.mark.slow
def test_a_hung_final_renderer_is_ended_after_its_deadline(loaded, final_renderer):
    scene = loaded("cube_on_plane")
    r = final_renderer()
    on_progress, hit = _fault_on(r, lambda lb: lb == "Baking", sig=signal.SIGSTOP)
    t0 = time.monotonic()
    got = r.render(scene, Settings(hard=True), *SIZE, on_progress=on_progress)
    assert len(hit) == 1 and r.starts == 2 and not _alive(hit[0])
    assert 4.0 < time.monotonic() - t0 < 60 and got.image.shape[:2] == (SIZE[1], SIZE[0])
    # stopped again in the retry: one line, "stopped answering", within two deadlines and the frames
    r2 = final_renderer()
    on_progress, hit = _fault_on(r2, lambda lb: lb == "Baking", sig=signal.SIGSTOP, times=2)
    with pytest.raises(RendererError, match=r"stopped answering for \d+ s and was ended in 'Baking', twice"):
        r2.render(scene, Settings(hard=True), *SIZE, on_progress=on_progress)
    assert not any(_alive(p) for p in hit)


def test_a_final_renderer_without_progress_past_its_stage_deadline_is_one_line(loaded, final_renderer,
                                                                              monkeypatch):
    """A renderer that beats but does not advance (here: any stage longer than 0.05 s) is ended
    after ``HYBRID_SHADOWS_STAGE_DEADLINE_S``, the frame tried once more, then one line."""
    monkeypatch.setenv("HYBRID_SHADOWS_STAGE_DEADLINE_S", "0.05")
    r = final_renderer()
    with pytest.raises(RendererError, match=r"made no progress for [\d.]+ s and was ended in '.*', twice") as info:
        r.render(loaded("forest"), Settings(samples=16), 320, 180)
    assert r.starts == 2 and "\n" not in str(info.value)


def test_a_frame_that_cannot_be_sent_is_one_line_at_once(loaded, final_renderer):
    r = final_renderer()
    t0 = time.monotonic()
    with pytest.raises(RendererError, match="could not be sent to the renderer process") as info:
        r.render(loaded("cube_on_plane"), Settings(hard=True), *SIZE, want=(lambda: 0,))
    assert time.monotonic() - t0 < 5 and "\n" not in str(info.value)
    assert r.render(loaded("cube_on_plane"), Settings(hard=True), *SIZE).image is not None


def test_a_channel_closed_mid_message_ends_the_child_and_the_next_render_starts_one(loaded, final_renderer):
    r = final_renderer()
    scene = loaded("cube_on_plane")
    r.render(scene, Settings(hard=True), *SIZE)
    pid, proc = r.pid, r._proc._proc
    proc.stdin.write(b"\x40\x00\x00\x00\x00\x00\x00\x00\x00\x00\x00\x00half a mess")
    proc.stdin.close()
    proc.wait(10)
    assert not _alive(pid)
    assert r.render(scene, Settings(hard=True), *SIZE).image is not None and r.pid != pid


_PARENT = """
import os, sys, time
from hybrid_shadow_addon.blender.load import load_scene
from hybrid_shadow_addon.core.runtime.remote import FinalRenderer
from hybrid_shadow_addon.core.settings import Settings
r = FinalRenderer()
r.render(load_scene("cube_on_plane"), Settings(hard=True), 64, 36)
print(r.pid, flush=True)
time.sleep(600)
"""


def test_no_child_outlives_its_parent():
    """The caller killed (SIGKILL: no clean-up runs): its renderer sees its channel close and ends."""
    parent = subprocess.Popen([sys.executable, "-c", _PARENT], cwd=REPO,
                              stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    try:
        child = int(parent.stdout.readline())
        assert _alive(child)
    finally:
        parent.kill()
        parent.wait(30)
    deadline = time.monotonic() + 15
    while _alive(child) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert not _alive(child)


def test_no_child_outlives_close(loaded, final_renderer):
    from hybrid_shadow_addon.core.runtime.remote import RemoteWorker

    r = final_renderer()
    r.render(loaded("cube_on_plane"), Settings(hard=True), *SIZE)
    pid = r.pid
    os.kill(pid, signal.SIGSTOP)  # (a child that would not exit when asked)
    r.close()
    assert not _alive(pid)
    w = RemoteWorker()
    w.set_scene(loaded("cube_on_plane"))  # (its sender starts a child while we close)
    w.close()
    time.sleep(0.5)
    assert w.pid is None or not _alive(w.pid)


@pytest.mark.parametrize("stage", ["export", "bake", "pass"])
def test_a_viewport_renderer_killed_is_one_status_line_and_the_next_frame_renders(loaded, stage):
    """Killed while the caller exports (the child idle), in a bake or in a frame's passes: one
    error, and the next frame renders in a new process."""
    import dataclasses

    from hybrid_shadow_addon.core.runtime.remote import RemoteWorker
    from hybrid_shadow_addon.core.runtime.worker import RenderRequest

    forest = dataclasses.replace(loaded("forest"), resolution=(320, 180))
    settings = Settings(hard=True)

    def request(scene):
        return RenderRequest(view="v", scene=scene, fast=settings, full=settings, width=scene.resolution[0],
                             height=scene.resolution[1])

    w = RemoteWorker()
    try:
        w.render(request(dataclasses.replace(loaded("cube_on_plane"), resolution=SIZE)))
        assert w.wait_idle(120) and w.poll("v")[1] == []
        pid = w.pid
        if stage == "bake":
            w.set_scene(forest)
            time.sleep(0.15)
        elif stage == "pass":
            w.render(request(forest))
            time.sleep(0.6)
        os.kill(pid, signal.SIGKILL)
        deadline, errors = time.monotonic() + 30, []
        while not errors and time.monotonic() < deadline:
            errors = w.poll("v")[1]
            time.sleep(0.05)
        assert len(errors) == 1 and "ended unexpectedly" in str(errors[0]), errors
        w.render(request(forest))
        assert w.wait_idle(120)
        result, errors = w.poll("v")
        assert result is not None and errors == [] and w.pid != pid
    finally:
        w.close()


def test_a_hung_viewport_renderer_is_one_status_line_and_the_next_frame_renders(loaded, monkeypatch):
    import dataclasses

    from hybrid_shadow_addon.core.runtime.remote import RemoteWorker
    from hybrid_shadow_addon.core.runtime.worker import RenderRequest

    monkeypatch.setenv("HYBRID_SHADOWS_DEADLINE_S", "3")
    scene = dataclasses.replace(loaded("cube_on_plane"), resolution=SIZE)
    settings = Settings(hard=True)

    def request(view="v"):
        return RenderRequest(view=view, scene=scene, fast=settings, full=settings, width=SIZE[0], height=SIZE[1])

    w = RemoteWorker()
    try:
        w.render(request())
        assert w.wait_idle(120)
        assert w.poll("v")[1] == []
        pid = w.pid
        os.kill(pid, signal.SIGSTOP)
        w.reset_history()  # (queued for the stopped child's scene)
        deadline, errors = time.monotonic() + 30, []
        while not errors and time.monotonic() < deadline:
            errors = w.poll("v")[1]
            time.sleep(0.05)
        assert len(errors) == 1 and "stopped answering" in str(errors[0]), errors
        assert not _alive(pid)
        w.render(request())
        assert w.wait_idle(120)
        result, errors = w.poll("v")
        assert result is not None and errors == [] and w.pid != pid
    finally:
        w.close()
