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
