"""Scoring cost: one `mata-eval eval` over several results folders against one call per folder,
and `mata-eval --version` against a bare Python start, measured in the same run.

    python benchmarks/eval_speed.py [--repeat 5]

Uses the five published DTB70 result sets of ``$MATA_SHARED_DATA/results/DTB70.zip`` (70
sequences each, pysot-toolkit profile) and the DTB70 annotations. Each figure is the CPU time
(user + system) of the child processes, min and median over the repetitions, printed next to
its anchor and the ratio:
- scoring 5 folders: one call with 5 folders, against 5 calls of one folder each;
- `mata-eval --version`, against `python -c pass` (the interpreter's own start-up).
"""

from __future__ import annotations

import argparse
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import zipfile
from pathlib import Path

import numpy as np

TRACKERS = ("LightTrack", "NanoTrack", "SiamAPN", "SiamAPN++", "SiamTPN")


def child_cpu(commands: list[list[str]]) -> float:
    """CPU seconds (user + system) of running the commands one after the other."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    for cmd in commands:
        subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def stats(values: list[float]) -> str:
    return f"min {min(values):.3f}  median {np.median(values):.3f}"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args(argv)
    data = Path(os.environ.get("MATA_SHARED_DATA", Path(__file__).resolve().parents[2] / "shared" / "data"))
    if not (data / "results" / "DTB70.zip").is_file():
        print(f"no {data / 'results' / 'DTB70.zip'}: set MATA_SHARED_DATA")
        return 1
    tmp = Path(tempfile.mkdtemp(prefix="eval_speed_"))
    try:
        with zipfile.ZipFile(data / "results" / "DTB70.zip") as z:
            z.extractall(tmp, [n for n in z.namelist() if n.split("/")[1:2] and n.split("/")[1] in TRACKERS])
        ann = data / "annotations" / "DTB70"
        exe = [sys.executable, "-m", "mata_eval.cli"]
        common = ["--dataset", "dtb70", "--root", str(ann), "--set", f"annotations={ann}", "--profile", "pysot-toolkit"]
        dirs = [str(tmp / "DTB70" / t) for t in TRACKERS]
        per_call, one_call, version, bare = [], [], [], []
        for _ in range(args.repeat):  # interleaved, so load changes hit every figure alike
            per_call.append(child_cpu([exe + ["eval", d] + common for d in dirs]))
            one_call.append(child_cpu([exe + ["eval", *dirs] + common]))
            version.append(child_cpu([exe + ["--version"]]))
            bare.append(child_cpu([[sys.executable, "-c", "pass"]]))
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    n = len(TRACKERS)
    print(f"DTB70, {n} result folders x 70 sequences, pysot-toolkit profile; CPU seconds, {args.repeat} repetitions")
    print(f"  {n} calls of `mata-eval eval DIR` (anchor)      {stats(per_call)}")
    print(f"  1 call of `mata-eval eval DIR x {n}`            {stats(one_call)}")
    ratio = np.array(per_call) / np.array(one_call)
    print(f"  speed-up one call / {n} calls                  min {ratio.min():.2f}  median {np.median(ratio):.2f}")
    print(f"  `python -c pass` (anchor)                    {stats(bare)}")
    print(f"  `mata-eval --version`                        {stats(version)}  (target < 0.2 s)")
    over = np.array(version) - np.array(bare)
    print(f"  --version beyond the interpreter start       min {over.min():.3f}  median {np.median(over):.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
