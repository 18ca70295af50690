"""Record a motion dataset's clamp poses late: the clamp stream of an independent motion dataset
(`independent_motion.py`) shifted by whole capture frames against the markers, the way two
capture streams on two clocks come out of step.

    python record_clamps_late.py SRC DST --frames 2

DST is a copy of SRC whose `clamps.csv` row at t_n holds the pose the clamp had at t_(n-k)
(the first k rows hold the pose at t = 0: the run starts from rest, so that is the pose the clamp
had before the record began); the markers are untouched. A simulation driven by the recorded clamp
therefore lags the markers by k frames: in `palpate_motion::time_offset`'s convention the
observation of step n is the simulated state of step n + k, a time offset of -k frames
(-k dt). `truth.json` gains an "injected" entry saying so.
"""

import argparse
import csv
import json
import os
import shutil


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("src")
    ap.add_argument("dst")
    ap.add_argument("--frames", type=int, required=True, help="frames the clamp record lags (k >= 1)")
    a = ap.parse_args()
    if a.frames < 1:
        ap.error("--frames must be at least 1")
    shutil.copytree(a.src, a.dst)
    with open(os.path.join(a.src, "clamps.csv")) as fh:
        rows = list(csv.reader(fh))
    head, body = rows[0], rows[1:]
    with open(os.path.join(a.src, "truth.json")) as fh:
        truth = json.load(fh)
    shifted = []
    for n, row in enumerate(body):
        src = body[max(n - a.frames, 0)]
        shifted.append([row[0], row[1]] + src[2:])
    with open(os.path.join(a.dst, "clamps.csv"), "w", newline="") as fh:
        fh.write(",".join(head) + "\n")
        for r in shifted:
            fh.write(",".join(r) + "\n")
    truth["injected"] = {
        "effect": "time-offset",
        "how": "clamps.csv recorded late (tests/generators/record_clamps_late.py)",
        "clamp_record_late_frames": a.frames,
        "time_offset_steps": -a.frames,
        "time_offset_s": -a.frames * truth["dt"],
    }
    with open(os.path.join(a.dst, "truth.json"), "w") as fh:
        json.dump(truth, fh, indent=1)
    print(f"wrote {a.dst}: clamps.csv {a.frames} frames late (time offset {-a.frames * truth['dt']} s)")


if __name__ == "__main__":
    main()
