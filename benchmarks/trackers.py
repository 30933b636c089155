"""Tracker benchmark: milliseconds per frame on 1280x720 frames and mean IoU on the real
sequences in ../shared/data (issue 7), in one command:

    python benchmarks/trackers.py [--trackers kcf,vittrack,nanotrack] [--no-opencv] [--frames 60]
                                  [--synthetic 20 --synthetic-frames 300]

Timing: each tracker runs on the UAV123_10fps sequences (real 1280x720 frames, decoded once
beforehand, JPEG decoding excluded); the figure is the median per-frame time of ``track``.
Baseline measured in the same run: ``cv2.TrackerVit`` / ``cv2.TrackerNano`` on the same frames
(``--opencv``, on by default when the models are present), printed as a ratio; for the parity
column our trackers reproduce the installed OpenCV's release (``opencv_port``, 5.0 or 5.1).
Accuracy: mean IoU against the ground truth per real sequence, one pass from the first frame.
``--synthetic N``: also the default synthetic suite (``mata_eval.data.synth.suite_specs``, 1280x720):
per tracker, how many sequences it *holds* (success rate, IoU > 0.5 over the frames where the
target is visible, of at least 0.5) and the mean IoU over visible frames.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import cv2
import numpy as np

REPO = Path(__file__).resolve().parents[1]
SEQUENCES = ("uav123_10fps/wakeboard7", "uav123_10fps/wakeboard10", "vot15_bag", "otb_Couple")


def shared_data_dir() -> Path:
    return Path(os.environ.get("MATA_SHARED_DATA", REPO.parent / "shared" / "data"))


def load_groundtruth(folder: Path) -> np.ndarray:
    """(N, 4) x, y, w, h: comma or tab separated rects, or 8-value VOT polygons (min/max box)."""
    name = "groundtruth_rect.txt" if (folder / "groundtruth_rect.txt").is_file() else "groundtruth.txt"
    rows = []
    for line in (folder / name).read_text().splitlines():
        if line.strip():
            rows.append([float(v) for v in line.replace("\t", ",").replace(" ", ",").split(",") if v])
    a = np.array(rows, dtype=float)
    if a.shape[1] == 8:
        xs, ys = a[:, 0::2], a[:, 1::2]
        a = np.stack([xs.min(1), ys.min(1), xs.max(1) - xs.min(1), ys.max(1) - ys.min(1)], axis=1)
    return a


def load_sequence(folder: Path, limit: int | None = None) -> tuple[list[np.ndarray], np.ndarray]:
    """Decoded BGR frames (sorted image files under img/ or imgs/) and the ground truth."""
    gt = load_groundtruth(folder)
    img_dir = next(d for d in (folder / "img", folder / "imgs", folder) if d.is_dir() and any(d.glob("*.jpg")))
    paths = sorted(img_dir.glob("*.jpg"))[: len(gt)]
    if limit:
        paths = paths[:limit]
    frames = [cv2.imread(str(p), cv2.IMREAD_COLOR) for p in paths]
    return frames, gt[: len(frames)]


def iou(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise IoU of (N, 4) x, y, w, h boxes."""
    x1 = np.maximum(a[:, 0], b[:, 0])
    y1 = np.maximum(a[:, 1], b[:, 1])
    x2 = np.minimum(a[:, 0] + a[:, 2], b[:, 0] + b[:, 2])
    y2 = np.minimum(a[:, 1] + a[:, 3], b[:, 1] + b[:, 3])
    inter = np.clip(x2 - x1, 0, None) * np.clip(y2 - y1, 0, None)
    union = a[:, 2] * a[:, 3] + b[:, 2] * b[:, 3] - inter
    return np.where(union > 0, inter / np.maximum(union, 1e-12), 0.0)


def run_ours(tracker, frames, init: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Boxes (N, 4), confidences (N,), per-frame ms (N-1,) of a mata-eval tracker."""
    from mata_eval.types import Box

    tracker.initialize(frames[0], Box.from_array(init))
    boxes, conf, ms = [np.asarray(init, float)], [1.0], []
    for f in frames[1:]:
        t0 = time.perf_counter()
        out = tracker.track(f)
        ms.append(1e3 * (time.perf_counter() - t0))
        boxes.append(out.box.as_array())
        conf.append(out.confidence)
    return np.array(boxes), np.array(conf), np.array(ms)


def run_opencv(tracker, frames, init: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Boxes (N, 4) and per-frame ms of a cv2 tracker; a failed update holds the last box."""
    tracker.init(frames[0], tuple(int(v) for v in init))
    boxes, ms, last = [np.asarray(init, float)], [], np.asarray(init, float)
    for f in frames[1:]:
        t0 = time.perf_counter()
        ok, box = tracker.update(f)
        ms.append(1e3 * (time.perf_counter() - t0))
        if ok:
            last = np.asarray(box, float)
        boxes.append(last)
    return np.array(boxes), np.array(ms)


def make_ours(name: str, opencv_port: str = "5.0"):
    from mata_eval_plugins.trackers import kcf, nanotrack, vittrack

    if name == "kcf":
        return kcf.KCFTracker()
    cls = {"vittrack": vittrack.VitTrack, "nanotrack": nanotrack.NanoTrack}[name]
    return cls(cls.Params(opencv_port=opencv_port))


def make_opencv(name: str):
    from mata_eval_plugins.trackers.model_files import resolve_model

    if name == "vittrack":
        params = cv2.TrackerVit_Params()
        params.net = str(resolve_model("vittrack", None))
        return cv2.TrackerVit_create(params)
    if name == "nanotrack":
        params = cv2.TrackerNano_Params()
        params.backbone = str(resolve_model("nanotrack_backbone", None))
        params.neckhead = str(resolve_model("nanotrack_head", None))
        return cv2.TrackerNano_create(params)
    return None


def synthetic_scores(names: list[str], n: int, n_frames: int) -> dict[str, list[tuple[str, float, float]]]:
    """Per tracker: (sequence, success rate, mean IoU) over frames with a visible target."""
    from mata_eval.data.synth import render_sequence, suite_specs

    scores: dict[str, list[tuple[str, float, float]]] = {name: [] for name in names}
    for spec in suite_specs(n, n_frames=n_frames):
        frames, gt, _, _ = render_sequence(spec)
        visible = np.all(np.isfinite(gt), axis=1)
        visible[0] = False
        for name in names:
            boxes, _, _ = run_ours(make_ours(name), frames, gt[0])
            ious = iou(boxes[visible], gt[visible])
            scores[name].append((spec.name, float((ious > 0.5).mean()), float(ious.mean())))
        del frames
    return scores


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trackers", default="kcf,vittrack,nanotrack")
    ap.add_argument("--no-opencv", action="store_true", help="skip the cv2.TrackerVit/Nano baseline")
    ap.add_argument("--frames", type=int, default=0, help="limit frames per sequence (0 = all)")
    ap.add_argument("--synthetic", type=int, default=0, help="also score N synthetic sequences")
    ap.add_argument("--synthetic-frames", type=int, default=300)
    args = ap.parse_args(argv)
    data = shared_data_dir()
    if not (data / "sequences").is_dir():
        print(f"shared data not found at {data} (set MATA_SHARED_DATA)", file=sys.stderr)
        return 2
    cv2.setNumThreads(1)
    from mata_eval_plugins.trackers.vittrack import installed_opencv_port   # the parity column's port

    seqs = {s.split("/")[-1]: load_sequence(data / "sequences" / s, args.frames or None) for s in SEQUENCES}
    names = [n.strip() for n in args.trackers.split(",") if n.strip()]
    rows = []
    for name in names:
        line = {"tracker": name}
        ms_720 = []
        for seq, (frames, gt) in seqs.items():
            boxes, conf, ms = run_ours(make_ours(name, installed_opencv_port()), frames, gt[0])
            line[seq] = float(iou(boxes, gt).mean())
            if frames[0].shape[:2] == (720, 1280):
                ms_720.append(ms)
            ref = None if args.no_opencv else make_opencv(name)
            if ref is not None:
                ref_boxes, ref_ms = run_opencv(ref, frames, gt[0])
                line[f"{seq}:cv2"] = float(iou(ref_boxes, gt).mean())
                line[f"{seq}:parity"] = float(iou(boxes, ref_boxes).mean())
                if frames[0].shape[:2] == (720, 1280):
                    line.setdefault("_ref_ms", []).append(ref_ms)
        line["ms"] = float(np.median(np.concatenate(ms_720)))
        if "_ref_ms" in line:
            line["cv2_ms"] = float(np.median(np.concatenate(line.pop("_ref_ms"))))
        rows.append(line)

    print("tracker    | ms/frame 1280x720 (median) | mean IoU per real sequence (ours [cv2] {parity IoU ours-vs-cv2})")
    for line in rows:
        timing = f"{line['ms']:6.2f}"
        if "cv2_ms" in line:
            timing += f" (cv2 {line['cv2_ms']:.2f}, ratio {line['ms'] / line['cv2_ms']:.2f})"
        parts = []
        for seq in seqs:
            text = f"{seq} {line[seq]:.3f}"
            if f"{seq}:cv2" in line:
                text += f" [{line[f'{seq}:cv2']:.3f}] {{{line[f'{seq}:parity']:.3f}}}"
            parts.append(text)
        print(f"{line['tracker']:<10} | {timing:<26} | " + ", ".join(parts))
    if args.synthetic:
        for name, rows_syn in synthetic_scores(names, args.synthetic, args.synthetic_frames).items():
            held = sum(sr >= 0.5 for _, sr, _ in rows_syn)
            print(f"{name:<10} synthetic: holds {held}/{len(rows_syn)} sequences, mean IoU "
                  f"{np.mean([m for _, _, m in rows_syn]):.3f}; " +
                  ", ".join(f"{seq} {sr:.2f}/{m:.2f}" for seq, sr, m in rows_syn))
    if "kcf" in [r["tracker"] for r in rows] and any("cv2_ms" in r for r in rows):
        kcf_ms = next(r["ms"] for r in rows if r["tracker"] == "kcf")
        ref = next(r["cv2_ms"] for r in rows if "cv2_ms" in r)
        print(f"kcf vs cv2 DNN tracker baseline: {kcf_ms / ref:.2f}x the time per frame")
    return 0


if __name__ == "__main__":
    sys.exit(main())
