"""Generation speed of the default synthetic suite (20 x 300 frames, 1280x720, JPEG, 2 workers).

Target: under 60 s on 2 cores. Baseline measured in the same run: the bare I/O floor, i.e.
one ground warp (cv2.warpPerspective of the pre-rendered texture) plus one JPEG write per frame
for the same number of frames, in one process - the cost no renderer of this design can avoid.

    python benchmarks/synth_speed.py [--n-sequences 20] [--n-frames 300] [--jobs 2]
"""

from __future__ import annotations

import argparse
import resource
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

from mata_eval.data import synth


def io_floor(n_frames: int, width: int, height: int, out: Path) -> tuple[float, float]:
    """Wall and CPU seconds for n_frames of (one ground warp + one JPEG write), one process."""
    cv2.setNumThreads(1)
    ground = synth.ground_texture(0, int(round(4096 * width / 1280)))
    G = np.array([[1.0, 0.05, -1000], [-0.05, 1.0, -1000], [0, 0, 1]])
    t0, c0 = time.perf_counter(), time.process_time()
    for k in range(n_frames):
        img = cv2.warpPerspective(ground, G, (width, height), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
        cv2.imwrite(str(out / f"{k % 50:06d}.jpg"), img, [cv2.IMWRITE_JPEG_QUALITY, 90])
    return time.perf_counter() - t0, time.process_time() - c0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--n-sequences", type=int, default=20)
    ap.add_argument("--n-frames", type=int, default=300)
    ap.add_argument("--width", type=int, default=1280)
    ap.add_argument("--height", type=int, default=720)
    ap.add_argument("--jobs", type=int, default=2)
    a = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        t0 = time.perf_counter()
        c0 = resource.getrusage(resource.RUSAGE_CHILDREN)
        synth.write_suite(tmp / "suite", a.n_sequences, a.n_frames, a.width, a.height, seed=0, jobs=a.jobs)
        t_suite = time.perf_counter() - t0
        c1 = resource.getrusage(resource.RUSAGE_CHILDREN)
        cpu_suite = (c1.ru_utime + c1.ru_stime) - (c0.ru_utime + c0.ru_stime)
        (tmp / "floor").mkdir()
        n_floor = min(a.n_sequences * a.n_frames, 600)
        wall, cpu = io_floor(n_floor, a.width, a.height, tmp / "floor")
        t_floor = wall * (a.n_sequences * a.n_frames / n_floor) / a.jobs
        cpu_floor = cpu * (a.n_sequences * a.n_frames / n_floor)
    frames = a.n_sequences * a.n_frames
    print(f"suite {a.n_sequences} x {a.n_frames} frames at {a.width}x{a.height}, {a.jobs} workers: "
          f"{t_suite:.1f} s ({1000 * t_suite / frames:.2f} ms/frame wall){'  OK (< 60 s)' if t_suite < 60 else '  SLOW (>= 60 s)'}")
    print(f"I/O floor (warp + JPEG write per frame, same frame count over {a.jobs} workers): {t_floor:.1f} s")
    print(f"ratio suite / floor: {t_suite / t_floor:.2f}x (wall), {cpu_suite / cpu_floor:.2f}x (CPU time)")
    print(f"CPU time: suite {cpu_suite:.1f} s in the workers -> {cpu_suite / a.jobs:.1f} s on {a.jobs} idle cores; "
          f"floor {cpu_floor:.1f} s")


if __name__ == "__main__":
    main()
