"""Scaling benchmark (one command: ``python benchmarks/scaling.py``).

Runs one experiment three times, each into a fresh output folder and in a fresh process:
``-j 1`` (in-process, the baseline), ``-j 2`` (two worker processes) and ``--executor ray`` on
a local Ray cluster of 2 CPUs. Prints, for each, the wall time and the CPU-seconds of every
process involved (the driver, its workers and, for Ray, the raylet, GCS and workers: reaped
children through ``RUSAGE_CHILDREN``, this process being their subreaper, and every descendant
sampled from /proc, Linux only), and both against ``-j 1`` measured in the same run. Also
checks that the three give the same predictions.

Default: experiments/protocols.yaml (24 runs) on the first 2 sequences of its dataset; with
``--sequences 20`` the whole synthetic suite.
"""

from __future__ import annotations

import argparse
import ctypes
import hashlib
import os
import resource
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import yaml

REPO = Path(__file__).resolve().parents[1]
PR_SET_CHILD_SUBREAPER = 36


def become_subreaper() -> bool:
    """Orphaned descendants (Ray's daemons and workers) are re-parented to this process, so
    their CPU time reaches ``RUSAGE_CHILDREN`` when we reap them (Linux only)."""
    try:
        return ctypes.CDLL(None, use_errno=True).prctl(PR_SET_CHILD_SUBREAPER, 1, 0, 0, 0) == 0
    except (OSError, AttributeError):
        return False


def children(pid: int) -> list[int]:
    out = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[1]) == pid:
            out.append(int(stat.parent.name))
    return out


def reap(timeout_s: float = 30.0) -> tuple[int, list[int]]:
    """Wait for every child (orphans included); kill those still alive after ``timeout_s``.
    Returns how many were reaped and the pids that had to be killed."""
    deadline = time.monotonic() + timeout_s
    killed: list[int] = []
    reaped = 0
    while True:
        try:
            pid, _ = os.waitpid(-1, os.WNOHANG)
        except ChildProcessError:
            return reaped, killed
        if pid:
            reaped += 1
            continue
        if time.monotonic() > deadline:
            for child in children(os.getpid()):
                os.kill(child, signal.SIGKILL)
                killed.append(child)
            deadline = float("inf")
        time.sleep(0.05)


def cpu_of_children() -> float:
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


class CpuSampler(threading.Thread):
    """Polls the CPU time of every descendant of this process (``/proc/PID/stat``) until
    stopped: Ray's workers are reaped by its raylet, so their CPU never reaches
    ``RUSAGE_CHILDREN``. A process that lives less than ``every_s`` may be missed."""

    def __init__(self, every_s: float = 0.2):
        super().__init__(daemon=True)
        self.every_s = every_s
        self.cpu: dict[int, float] = {}
        self.halt = threading.Event()

    def run(self) -> None:
        tick = os.sysconf("SC_CLK_TCK")
        while not self.halt.wait(self.every_s):
            parents: dict[int, int] = {}
            times: dict[int, float] = {}
            for stat in Path("/proc").glob("[0-9]*/stat"):
                try:
                    fields = stat.read_text().rsplit(")", 1)[1].split()
                except OSError:
                    continue
                pid = int(stat.parent.name)
                parents[pid] = int(fields[1])
                times[pid] = (int(fields[11]) + int(fields[12])) / tick
            mine = {os.getpid()}
            for _ in range(16):  # descendants, generation by generation
                mine |= {pid for pid, parent in parents.items() if parent in mine}
            for pid in mine - {os.getpid()}:
                self.cpu[pid] = max(self.cpu.get(pid, 0.0), times[pid])

    def total(self) -> float:
        self.halt.set()
        self.join()
        return sum(self.cpu.values())


def small_experiment(src: Path, n_sequences: int, folder: Path) -> Path:
    """``src`` with its top-level dataset cut to its first ``n_sequences`` sequences."""
    from mata_eval.run.config import load_experiment

    doc = yaml.safe_load(src.read_text())
    dataset = doc["dataset"] if isinstance(doc["dataset"], dict) else {"name": doc["dataset"]}
    names = [s.name for s in load_experiment(src).runs[0].dataset.create().sequences()]
    doc["dataset"] = {**dataset, "sequences": names[:n_sequences]}
    out = folder / src.name
    out.write_text(yaml.safe_dump(doc, sort_keys=False))
    return out


def predictions_digest(folder: Path) -> str:
    h = hashlib.sha256()
    for p in sorted(folder.rglob("*.txt")):
        h.update(str(p.relative_to(folder)).encode() + b"\0" + p.read_bytes())
    return h.hexdigest()[:12]


def measure(label: str, args: list[str], experiment: Path, out: Path) -> dict:
    cmd = [sys.executable, "-m", "mata_eval", "run", str(experiment), "-o", str(out), "--no-report", "-q", *args]
    cpu0 = cpu_of_children()
    sampler = CpuSampler()
    sampler.start()
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    processes, killed = reap()
    # Exact for what was reaped (the driver, local workers); the samples also see Ray's workers.
    cpu = max(cpu_of_children() - cpu0, sampler.total())
    processes = max(processes + 1, len(sampler.cpu))
    if proc.returncode != 0:
        sys.exit(f"{label}: {' '.join(cmd)} failed ({proc.returncode}):\n{proc.stderr[-2000:]}")
    if killed:
        print(f"  ({label}: {len(killed)} leftover process(es) killed after 30 s)")
    return {"label": label, "wall": wall, "cpu": cpu, "processes": processes,
            "digest": predictions_digest(out)}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("experiment", nargs="?", default=str(REPO / "experiments" / "protocols.yaml"))
    parser.add_argument("--sequences", type=int, default=2, help="first N sequences of the dataset (default 2)")
    parser.add_argument("--no-ray", action="store_true", help="skip the Ray run")
    args = parser.parse_args()
    if not become_subreaper():
        print("note: not Linux: Ray's daemons are not counted in its CPU-seconds")
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        exp = small_experiment(Path(args.experiment), args.sequences, tmp)
        configs = [("-j 1", ["-j", "1"]), ("-j 2", ["-j", "2"])]
        if not args.no_ray:
            try:
                import ray  # noqa: F401
                configs.append(("ray, 2 CPUs", ["--executor", "ray", "-j", "2"]))
            except ImportError:
                print("ray is not installed (pip install 'mata-eval[ray]'): its row is left out")
        print(f"{args.experiment}, first {args.sequences} sequence(s), {os.cpu_count()} cores, "
              f"load average {os.getloadavg()[0]:.1f} at the start")
        rows = [measure(label, a, exp, tmp / f"out{i}") for i, (label, a) in enumerate(configs)]
        shutil.rmtree(tmp, ignore_errors=True)
    base = rows[0]
    print(f"{'executor':<14}{'wall s':>9}{'CPU s':>9}{'speed-up':>10}{'CPU / -j 1':>12}{'processes':>11}  predictions")
    for r in rows:
        same = "same" if r["digest"] == base["digest"] else "DIFFERENT"
        print(f"{r['label']:<14}{r['wall']:>9.1f}{r['cpu']:>9.1f}{base['wall'] / r['wall']:>10.2f}"
              f"{r['cpu'] / base['cpu']:>12.2f}{r['processes']:>11}  {same} ({r['digest']})")
    return 0 if all(r["digest"] == base["digest"] for r in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
