"""The timing profiles of the device that experiments/embedded.yaml emulates (Table 4;
docs/decisions/paper.md "Table 4"): every tracker call's wall time in the ``vot_rt`` baseline
runs of that file (the "device" measuring itself; the initialisation and the calls vot_rt's grace
forgave left out), 1000 drawn with numpy
seed 0 (all of them if fewer), times the run's ``time_scale``, written as ``<out>/<tracker>-x<scale>.json``.

    mata-eval run experiments/embedded.yaml -j 1 --force --runs kcf-baseline-embedded vittrack-baseline-embedded
    python benchmarks/embedded_profiles.py experiments/embedded.yaml --out experiments/profiles

Re-measure when a tracker's speed or the machine changes (the rate each profile gives is
printed); run with one worker, not niced (other processes' load shows in the wall times), and
say the load in the profile (``--load``).
"""

from __future__ import annotations

import argparse
import csv
import math
import os
import platform
from pathlib import Path

import numpy as np

from mata_eval.run.config import load_experiment
from mata_eval.run.results import read_manifest
from mata_eval.run.runner import run_dir
from mata_eval.run.timing_profile import profile_from_samples, write_profile

N_SAMPLES = 1000


def tracker_wall_s(folder: Path, scale: float = 1.0, grace: int = 0, interval_s: float = 1 / 30) -> np.ndarray:
    """Every tracker call's wall time (s) in a run folder's ``*.frames.csv``, frame 0 (the
    initialisation) left out, and so is each call vot_rt's ``grace`` forgave: as the protocol
    counts them, per sequence the first ``grace`` calls, initialisation included, whose wall time
    times ``scale`` exceeds one frame ``interval_s`` (VitTrack's first track creates its ONNX
    Runtime session; a slow KCF initialisation takes the grace instead)."""
    out = []
    for frames in sorted(folder.glob("*.frames.csv")):
        with open(frames) as f:
            calls = [(int(row["frame"]), float(row.get("tracker_ms") or "nan") / 1e3) for row in csv.DictReader(f)]
        left = grace
        for frame, wall in calls:
            if not math.isfinite(wall):
                continue
            if left and wall * scale > interval_s:
                left -= 1
                continue
            if frame > 0:
                out.append(wall)
    return np.asarray(out)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("experiment", help="experiments/embedded.yaml")
    ap.add_argument("--out", required=True, help="folder of the profiles (experiments/profiles)")
    ap.add_argument("--load", default="", help="the machine's load average during the runs (recorded)")
    args = ap.parse_args(argv)
    exp = load_experiment(args.experiment)
    for spec in exp.runs:
        folder = run_dir(exp, spec)
        manifest = read_manifest(folder) if folder.is_dir() else None
        config = (manifest or {}).get("config", {})
        if config.get("protocol", {}).get("name") != "vot_rt" or config.get("estimator") is not None:
            continue  # only the baseline runs of the emulated device
        scale = float(config["protocol"].get("time_scale", 1.0))
        grace = int(config["protocol"].get("grace", 0))   # runs made before the grace had none
        fps = float(config["dataset"].get("fps") or 30.0)   # the synthetic suite: 30
        tracker = config["tracker"]["name"]
        wall = tracker_wall_s(folder, scale, grace, 1.0 / fps)
        if len(wall) == 0:
            raise SystemExit(f"{folder}: no tracker calls recorded; run it first")
        n = min(N_SAMPLES, len(wall))
        drawn = np.random.default_rng(0).choice(wall, n, replace=False) * scale
        machine = {
            "emulated_device": f"this machine's measured tracker wall times x {scale:g} (a device {scale:g}x slower)",
            "measured_on": f"{platform.machine()}, {os.cpu_count()} shared cores, Python {platform.python_version()}"
                           + (f", load average {args.load}" if args.load else ""),
            "how": f"tracker wall times of the vot_rt run {spec.name} (time_scale {scale:g}) of {args.experiment}: "
                   f"{len(wall)} calls (initialisation and the calls the grace forgave left out), {n} drawn with numpy seed 0, x {scale:g} "
                   "(benchmarks/embedded_profiles.py)",
            "time_scale": scale, "tracker": tracker,
        }
        created = np.datetime_as_string(np.datetime64("now"), unit="s") + "Z"
        path = write_profile(profile_from_samples({"tracker": drawn}, machine, created=created),
                             Path(args.out) / f"{tracker}-x{scale:g}.json")
        print(f"{path}: {tracker} {1e3 * wall.mean():.2f} ms a call here (median {1e3 * np.median(wall):.2f}, "
              f"n={len(wall)}), profile mean {1e3 * drawn.mean():.1f} ms = {1 / drawn.mean():.2f} Hz")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
