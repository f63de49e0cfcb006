"""Worker processes (slipsense.parallel.run_jobs) next to a live ONNX Runtime detector."""

from __future__ import annotations

import subprocess
import sys
import textwrap

import pytest

SCRIPT = textwrap.dedent(
    """
    import gc
    import numpy as np
    from slipsense.models import build
    from slipsense.parallel import run_jobs
    from slipsense.streaming.detector import SlipDetector

    def job(shared, k, tick):
        gc.collect()  # a worker collecting what it inherited
        return k * shared

    if __name__ == "__main__":
        import torch

        torch.set_num_threads(2)  # ONNX Runtime takes as many: a session with a pool of threads
        gc.disable()  # the detector's cycle stays uncollected until the fork, as it may in a user's script
        model = build("motionnet", width=4, features=8, temporal=8, lags=[1, 2], dilations=[1], image_size=[12, 16])
        det = SlipDetector(model, backend="onnx", sensors=2)
        det.push(np.zeros((48, 64, 3), np.uint8), np.zeros((48, 64, 3), np.uint8))
        det.cycle = det  # garbage only a collection frees
        del det
        print(run_jobs(job, [1, 2, 3, 4], shared=10, workers=2, progress=False))
    """
)


def test_workers_forked_beside_a_dropped_onnx_detector_finish(tmp_path):
    pytest.importorskip("onnxruntime")
    script = tmp_path / "fork_after_onnx.py"
    script.write_text(SCRIPT)
    done = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip().endswith("[10, 20, 30, 40]")


@pytest.mark.skipif(sys.platform != "linux", reason="reads /proc")
@pytest.mark.parametrize("after_s", [0.0, 1.5])
def test_ctrl_c_ends_jobs_under_way_at_once(tmp_path, after_s):
    """Ctrl-C (SIGINT to the process group) while workers run long jobs: run_jobs raises
    KeyboardInterrupt within 3 s and no worker is left, at once and with the jobs well under way
    (the workers used to be looked up after the pool had forgotten them: each ran its job to the end)."""
    import os
    import signal
    import time

    script = tmp_path / "long.py"
    script.write_text(
        textwrap.dedent(
            """
            import sys, time
            from slipsense.parallel import run_jobs

            def job(shared, seconds, tick):
                time.sleep(seconds)

            if __name__ == "__main__":
                try:
                    run_jobs(job, [60.0] * 4, None, workers=2, progress=False)
                except KeyboardInterrupt:
                    print("interrupted", flush=True)
                    sys.exit(130)
            """
        )
    )
    from tests.test_workers_end import terminal_sigint

    proc = subprocess.Popen(
        [sys.executable, str(script)],
        stdout=subprocess.PIPE,
        text=True,
        start_new_session=True,
        preexec_fn=terminal_sigint,
    )
    deadline = time.monotonic() + 60
    kids: set[int] = set()
    while not kids and time.monotonic() < deadline:
        kids = {int(p) for p in _children(proc.pid)}
        time.sleep(0.01)
    assert kids, "no worker started"
    time.sleep(after_s)
    os.killpg(proc.pid, signal.SIGINT)
    sent = time.monotonic()
    assert proc.wait(30) == 130 and time.monotonic() - sent < 3.0, time.monotonic() - sent
    assert proc.stdout.read().strip() == "interrupted"
    assert not [k for k in kids if os.path.exists(f"/proc/{k}") and _state(k) != "Z"], "workers left behind"


def _children(pid: int) -> list[str]:
    path = f"/proc/{pid}/task/{pid}/children"
    try:
        return open(path).read().split()
    except OSError:
        return []


def _state(pid: int) -> str:
    try:
        return open(f"/proc/{pid}/stat").read().rsplit(")", 1)[1].split()[0]
    except OSError:
        return "Z"


def _started(shared, job, tick):
    import time

    started = time.monotonic()
    time.sleep(shared[job] / 250)  # as long as its weight says (0.3-0.4 s: a slow fork stays well inside)
    return started, job


def test_longest_first_starts_the_heaviest_jobs_first_and_keeps_job_order():
    from slipsense.parallel import run_jobs

    jobs, weights = ["a", "b", "c", "d"], [110, 71, 68, 81]
    kept = run_jobs(_started, jobs, dict(zip(jobs, weights)), 2, weights, progress=False, longest_first=True)
    assert [job for _, job in kept] == jobs  # results in job order
    started = [job for _, job in sorted(kept)]
    assert started[:2] in (["a", "d"], ["d", "a"]) and started[2:] == ["b", "c"]
