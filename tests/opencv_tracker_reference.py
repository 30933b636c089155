"""Writes tests/data/opencv50_trackers.npz: cv2.TrackerVit's and cv2.TrackerNano's boxes (and
TrackerVit's tracking scores) from OpenCV 5.0, the release whose trackers the default
``opencv_port: "5.0"`` reproduces, so that parity with it stays tested where a newer OpenCV is
installed (5.1 changed both trackers; tests/test_trackers_onnx.py). Run once, in a venv with
``pip install opencv-python-headless==5.0.0.93``:

    MATA_SHARED_DATA=../shared/data python tests/opencv_tracker_reference.py
"""

from __future__ import annotations

import os
from pathlib import Path

import cv2
import numpy as np

from test_trackers_onnx import PARITY_SEQUENCES, cv2_nano, cv2_vit, load_sequence

OUT = Path(__file__).parent / "data" / "opencv50_trackers.npz"


def main() -> None:
    if cv2.__version__.split(".")[:2] != ["5", "0"]:
        raise SystemExit(f"needs OpenCV 5.0 (pip install opencv-python-headless==5.0.0.93), found {cv2.__version__}")
    shared = Path(os.environ.get("MATA_SHARED_DATA", Path(__file__).parents[2] / "shared" / "data"))
    arrays = {}
    for name, make in (("vittrack", cv2_vit), ("nanotrack", cv2_nano)):
        for seq, limit in PARITY_SEQUENCES[name]:
            frames, gt = load_sequence(shared / "sequences" / seq, limit)
            tracker = make(shared)
            tracker.init(frames[0], tuple(int(v) for v in gt[0]))
            boxes, scores, last = [], [], tuple(int(v) for v in gt[0])
            for f in frames[1:]:
                ok, box = tracker.update(f)
                last = tuple(box) if ok else last
                boxes.append(last)
                scores.append(tracker.getTrackingScore())
            arrays[f"{name}/{seq}/boxes"] = np.array(boxes, np.int32)
            arrays[f"{name}/{seq}/scores"] = np.array(scores, np.float32)
    np.savez_compressed(OUT, opencv=cv2.__version__, **arrays)
    print(f"wrote {OUT} (OpenCV {cv2.__version__}, {len(arrays) // 2} sequences)")


if __name__ == "__main__":
    main()
