"""What latency costs on each dataset: the perfect-tracker oracle and the motion statistics of
UAV123, DTB70, UAVDT (ground truth from ../shared/data/annotations) and the synthetic suite, side
by side, each with its ratio to UAV123 (issue 15; docs/decisions/data.md "Motion statistics").

    python benchmarks/oracle.py [--n-sequences 20] [--n-frames 300] [--width 1280] [--height 720]
                                [--seed 0] [--motion uav123 legacy] [--profile default] [--no-camera]

Oracle: a tracker that returns the ground-truth box, under EOP at 30 Hz with one frame of
latency and at 10 Hz with one period (paper section 3.1), through the project's scheduler, scored
with its NT2F (metric profile ``--profile``: ``default`` is eq. nt2f, ``T_f / N`` over every frame;
``nt2f-valid`` counts only frames with ground truth, the reading issue 15's figures used). Target: the default synthetic suite (``--motion uav123``) within 10 % of UAV123 on
the 10 Hz NT2F and on the motion statistics. Camera motion: grid-LK homographies (block B,
``grid_lk`` defaults) of the real sequences in ../shared/data/sequences, the exact homographies
of the synthetic suite. The synthetic suite is rendered in memory (nothing written); its exact
ground truth is put on UAV123's annotation grid (whole pixels of a 1280x720 frame, at any render
size) before it is scored and measured, so that both carry the same quantisation noise.
"""

from __future__ import annotations

import argparse
import os
import resource
import time
from pathlib import Path

import cv2
import numpy as np

from mata_eval.core.registry import load_registry
from mata_eval.core.sequence import Sequence
from mata_eval.data.datasets.dtb70 import DTB70
from mata_eval.data.datasets.uav123 import UAV123
from mata_eval.data.datasets.uavdt import UAVDT
from mata_eval.data.synth import suite_specs
from mata_eval.data.synth.render import render
from mata_eval.score.metrics import summarize
from mata_eval.score.motion_stats import (camera_motion, camera_rates, estimate_homographies, on_annotation_grid,
                                          target_motion)
from mata_eval.score.oracle import oracle_scores

#: Real footage for the camera statistics: (folder under sequences/, fps).
REAL_FOOTAGE = (("aerial30/MountainBike6", 30.0), ("aerial30/Surfing06", 30.0), ("aerial30/S0310", 30.0),
                ("aerial30/S0601", 30.0), ("uav123_10fps/wakeboard7", 10.0), ("uav123_10fps/wakeboard10", 10.0))

COLUMNS = (  # (header, function of (nt2f30, nt2f10, TargetMotion))
    ("NT2F@30", lambda a, b, m: a),
    ("NT2F@10", lambda a, b, m: b),
    ("d1", lambda a, b, m: m.at(1).displacement_median),
    ("d3", lambda a, b, m: m.at(3).displacement_median),
    ("d10", lambda a, b, m: m.at(10).displacement_median),
    ("d3 p90", lambda a, b, m: m.at(3).displacement_p90),
    ("d10 p90", lambda a, b, m: m.at(10).displacement_p90),
    ("scale10", lambda a, b, m: m.at(10).scale_median),
    ("scale10 p90", lambda a, b, m: m.at(10).scale_p90),
    ("IoU3<.5", lambda a, b, m: m.at(3).iou_below_half),
)


def shared_data() -> Path:
    root = Path(os.environ.get("MATA_SHARED_DATA", Path(__file__).resolve().parents[1].parent / "shared" / "data"))
    if not (root / "annotations").is_dir():
        raise SystemExit(f"benchmarks/oracle.py: no annotations under {root}; set MATA_SHARED_DATA")
    return root


def real_datasets(root: Path) -> dict[str, list[Sequence]]:
    a = root / "annotations"
    return {
        "UAV123": UAV123(UAV123.Params(root=str(a), annotations=str(a / "UAV123"))).sequences(),
        "DTB70": DTB70(DTB70.Params(root=str(a), annotations=str(a / "DTB70"))).sequences(),
        "UAVDT": UAVDT(UAVDT.Params(root=str(a), annotations=str(a / "UAVDT"))).sequences(),
    }


def synthetic(args: argparse.Namespace, motion: str) -> tuple[list[Sequence], np.ndarray]:
    """The suite's ground truth (in memory, frames discarded) as UAV123's annotators would have
    written it (whole pixels of a 1280x720 frame: :func:`on_annotation_grid`), and its camera
    rates."""
    seqs, rates = [], []
    for sp in suite_specs(args.n_sequences, args.n_frames, args.width, args.height, args.seed, motion=motion):
        r = render(sp, lambda k, img: None)
        seqs.append(Sequence(sp.name, on_annotation_grid(r.groundtruth, sp.width), sp.fps))
        rates.append(camera_rates(r.homographies[1:], sp.width, sp.height, sp.fps))
    return seqs, rates


def row(seqs: list[Sequence], eop, profile: str) -> list[float]:
    n30 = summarize(oracle_scores(seqs, eop(eop.Params(tracker_hz=30)), profile)).nt2f
    n10 = summarize(oracle_scores(seqs, eop(eop.Params(tracker_hz=10)), profile)).nt2f
    motion = target_motion(s.groundtruth for s in seqs)
    return [f(n30, n10, motion) for _, f in COLUMNS]


def print_table(title: str, header: list[str], rows: dict[str, list[float]], ref: str | None) -> None:
    print(f"\n{title}")
    print(f"{'':<34}" + "".join(f"{h:>15}" for h in header))
    for name, vals in rows.items():
        cells = []
        for i, v in enumerate(vals):
            r = rows[ref][i] if ref else None
            cells.append(f"{v:.3f} ({v / r:.2f})" if r else f"{v:.3f}")
        print(f"{name:<34}" + "".join(f"{c:>15}" for c in cells))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--n-sequences", type=int, default=20)
    ap.add_argument("--n-frames", type=int, default=300)
    ap.add_argument("--width", type=int, default=1280)
    ap.add_argument("--height", type=int, default=720)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--motion", nargs="+", default=["uav123", "legacy"], help="synthetic camera models to compare")
    ap.add_argument("--profile", default="default", help="metric profile of the NT2F (default: eq. nt2f)")
    ap.add_argument("--no-camera", action="store_true", help="skip the camera statistics of real footage")
    args = ap.parse_args()
    t0, c0 = time.perf_counter(), time.process_time()
    eop = load_registry().get("protocol", "eop").cls
    root = shared_data()
    data = real_datasets(root)
    cams: dict[str, list[float]] = {}
    for motion in args.motion:
        seqs, rates = synthetic(args, motion)
        name = f"synthetic/{motion}"
        data[name] = seqs
        cams[f"{name} (true H)"] = rates
    rows = {name: row(seqs, eop, args.profile) for name, seqs in data.items()}
    print(f"perfect tracker under EOP (NT2F, profile {args.profile}) and target motion (medians unless p90; d = centre shift / "
          f"sqrt(wh) over 1, 3, 10 frames; scale = |log size ratio| over 10 frames); (ratio to UAV123). "
          f"Synthetic: {args.n_sequences} x {args.n_frames} frames, {args.width}x{args.height}, seed {args.seed}")
    print_table("datasets (ground truth)", [h for h, _ in COLUMNS], rows, "UAV123")

    cam_rows: dict[str, list[float]] = {}
    real_rates: list[np.ndarray] = []
    if not args.no_camera:
        lk = load_registry().get("egomotion", "grid_lk").cls
        for rel, fps in REAL_FOOTAGE:
            folder = root / "sequences" / rel
            files = sorted((folder / "img").glob("*.jpg")) or sorted(folder.glob("*.jpg"))
            if not files:
                continue
            h, w = cv2.imread(str(files[0])).shape[:2]
            rates = camera_rates(estimate_homographies((cv2.imread(str(f)) for f in files), lk()), w, h, fps)
            cam_rows[f"{rel.split('/')[-1]} ({fps:g} fps, LK)"] = _cam(camera_motion([rates], fps))
            real_rates.append(rates)
        if real_rates:
            cam_rows["real footage, pooled (LK)"] = _cam(camera_motion(real_rates, float("nan")))
    for name, rates in cams.items():
        cam_rows[name] = _cam(camera_motion(rates, 30.0))
    print_table("camera motion per second (median / p90): translation in image widths, rotation deg, "
                "zoom |log scale|, jerk in widths/s^2",
                ["transl", "transl p90", "rot", "rot p90", "zoom", "zoom p90", "jerk", "jerk p90"], cam_rows, None)
    if not args.no_camera:
        print("(MountainBike6 repeats about every other frame, hence its zero median translation and its jerk)")
    cpu = time.process_time() - c0 + _children_cpu()
    print(f"\n{time.perf_counter() - t0:.1f} s wall, {cpu:.1f} CPU-s")


def _cam(c) -> list[float]:
    return [c.translation_median, c.translation_p90, c.rotation_median, c.rotation_p90,
            c.zoom_median, c.zoom_p90, c.jerk_median, c.jerk_p90]


def _children_cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


if __name__ == "__main__":
    main()
