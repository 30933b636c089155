"""Block B: milliseconds per frame and accuracy of grid_lk against the feature-based peer
(BoT-SORT's camera-motion module) measured in the same run.

    python benchmarks/egomotion.py [--sequences 5] [--frames 30] [--threads 1]
        [--variant NAME:KEY=VALUE,...]...

Prints, per method (grid_lk; grid_lk with the forward-backward check; grid_lk with OpenCV's
21-pixel LK window; features; identity; each ``--variant``, grid_lk with those parameters, e.g.
``--variant ds3:downscale=3`` to weigh a cheaper setting against the default):
- ms per frame of ``estimate`` at 1280x720: median CPU time of the process (the figure used for
  the ratios: on a shared machine it does not count time spent waiting for a core) and median
  wall time; OpenCV limited to ``--threads`` threads; the methods run interleaved frame by frame,
  so load changes hit all of them alike; on the synthetic suite and on the real footage;
- mean corner-transfer error (px) against the exact inter-frame homographies of the synthetic
  suite (:mod:`mata_eval.data.synth`), over the frames where every method gives a valid motion, and
  the number of invalid motions;
- the photometric residual after warping (mean absolute grey difference between frame k and
  frame k-1 warped by the estimate, over the covered pixels) on wakeboard7 and wakeboard10 from
  ``../shared/data`` (skipped when absent);
then the ratios features / grid_lk (target: grid_lk >= 3x faster at an equal or smaller
transfer error).
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import cv2
import numpy as np

from mata_eval.data import synth
from mata_eval.params import build_params, parse_key_values
from mata_eval_plugins.egomotion import homography_covariance as hc
from mata_eval_plugins.egomotion.features import FeatureLK
from mata_eval_plugins.egomotion.grid_lk import GridLK
from mata_eval_plugins.egomotion.identity import IdentityMotion

REPO = Path(__file__).resolve().parents[1]
REAL = ("wakeboard7", "wakeboard10")


def methods(variants: dict[str, dict] | None = None) -> dict[str, object]:
    """The compared methods; ``variants``: more grid_lk ones, name -> parameters."""
    return {
        "grid_lk": GridLK(),
        "grid_lk+fb": GridLK(GridLK.Params(fb_threshold=1.0)),
        "grid_lk w21": GridLK(GridLK.Params(win_size=21)),
        "features": FeatureLK(),
        "identity": IdentityMotion(),
        **{name: GridLK(GridLK.Params(**kw)) for name, kw in (variants or {}).items()},
    }


def parse_variant(text: str) -> tuple[str, dict]:
    """``NAME:KEY=VALUE,KEY=VALUE`` (values in YAML: 3, 2.5, true) -> (NAME, parameters)."""
    name, sep, body = text.partition(":")
    if not (sep and name):
        raise SystemExit(f"--variant {text!r}: expected NAME:KEY=VALUE,...")
    try:
        kw = parse_key_values(item.strip() for item in body.split(","))
        build_params(GridLK.Params, kw)
    except ValueError as exc:
        raise SystemExit(f"--variant {text!r}: expected NAME:KEY=VALUE,... with grid_lk parameters ({exc})")
    return name, kw


def run_pairs(frames, names: list[str], variants: dict[str, dict] | None = None):
    """Run every method over the frames, interleaved; yields (k, {name: (Motion, cpu s, wall s)})."""
    ms = methods(variants)
    for m in ms.values():
        m.initialize(frames[0])
    for k in range(1, len(frames)):
        out = {}
        for name in names:
            c0, t0 = time.process_time(), time.perf_counter()
            mo = ms[name].estimate(frames[k])
            out[name] = (mo, time.process_time() - c0, time.perf_counter() - t0)
        yield k, out


def photometric_residual(prev: np.ndarray, cur: np.ndarray, Hm: np.ndarray) -> float:
    """Mean absolute grey difference between ``cur`` and ``prev`` warped by ``Hm`` (covered pixels)."""
    g0 = cv2.cvtColor(prev, cv2.COLOR_BGR2GRAY).astype(np.float32)
    g1 = cv2.cvtColor(cur, cv2.COLOR_BGR2GRAY).astype(np.float32)
    size = (g1.shape[1], g1.shape[0])
    warped = cv2.warpPerspective(g0, Hm, size)
    cover = cv2.warpPerspective(np.ones_like(g0), Hm, size, flags=cv2.INTER_NEAREST) > 0
    return float(np.mean(np.abs(warped - g1)[cover]))


def shared_data() -> Path:
    return Path(os.environ.get("MATA_SHARED_DATA", REPO.parent / "shared" / "data"))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sequences", type=int, default=5, help="synthetic sequences (one per scenario)")
    ap.add_argument("--frames", type=int, default=30, help="frames per synthetic sequence")
    ap.add_argument("--width", type=int, default=1280)
    ap.add_argument("--height", type=int, default=720)
    ap.add_argument("--seed", type=int, default=0, help="synthetic suite seed")
    ap.add_argument("--threads", type=int, default=1, help="cv2.setNumThreads (0: OpenCV's default)")
    ap.add_argument("--variant", action="append", default=[], metavar="NAME:KEY=VALUE,...",
                    help="also run grid_lk with these parameters, e.g. ds3:downscale=3 (repeatable)")
    args = ap.parse_args(argv)
    if args.threads > 0:
        cv2.setNumThreads(args.threads)
    variants = dict(parse_variant(v) for v in args.variant)
    names = list(methods(variants))
    W, H = args.width, args.height

    # --- synthetic suite: exact homographies -------------------------------------------------
    times: dict[str, list[float]] = {n: [] for n in names}
    walls: dict[str, list[float]] = {n: [] for n in names}
    errors: dict[str, list[float]] = {n: [] for n in names}
    invalid = {n: 0 for n in names}
    n_pairs = 0
    for spec in synth.suite_specs(args.sequences, args.frames, W, H, seed=args.seed):
        r = synth.render_sequence(spec)
        for k, out in run_pairs(r.frames, names, variants):
            n_pairs += 1
            for n, (mo, cpu, wall) in out.items():
                times[n].append(cpu)
                walls[n].append(wall)
                invalid[n] += not mo.valid
            if all(v[0].valid for v in out.values()):
                for n, (mo, *_) in out.items():
                    errors[n].append(hc.corner_transfer_error(mo.H, r.homographies[k], W, H))
        del r
    print(f"synthetic suite: {args.sequences} sequences x {args.frames} frames at {W}x{H}, "
          f"{n_pairs} frame pairs, {len(errors['grid_lk'])} valid for every method; "
          f"cv2 threads {cv2.getNumThreads()}")
    print(f"{'method':12s} {'cpu ms':>7s} {'wall ms':>8s} {'err mean':>9s} {'err median':>10s} "
          f"{'err p95':>8s} {'invalid':>7s}")
    for n in names:
        e, t, w = np.array(errors[n]), np.array(times[n]) * 1e3, np.array(walls[n]) * 1e3
        print(f"{n:12s} {np.median(t):7.2f} {np.median(w):8.2f} {e.mean():9.3f} {np.median(e):10.3f} "
              f"{np.percentile(e, 95):8.3f} {invalid[n]:7d}")

    # --- real UAV footage: photometric residual ----------------------------------------------
    real_times: dict[str, list[float]] = {n: [] for n in names}
    root = shared_data() / "sequences" / "uav123_10fps"
    if not root.is_dir():
        print(f"real footage: skipped ({root} not found; set MATA_SHARED_DATA)")
    for seq in REAL:
        img = root / seq / "img"
        if not img.is_dir():
            continue
        frames = [cv2.imread(str(p)) for p in sorted(img.glob("*.jpg"))]
        resid: dict[str, list[float]] = {n: [] for n in names}
        for k, out in run_pairs(frames, names, variants):
            for n, (mo, cpu, _) in out.items():
                real_times[n].append(cpu)
                resid[n].append(photometric_residual(frames[k - 1], frames[k], mo.H) if mo.valid else np.nan)
        h, w = frames[0].shape[:2]
        line = ", ".join(f"{n} {np.nanmean(v):.2f} ({int(np.isnan(v).sum())} invalid)"
                         for n, v in ((n, np.array(resid[n])) for n in names))
        print(f"real {seq} ({len(frames)} frames, {w}x{h}) photometric residual (grey levels): {line}")
        del frames
    if real_times["grid_lk"]:
        print("real footage cpu ms median: " + ", ".join(f"{n} {np.median(real_times[n]) * 1e3:.2f}" for n in names))

    # --- ratios --------------------------------------------------------------------------------
    speed = np.median(times["features"]) / np.median(times["grid_lk"])
    err_ratio = np.mean(errors["grid_lk"]) / np.mean(errors["features"])
    ok = speed >= 3.0 and err_ratio <= 1.0
    print(f"synthetic: grid_lk is {speed:.2f}x faster than features (median cpu ms), transfer error "
          f"grid_lk/features = {err_ratio:.2f} -> target (>= 3x, <= 1.0) {'MET' if ok else 'NOT MET'}")
    if real_times["grid_lk"]:
        rs = np.median(real_times["features"]) / np.median(real_times["grid_lk"])
        print(f"real footage: grid_lk is {rs:.2f}x faster than features (median cpu ms)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
