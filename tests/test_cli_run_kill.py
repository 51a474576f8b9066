"""`vdb run` killed with SIGKILL at random moments, then started again with the same command, ends with
episode logs byte-identical to an uninterrupted run (sequential, process pool, pipelined)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import runner_fakes as fakes

BASE = ["run", "--model", "echo", "--sim", "line", "--controller", "speed"]


def snapshot(directory: Path) -> dict[str, bytes]:
    return {str(p.relative_to(directory)): p.read_bytes() for p in sorted(directory.rglob("*")) if p.is_file()}


# -- SIGKILL at random moments, then the same command again ---------------------------------------------
def fake_vdb(*args: object) -> list[str]:
    return [sys.executable, str(Path(fakes.__file__)), *[str(a) for a in args]]


KILL_ARGS = ("--scenarios", "road,long", "--seeds", 2, "--model-opt", "sleep=0.003", "--quiet")


def wait_for(path: Path, timeout: float = 20.0) -> None:
    deadline = time.monotonic() + timeout
    while not path.exists() and time.monotonic() < deadline:
        time.sleep(0.01)


def wait_for_episodes(out: Path, count: int, timeout: float = 30.0) -> None:
    """Until ``count`` complete episode logs exist (kill points by progress, not by the clock)."""
    deadline = time.monotonic() + timeout
    while len(list(out.glob("episodes/*.mcap"))) < count and time.monotonic() < deadline:
        time.sleep(0.005)


@pytest.mark.parametrize(("executor", "attempts", "span"), [(("--workers", 1), 3, 1.0), (("--workers", 2), 3, 3.0),
                                                         (("--executor", "pipelined"), 3, 3.0)],
                         ids=["sequential", "process", "pipelined"])
def test_killed_runs_resume_to_byte_identical_results(tmp_path, executor, attempts, span):
    reference = tmp_path / "reference"
    subprocess.run(fake_vdb(*BASE, *KILL_ARGS, "--out", reference), check=True, capture_output=True)
    expected = snapshot(reference / "episodes")
    rng = np.random.default_rng(20240607)
    states = []
    for attempt in range(attempts):
        out = tmp_path / f"killed{attempt}"
        command = fake_vdb(*BASE, *KILL_ARGS, *executor, "--out", out)
        process = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                                   start_new_session=True)
        if attempt == 0:  # anywhere from interpreter start-up on, possibly before the manifest exists
            time.sleep(float(rng.uniform(0.1, 1.0)))
        else:  # somewhere within the sweep: after the manifest and a random number of finished episodes
            wait_for(out / "run.json")
            wait_for_episodes(out, int(rng.integers(0, len(expected))))
            time.sleep(float(rng.uniform(0.0, span / 100)))
        os.killpg(process.pid, signal.SIGKILL)  # the whole group, as a job scheduler or OOM kill of a session would
        process.wait()
        states.append(((out / "run.json").exists(), len(list(out.glob("episodes/*.mcap")))))
        resumed = subprocess.run(command, capture_output=True, text=True)
        assert resumed.returncode == 0, resumed.stderr
        assert snapshot(out / "episodes") == expected
        assert json.loads((out / "failures.json").read_text()) == {"failures": []}
    print("state at each kill (manifest written, complete logs):", states)
    assert any(manifest and done < len(expected) for manifest, done in states), states  # killed mid-sweep


def test_killing_only_the_driver_takes_the_workers_down_too(tmp_path):
    out = tmp_path / "out"
    command = fake_vdb(*BASE, *KILL_ARGS, "--workers", 2, "--out", out)
    process = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 20
    while not list(out.glob("episodes/*.partial")) and time.monotonic() < deadline:
        time.sleep(0.05)
    process.send_signal(signal.SIGKILL)  # only the driver: its workers must not go on writing
    process.wait()
    time.sleep(1.0)
    files = {p.name: p.stat().st_size for p in out.glob("episodes/*")}
    time.sleep(0.5)
    assert {p.name: p.stat().st_size for p in out.glob("episodes/*")} == files  # nobody is writing any more
    resumed = subprocess.run(command, capture_output=True, text=True)
    assert resumed.returncode == 0, resumed.stderr
    assert not list(out.glob("episodes/*.partial"))


@pytest.mark.parametrize("executor", [("--workers", 1), ("--workers", 2), ("--executor", "pipelined")],
                         ids=["sequential", "process", "pipelined"])
def test_ctrl_c_stops_a_run_in_one_line_and_the_same_command_finishes_it(tmp_path, executor):
    slow = ("--scenarios", "road,long", "--seeds", 2, "--model-opt", "sleep=0.03", "--quiet")  # seconds a run
    reference = tmp_path / "reference"
    subprocess.run(fake_vdb(*BASE, *slow, "--out", reference), check=True, capture_output=True)
    out = tmp_path / "out"
    command = fake_vdb(*BASE, *slow, *executor, "--out", out)
    # A shell that starts the suite in the background hands its children SIGINT ignored, and Python then
    # installs no Ctrl-C handler: give the run the default disposition, as a terminal would.
    process = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                               preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    wait_for(out / "run.json")
    wait_for_episodes(out, 1)
    process.send_signal(signal.SIGINT)
    _, err = process.communicate(timeout=30)
    assert process.returncode == 130 and err.strip().splitlines() == ["vdb: error: interrupted"]
    resumed = subprocess.run(command, capture_output=True, text=True)
    assert resumed.returncode == 0, resumed.stderr
    assert snapshot(out / "episodes") == snapshot(reference / "episodes")
