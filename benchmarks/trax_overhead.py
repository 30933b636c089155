"""What running a tracker out of process over TraX costs per frame (issue 21), in one command:

    python benchmarks/trax_overhead.py [--tracker nanotrack|vittrack] [--frames 60]

The shipped plugin runs in process (the baseline, measured in the same run) and behind TraX in a
separate Python process (``tests/trax_servers/plugin_server.py``), frame by frame, interleaved, on
the real 1280x720 DTB70 ``MountainBike6`` frames of ../shared/data (decoded once beforehand).
Printed: the median ``track`` milliseconds of each, their difference (the cost of the protocol:
writing the frame as a BMP, the tracker reading it back, the pipe round trip) and the ratio
(in-process ms / TraX ms), the process CPU seconds of this side, and whether the boxes agree.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
from pathlib import Path

import cv2
import numpy as np

REPO = Path(__file__).resolve().parents[1]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--tracker", choices=["nanotrack", "vittrack"], default="nanotrack")
    ap.add_argument("--frames", type=int, default=60)
    args = ap.parse_args()
    shared = Path(os.environ.get("MATA_SHARED_DATA", REPO.parent / "shared" / "data"))
    seq = shared / "sequences" / "aerial30" / "MountainBike6"
    if not seq.is_dir():
        sys.exit(f"needs the real frames in {seq} (set MATA_SHARED_DATA)")

    from mata_eval.core.registry import load_registry
    from mata_eval.types import Box
    from mata_eval_plugins.trackers.trax import TraxTracker

    models = shared / "models"
    plugin_args = {"nanotrack": [f"backbone={models / 'nanotrack/v2/nanotrack_backbone_sim.onnx'}",
                                 f"head={models / 'nanotrack/v2/nanotrack_head_sim.onnx'}"],
                   "vittrack": [f"model={models / 'vittrack/object_tracking_vittrack_2023sep.onnx'}"]}[args.tracker]
    frames = [cv2.imread(str(p)) for p in sorted((seq / "img").glob("*.jpg"))[: args.frames]]
    x, y, w, h = (float(v) for v in (seq / "groundtruth_rect.txt").read_text().split("\n")[0].split(","))
    cls = load_registry().get("tracker", args.tracker).cls
    local = cls(cls.Params(**dict(a.split("=", 1) for a in plugin_args)))
    remote = TraxTracker(TraxTracker.Params(
        command=[sys.executable, str(REPO / "tests/trax_servers/plugin_server.py"), args.tracker, *plugin_args],
        env={"OMP_NUM_THREADS": "1"}))
    cpu0 = time.process_time()
    try:
        for t in (local, remote):
            t.initialize(frames[0], Box(x, y, w, h))
        ms = {"in process": [], "TraX": []}
        same = True
        for img in frames[1:]:
            t0 = time.perf_counter()
            a = local.track(img)
            t1 = time.perf_counter()
            b = remote.track(img)
            t2 = time.perf_counter()
            ms["in process"].append((t1 - t0) * 1e3)
            ms["TraX"].append((t2 - t1) * 1e3)
            same &= bool(np.array_equal(a.box.as_array(), b.box.as_array()))
    finally:
        remote.close()
    med = {k: statistics.median(v[3:]) for k, v in ms.items()}
    print(f"{args.tracker}, {len(frames) - 1} frames of 1280x720, median track() ms after 3 warm-up frames:")
    for k, v in med.items():
        print(f"  {k:<11} {v:7.1f} ms")
    print(f"  TraX cost   {med['TraX'] - med['in process']:7.1f} ms per frame; ratio in-process/TraX = "
          f"{med['in process'] / med['TraX']:.2f}")
    print(f"  boxes identical on every frame: {same}; CPU seconds of this process: {time.process_time() - cpu0:.1f}")


if __name__ == "__main__":
    main()
