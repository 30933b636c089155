"""EOP against the live run, on this machine (the paper's Table 4; one command after the runs:
``python benchmarks/live_vs_eop.py experiments/live.yaml experiments/live_self.yaml``).

Reads (and scores, when needed) the run folders of an experiment whose run names are
``<tracker>-<mata>-<protocol>`` with protocol labels ``live<i>`` (repetitions of a live run),
any number of EOP variants and ``ltp``, and prints, per tracker x MATA: the live SR, NT2F and
tracker rate (mean over the repetitions, and their spread: the noise floor), then
|dSR| and |dNT2F| of every other protocol against the live mean, and the mean discrepancies with
their ratio to LTP's (the paper's "EOP 6.4x closer than LTP in SR"). Timing diagnostics per
protocol, from the traces: the tracker's rate, the mean age of the scored output (frames between
the frame scored and the frame its box was computed from) and the ego-motion's mean call time.
"""

from __future__ import annotations

import argparse
import csv
import math
import sys
from collections import defaultdict
from pathlib import Path

import numpy as np

from mata_eval.run.config import load_experiment
from mata_eval.run.runner import run_dir
from mata_eval.score.evaluate import scores_for


def timing_of(folder: Path) -> dict[str, float]:
    """Mean output age (frames) and mean ego-motion call time (ms) over the sequences of a run."""
    ages, ego = [], []
    for frames in sorted(folder.glob("*.frames.csv")):
        with open(frames) as f:
            rows = list(csv.DictReader(f))
        ages += [int(r["frame"]) - int(r["source_frame"]) for r in rows]
        ego += [float(r["egomotion_ms"]) for r in rows if r.get("egomotion_ms") not in (None, "", "nan")]
    return {"age": float(np.mean(ages)) if ages else math.nan, "ego_ms": float(np.mean(ego)) if ego else math.nan}


def collect(exp_paths: list[str]) -> dict:
    """{(tracker, mata): {protocol label: [(sr, nt2f, tracker Hz, timing), ...]}}."""
    table: dict = defaultdict(lambda: defaultdict(list))
    for exp, spec in ((exp, spec) for exp in map(load_experiment, exp_paths) for spec in exp.runs):
        folder = run_dir(exp, spec)
        if not folder.is_dir():
            print(f"skipped {spec.name}: no run folder {folder}", file=sys.stderr)
            continue
        scores = scores_for(folder)   # (scored again where its scores.json is out of date: QA pass 16c)
        tracker, mata, label = spec.name.split("-", 2)
        kind = "live" if label.startswith("live") else label
        s = scores.summary.overall
        f = scores.frequencies.get("tracker")
        table[(tracker, mata)][kind].append((s.sr, s.nt2f, f.scheduled_hz if f else math.nan, timing_of(folder)))
    return table


def render(table: dict) -> str:
    protocols = sorted({p for cell in table.values() for p in cell if p != "live"},
                       key=lambda p: (p == "ltp", p))
    head = ["VOT", "MATA", "live SR", "live NT2F", "live Hz", "live spread SR / NT2F"]
    for p in protocols:
        head += [f"{p} \\|dSR\\|", f"{p} \\|dNT2F\\|", f"{p} Hz"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    diffs: dict = defaultdict(dict)   # protocol -> {(tracker, mata): (|dSR|, |dNT2F|)}
    spreads = []
    timing_rows = []
    for (tracker, mata), cell in table.items():
        live = cell.get("live", [])
        if not live:
            continue
        sr, nt2f, hz = (np.array([r[i] for r in live]) for i in range(3))
        m_sr, m_nt2f = sr.mean(), nt2f.mean()
        # noise floor: how far one repetition lies from the mean of the repetitions (mean abs. dev.)
        spread = (np.abs(sr - m_sr).mean(), np.abs(nt2f - m_nt2f).mean())
        spreads.append(spread)
        row = [tracker, mata, f"{100 * m_sr:.1f}", f"{100 * m_nt2f:.1f}", f"{hz.mean():.1f}",
               f"{100 * spread[0]:.1f} / {100 * spread[1]:.1f} (n={len(live)})"]
        live_t = [r[3] for r in live]
        timing_rows.append((tracker, mata, "live", hz.mean(), np.mean([t["age"] for t in live_t]),
                            np.mean([t["ego_ms"] for t in live_t])))
        for p in protocols:
            if not cell.get(p):
                row += ["-", "-", "-"]
                continue
            p_sr, p_nt2f, p_hz, p_t = cell[p][0]
            d = (abs(p_sr - m_sr), abs(p_nt2f - m_nt2f))
            diffs[p][(tracker, mata)] = d
            row += [f"{100 * d[0]:.1f}", f"{100 * d[1]:.1f}", f"{p_hz:.1f}"]
            timing_rows.append((tracker, mata, p, p_hz, p_t["age"], p_t["ego_ms"]))
        lines.append("| " + " | ".join(row) + " |")
    out = ["\n".join(lines), ""]
    if spreads:
        out.append(f"- live noise floor (mean abs. deviation of one repetition from the mean): "
                   f"SR {100 * np.mean([s[0] for s in spreads]):.1f}, NT2F {100 * np.mean([s[1] for s in spreads]):.1f} points")
    mean = lambda ds: [float(np.mean([d[k] for d in ds])) for k in (0, 1)]  # noqa: E731
    for p in protocols:
        if not diffs.get(p):
            continue
        m = mean(diffs[p].values())
        # the ratio over the rows both protocols have (QA pass 16b: means of different rows were divided)
        common = sorted(set(diffs[p]) & set(diffs.get("ltp", {})))
        ratio = ""
        if p != "ltp" and common and min(p_c := mean([diffs[p][k] for k in common])) > 0:
            ltp_c = mean([diffs["ltp"][k] for k in common])
            ratio = (f" (LTP / {p} over the {len(common)} row(s) both have: SR {ltp_c[0] / p_c[0]:.1f}x, "
                     f"NT2F {ltp_c[1] / p_c[1]:.1f}x)")
        out.append(f"- mean |dSR| {p}: {100 * m[0]:.1f}, mean |dNT2F|: {100 * m[1]:.1f} points over "
                   f"{len(diffs[p])} row(s){ratio}")
    out += ["", "| VOT | MATA | protocol | tracker Hz | mean output age (frames) | ego-motion ms/call |",
            "|---|---|---|---|---|---|"]
    out += [f"| {t} | {m} | {p} | {hz:.1f} | {age:.2f} | {ego:.1f} |" for t, m, p, hz, age, ego in timing_rows]
    return "\n".join(out)


def write_self_profiles(exp_path: str, out_dir: str) -> None:
    """Timing profiles of the live runs themselves (``<out>/live-<tracker>-self.json``): every
    call's measured work time in the MATA live repetitions, times the run's ``time_scale``. An EOP
    run reading one has the live run's own latencies, so what remains between them is EOP's model
    of time, not the error of a profile taken at another moment on a loaded machine."""
    from mata_eval.run.results import read_manifest
    from mata_eval.run.timing_profile import profile_from_samples, write_profile

    exp = load_experiment(exp_path)
    pooled: dict = defaultdict(lambda: defaultdict(list))
    for spec in exp.runs:
        tracker, mata, label = spec.name.split("-", 2)
        folder = run_dir(exp, spec)
        if mata != "mata" or not label.startswith("live") or not folder.is_dir():
            continue
        scale = (read_manifest(folder) or {})["config"]["protocol"].get("time_scale", 1.0)
        for frames in sorted(folder.glob("*.frames.csv")):
            with open(frames) as f:
                for row in csv.DictReader(f):
                    for block in ("tracker", "egomotion", "estimator"):
                        ms = float(row.get(f"{block}_ms") or "nan")
                        if math.isfinite(ms) and int(row["frame"]) > 0:  # not the initialisation
                            factor = scale.get(block, 1.0) if isinstance(scale, dict) else scale
                            pooled[tracker][block].append(ms * factor / 1e3)
    for tracker in sorted({spec.name.split("-", 2)[0] for spec in exp.runs} - set(pooled)):
        print(f"{tracker}: no self profile (no finished MATA live run of it in {exp_path})")
    for tracker, samples in pooled.items():
        machine = {"measured_on": "the live runs of " + exp_path, "how": "every call's work time x time_scale"}
        path = write_profile(profile_from_samples(samples, machine), Path(out_dir) / f"live-{tracker}-self.json")
        print(f"{path}: " + ", ".join(f"{b} {1e3 * np.mean(v):.1f} ms (n={len(v)})" for b, v in samples.items()))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("experiments", nargs="+", help="experiment files (experiments/live.yaml [live_self.yaml])")
    ap.add_argument("--self-profiles", metavar="DIR",
                    help="instead: write the timing profiles of the live runs themselves into DIR")
    args = ap.parse_args(argv)
    if args.self_profiles:
        write_self_profiles(args.experiments[0], args.self_profiles)
        return 0
    print(render(collect(args.experiments)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
