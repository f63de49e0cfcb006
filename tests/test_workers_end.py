"""Worker processes end with the command that started them: killed with SIGKILL mid-run (a crash, an
OOM kill, a robot's supervisor) or stopped with Ctrl-C, every command that starts workers leaves no
process behind within 5 s, and Ctrl-C ends with one line."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tests.test_frame_folders import _lift_data
from tests.test_grasp_cli import SMALL

#: motionnet small enough for seconds of training, with every run's trainings in two workers
TRAIN = [a for a in SMALL if a not in ("--threads", "1")] + ["--workers", "2"]


def _commands(rec: Path, lift: Path, mine: Path, out: Path) -> dict[str, list[str]]:
    cli = [sys.executable, "-m", "slipsense.cli"]
    return {
        "label": [*cli, "label", "--recordings", str(mine), "--csv", str(out / "l.csv"), "--no-progress"],
        "train --workers": [
            *cli,
            "train",
            "--recordings",
            str(rec),
            "--out",
            str(out / "t"),
            "--fold",
            "0",
            "--folds",
            "2",
            "--inner-folds",
            "2",
            *TRAIN,
        ],  # fmt: skip
        "train --cross-validate": [
            *cli,
            "train",
            "--cross-validate",
            "--recordings",
            str(rec),
            "--out",
            str(out / "cv"),
            "--folds",
            "2",
            "--inner-folds",
            "2",
            *TRAIN,
        ],  # fmt: skip
        "evaluate": [*cli, "evaluate", "--recordings", str(lift), "--no-progress"],
        "adapt": [
            *cli,
            "adapt",
            "--recordings",
            str(lift),
            "--out",
            str(out / "a"),
            "--epochs",
            "1",
            "--folds",
            "3",
            "--no-progress",
        ],  # fmt: skip
        "studies grasp adaptation": [
            sys.executable,
            "-m",
            "studies",
            "grasp",
            "adaptation",
            "--recordings",
            str(lift),
            "--out",
            str(out / "s"),
            "--epochs",
            "1",
            "--workers",
            "2",
            "--no-progress",
        ],  # fmt: skip
    }


def _parents() -> dict[int, int]:
    """pid -> parent pid of every process alive (zombies, already ended, left out)."""
    out = {}
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            stat = (entry / "stat").read_text()
        except OSError:
            continue
        state, ppid = stat.rsplit(")", 1)[1].split()[:2]
        if state != "Z":
            out[int(entry.name)] = int(ppid)
    return out


def _descendants(pid: int) -> set[int]:
    parents, found, frontier = _parents(), set(), {pid}
    while frontier:
        frontier = {p for p, pp in parents.items() if pp in frontier} - found
        found |= frontier
    return found


def _alive(pids: set[int]) -> set[int]:
    return pids & set(_parents())


def _run_until_workers(args: list[str], env: dict, tmp_path: Path) -> tuple[subprocess.Popen, set[int]]:
    """Start the command and return as soon as it has worker processes (their pids)."""
    proc = subprocess.Popen(
        args,
        env=env,
        cwd=Path(__file__).resolve().parents[1],
        stdout=subprocess.DEVNULL,
        stderr=(tmp_path / "stderr").open("w"),
        start_new_session=True,  # its own process group, as a command started at a terminal
        preexec_fn=terminal_sigint,  # and Ctrl-C's default action, whatever the test run inherited
    )
    deadline = time.monotonic() + 180
    while time.monotonic() < deadline and proc.poll() is None:
        kids = _descendants(proc.pid)
        if kids:
            return proc, kids
        time.sleep(0.005)
    proc.kill()
    pytest.fail(f"{args[3]}: no worker process seen (exit {proc.poll()}): {(tmp_path / 'stderr').read_text()}")


def terminal_sigint() -> None:
    """In a child before it runs: SIGINT's default action, as a terminal's foreground job has it. A test
    run started in the background of a script inherits SIGINT ignored, and a Python started so never
    raises KeyboardInterrupt (a command a user starts at a terminal always can)."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def _gone_within(pids: set[int], seconds: float) -> set[int]:
    deadline = time.monotonic() + seconds
    while _alive(pids) and time.monotonic() < deadline:
        time.sleep(0.05)
    return _alive(pids)


@pytest.fixture(scope="module")
def commands(grasp_recordings, tmp_path_factory):
    lift = _lift_data(tmp_path_factory.mktemp("lift") / "lift")
    mine = _lift_data(tmp_path_factory.mktemp("mine") / "mine")  # frame folders of a sensor of one's own
    (mine / "sensor.json").write_text(
        json.dumps({"name": "mine", "output": "video", "fps": 30, "image_size": [48, 64]})
    )
    return lambda out: _commands(grasp_recordings, lift, mine, out)


def _env(tmp_path: Path) -> dict:
    return {**os.environ, "SLIPSENSE_CACHE": str(tmp_path / "cache"), "OMP_NUM_THREADS": "1"}


NAMES = list(_commands(Path("r"), Path("l"), Path("m"), Path("o")))


@pytest.mark.skipif(sys.platform != "linux", reason="reads /proc")
@pytest.mark.parametrize("name", NAMES)
def test_sigkill_mid_run_leaves_no_worker_behind(name, commands, tmp_path):
    proc, workers = _run_until_workers(commands(tmp_path)[name], _env(tmp_path), tmp_path)
    os.kill(proc.pid, signal.SIGKILL)
    assert proc.wait(10) == -signal.SIGKILL  # killed mid-run, not finished before the kill
    assert not _gone_within(workers, 5.0), f"{name}: workers {_alive(workers)} outlived their parent"


@pytest.mark.skipif(sys.platform != "linux", reason="reads /proc")
@pytest.mark.parametrize("name", NAMES)
def test_ctrl_c_ends_everything_with_one_line(name, commands, tmp_path):
    proc, workers = _run_until_workers(commands(tmp_path)[name], _env(tmp_path), tmp_path)
    os.killpg(proc.pid, signal.SIGINT)  # as a terminal does: to the whole foreground group
    sent = time.monotonic()
    code = proc.wait(30)
    assert time.monotonic() - sent < 3.0, f"{name}: {time.monotonic() - sent:.1f} s to stop after Ctrl-C"
    text = (tmp_path / "stderr").read_text()  # the command's and its workers' (they share it)
    assert code == 130, (code, text)
    assert "Traceback" not in text and "KeyboardInterrupt" not in text, text
    assert text.count("interrupted: ") == 1 and text.splitlines()[-1].startswith("interrupted: "), text
    assert not _gone_within(workers, 5.0), f"{name}: workers {_alive(workers)} outlived Ctrl-C"
