"""Faults on the paths a farm uses, each with what the user sees.

- ``render --frames`` killed (SIGKILL, SIGTERM) at chosen points inside a frame's writes and at
  random times, then run again until it finishes: the same images and masks as an uninterrupted
  run (SHA-256 of every file), a stats list with every frame, and nothing staged left behind.
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

import pytest

pytestmark = [pytest.mark.blender, pytest.mark.gpu]

REPO = Path(__file__).resolve().parents[1]
FRAMES = "1-4"
ARGS = ["animated", "--frames", FRAMES, "--resolution", "96x72", "--quality", "high"]

# the CLI, with the process ended (signal ``sig``) as it is about to make its ``at``-th rename
_KILLED_AT_RENAME = """
import os, runpy, signal, sys
sys.path.insert(0, {repo!r})
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
        code = _KILLED_AT_RENAME.format(repo=str(REPO), at=at, sig=int(sig), args=_args(out))
        p = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, timeout=300)
        assert p.returncode == -int(sig), (at, p.returncode, p.stderr[-2000:])
        done = (at - 1) // per_frame  # frames whose image was put in place
        assert sorted(x.name for x in out.glob("f_*.png")) == [f"f_{f:04d}.png" for f in range(1, done + 1)]
        _finish(out)
        _check_same(out, want)


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
