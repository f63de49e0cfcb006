"""`slipsense record`: grasps captured into the recordings layout, started and stopped by command or by
contact, read back by every command; a grasp cut short leaves no video that looks whole."""

from __future__ import annotations

import cv2
import numpy as np
from typer.testing import CliRunner

from slipsense.cli import app
from slipsense.recordings.folders import find_recordings
from slipsense.recordings.video import read_video
from slipsense.streaming.record import GraspWriter, record


def _frames(n: int, contacts: list[tuple[int, int]], seed: int = 0) -> list[np.ndarray]:
    """48 x 64 frames of a gel at rest, with a pressed square during each (first, last) contact."""
    rng = np.random.default_rng(seed)
    out = []
    for t in range(n):
        f = np.full((48, 64, 3), 110, np.uint8) + rng.integers(0, 4, (48, 64, 3), dtype=np.uint8)
        if any(a <= t <= b for a, b in contacts):
            f[12:36, 16:40] = 200
        out.append(f)
    return out


def test_commands_start_stop_and_mark_a_grasp(tmp_path):
    frames = _frames(30, [])
    keys = {5: [""], 10: ["s"], 15: [""], 20: [""], 25: ["q"]}
    done = record(
        ([f, f] for f in frames), tmp_path, "cup", 25.0, commands=lambda i: keys.get(i, []), echo=lambda s: None
    )
    assert [p.name for p in done] == ["exp_num_1", "exp_num_2"]  # the second still open at "q": kept
    assert (done[0] / "slip.txt").exists() and not (done[1] / "slip.txt").exists()
    assert len(read_video(done[0] / "camera_0.avi", expected_size=None)) == 10  # frames 5..14
    recs = find_recordings(tmp_path)
    assert [(r.object, r.experiment, r.camera) for r in recs][:2] == [("cup", 1, "camera_0"), ("cup", 1, "camera_1")]
    again = record(([f, f] for f in frames), tmp_path, "cup", 25.0, commands=lambda i: [""] if i == 3 else [])
    assert again[0].name == "exp_num_3"  # recording again adds grasps


def test_contact_starts_and_stops_grasps_and_the_cli_writes_videos(tmp_path):
    video = tmp_path / "long.avi"
    w = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"XVID"), 25, (64, 48))
    for f in _frames(140, [(20, 50), (90, 120)]):
        w.write(f)
    w.release()
    res = CliRunner().invoke(
        app, ["record", str(video), "--out", str(tmp_path / "rec"), "--object", "mug", "--by-contact"]
    )
    assert res.exit_code == 0, res.output
    assert "2 grasp(s) recorded" in res.output
    assert "25 frames/s (the video's stated rate)" in res.output and "the gels start and stop" in res.output
    assert "Enter starts" not in res.output  # no key starts a grasp here
    for k in (1, 2):  # numbered from 1, as the shared recordings are
        n = len(read_video(tmp_path / "rec" / "mug" / f"exp_num_{k}" / "camera_0.avi", expected_size=None))
        assert 45 <= n <= 60, n  # the 31 frames of contact, 20 before them (pre-roll), 5 after (the stop rule)
    res = CliRunner().invoke(app, ["record", str(video), "--out", str(tmp_path / "rec"), "--object", "a b"])
    assert res.exit_code == 2 and "object name" in res.output


def test_a_recorded_run_that_slipped_gives_grasps_labelled_slipped(tmp_path):
    """A run folder standing in for the cameras, labelled slipped (its slip.txt): the grasp cut from
    it by contact is labelled slipped, as the line printed for it says."""
    run = tmp_path / "src" / "mug" / "exp_num_4"
    run.mkdir(parents=True)
    for cam in ("camera_0", "camera_2"):
        w = cv2.VideoWriter(str(run / f"{cam}.avi"), cv2.VideoWriter_fourcc(*"XVID"), 25, (64, 48))
        for f in _frames(90, [(20, 60)]):
            w.write(f)
        w.release()
    (run / "slip.txt").write_text("")
    out = tmp_path / "rec"
    res = CliRunner().invoke(app, ["record", str(run), "--out", str(out), "--object", "mug", "--by-contact"])
    assert res.exit_code == 0, res.output
    assert "the source is labelled slipped" in res.output and "(slipped)" in res.output
    recs = find_recordings(out)
    assert len(recs) == 2 and all(r.slipped for r in recs)
    (run / "slip.txt").unlink()  # the same run labelled held gives a held grasp
    res = CliRunner().invoke(app, ["record", str(run), "--out", str(out), "--object", "cup", "--by-contact"])
    assert res.exit_code == 0 and "(held)" in res.output, res.output
    assert not any(r.slipped for r in find_recordings(out) if r.object == "cup")


def test_a_grasp_cut_short_leaves_only_a_partial_file(tmp_path):
    writer = GraspWriter(tmp_path / "cup" / "exp_num_0", 1, 25.0)
    for f in _frames(5, []):
        writer.add([f])
    assert (tmp_path / "cup" / ".exp_num_0.partial" / "camera_0.avi").is_file()  # killed here
    assert not (tmp_path / "cup" / "exp_num_0").exists()  # nothing any command reads
    from slipsense.streaming.record import next_grasp_folder

    assert next_grasp_folder(tmp_path, "cup").name == "exp_num_1"  # the cut grasp keeps its number
