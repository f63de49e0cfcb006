"""Print, for each slip run, contact strength and motion of both sensors in the 30 frames before
the moment of slip (every other frame), to see what precedes a slip in the recordings.

    .venv/bin/python scripts/inspect_slips.py [--limit N]
"""

import argparse

import numpy as np

from slipsense import config
from slipsense.recordings.folders import find_recordings
from slipsense.recordings.labels import label_recordings
from slipsense.recordings.runs import load_runs

parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
parser.add_argument("--limit", type=int, default=None)
parser.add_argument("--overrides", default="configs/gelsight-label-overrides.csv")
args = parser.parse_args()
recs = find_recordings(config.gelsight_recordings())
labels = label_recordings(recs, overrides=args.overrides, progress=False)
runs = [r for r in load_runs(recs, labels, (30, 40), progress=False) if r.moment_of_slip is not None]
np.set_printoptions(linewidth=250, precision=1, suppress=True)
for r in runs[: args.limit]:
    m = r.moment_of_slip
    motion = np.abs(np.diff(r.gray.astype(np.float32), axis=1, prepend=r.gray[:, :1])).mean(axis=(2, 3))
    a = max(0, m - 30)
    print(f"{r.object} {r.experiment}: moment {m} of {r.n_frames} frames; frames {a}..{m + 2} every other")
    for s in range(len(r.contact)):
        print(f"  contact {r.cameras[s]}", r.contact[s, a : m + 3 : 2])
        print(f"  motion  {r.cameras[s]}", motion[s, a : m + 3 : 2])
