"""The run tables of ``mata-eval run`` and ``mata-eval report``, one row per run:

- ``overall``: SR, MSR, PR, P@20, NT2F, block frequencies, excluded frames, failed sequences
  (the paper's Tables 1 and 3);
- ``challenges``: SR and NT2F per challenge group (the paper's Table 2);
- ``attributes``: SR and NT2F per sequence attribute of the dataset (pysot's per-attribute
  analysis: UAV123's 12, DTB70's 11, ...).

Metrics print as percentages with one decimal (CSV keeps fractions at full precision); block
frequencies as scheduled Hz (wall-clock Hz)."""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path
from typing import Any, Iterable, Mapping, Sequence

from ..score.evaluate import RunScores
from ..score.metrics import DEFAULT_GROUPS, summarize
from .tables import FORMATS, Table, hz, pct, render

TABLES = ("overall", "challenges", "attributes")
METRIC_LABELS = (("sr", "SR"), ("msr", "MSR"), ("pr", "PR"), ("precision20", "P@20"), ("nt2f", "NT2F"))

#: The legend printed under the overall table, one line per column (paper section 3.3;
#: docs/metrics.md has the exact definitions and the toolkit profiles).
LEGEND = (
    ("Seqs", "sequences scored"),
    ("SR", "success rate: % of frames whose box overlaps the ground truth with IoU > 0.5"),
    ("MSR", "mean success rate: mean over the IoU thresholds 0, 0.05, ..., 1 of the % of frames above "
            "them (area under the success plot, the 'AUC' of OTB/UAV123)"),
    ("PR", "normalised precision: % of frames whose centre error, divided by the target's width and "
           "height, is within 0.2"),
    ("P@20", "precision: % of frames whose centre error is within 20 pixels"),
    ("NT2F", "normalised time to failure: the first frame where the box stops overlapping the target "
             "(IoU 0), over the sequence length; 100 = never lost (paper eq. nt2f)"),
    ("<block> Hz", "e.g. tracker Hz 10.0 (22.5): the protocol ran the block 10 times per second of video "
                   "(camera clock); in parentheses, 1 / its mean wall time per call on this machine (both "
                   "from frame 1 on: frame 0 initialises the blocks); -: no rate (no call, or a single one: no "
                   "interval)"),
    ("Excl. frames", "frames left out of every metric because their ground truth is empty or missing "
                     "(target fully occluded or out of view, or not annotated)"),
    ("Failed", "sequences that failed to run (<run>/<sequence>.failed.json says why) or whose results cannot be "
               "scored (named under the table)"),
)

__all__ = ["FORMATS", "LEGEND", "METRIC_LABELS", "TABLES", "challenges_table", "mata_deltas", "overall_table",
           "render_table"]


def _num(v: float) -> str:
    return "" if v is None or not math.isfinite(v) else f"{v:.6g}"


_BLOCK_ORDER = ("tracker", "egomotion", "estimator")


def _in_order(keys: Iterable[Iterable[str]], canonical: Iterable[str]) -> list[str]:
    """The distinct ``keys`` (each run's), in ``canonical`` order, then any other as first seen:
    the same whether the scores are fresh or read back from scores.json (whose keys are sorted)."""
    rank = {k: i for i, k in enumerate(canonical)}
    seen = dict.fromkeys(k for ks in keys for k in ks)
    return sorted(seen, key=lambda k: rank.get(k, len(rank)))   # stable: the others keep their order


def _blocks(runs: Sequence[RunScores]) -> list[str]:
    """The blocks with a Hz column: tracker, egomotion, estimator, then any other."""
    return _in_order((r.frequencies for r in runs), _BLOCK_ORDER)


def distinct_names(runs: Sequence[RunScores]) -> list[RunScores]:
    """``runs`` with each name that several of them share followed by the end of its folder's
    path that tells them apart (``mata (out1)``, ``mata (out2)``): two run folders of one
    experiment written to two outputs are two rows, not two rows of one label; one folder scored
    under several metric profiles (``eval --output``) is told apart by the profile."""
    out = list(runs)
    for name in {r.name for r in runs}:
        same = [i for i, r in enumerate(runs) if r.name == name]
        if len(same) < 2:
            continue
        paths = list(dict.fromkeys(runs[i].path for i in same))   # the folders, each once
        tail_of = {p: "" for p in paths}
        if len(paths) > 1:
            parts = [Path(p).parts for p in paths]
            if len({p[-1:] for p in parts}) == 1:   # one folder name (the run's): its parents differ
                parts = [p[:-1] for p in parts]
            for k in range(1, max(map(len, parts)) + 1):
                tails = [str(Path(*p[-k:])) for p in parts]
                if len(set(tails)) == len(tails):
                    tail_of = dict(zip(paths, tails))
                    break
        labels = [tail_of[runs[i].path] for i in same]
        # one folder scored more than once (eval --output): its rows told apart by profile, then order
        labels = [", ".join(filter(None, [t, runs[i].profile])) if labels.count(t) > 1 else t
                  for t, i in zip(labels, same)]
        labels = [f"{t}, {j + 1}" if labels.count(t) > 1 else t for j, t in enumerate(labels)]
        for i, label in zip(same, labels):
            out[i] = dataclasses.replace(runs[i], name=f"{name} ({label})")
    return out


def _group_names(runs: Sequence[RunScores]) -> list[str]:
    """The challenge groups in the order of DEFAULT_GROUPS (the paper's Table 2), then any other."""
    return _in_order((r.summary.groups for r in runs), DEFAULT_GROUPS)


def overall_table(runs: Sequence[RunScores], fmt: str = "terminal") -> Table:
    """One row per run; in LaTeX the frequency columns are the scheduled rate only ("Freq.")."""
    blocks = _blocks(runs)
    metric_cols = [lab for _, lab in METRIC_LABELS]
    freq_cols = [f"{b} Freq." if fmt == "latex" else f"{b} Hz" for b in blocks]
    rows = []
    for r in runs:
        s = r.summary.overall
        row = [r.name, str(s.n_sequences)] + [pct(getattr(s, m)) for m, _ in METRIC_LABELS]
        for b in blocks:
            f = r.frequencies.get(b)
            if f is None:
                row.append("-")
            elif fmt == "latex":
                row.append(hz(f.scheduled_hz))
            else:  # scheduled rate (camera clock), wall-clock rate in parentheses
                row.append(f"{hz(f.scheduled_hz)} ({hz(f.wall_hz)})")
        row += [str(s.n_excluded), str(len(r.failures))]
        rows.append(row)
    # unlabelled groups: vertical rules between sequences, metrics, frequencies and counts in LaTeX
    groups = [(g, n) for g, n in (("", 1), ("", len(metric_cols)), ("", len(blocks)), ("", 2)) if n]
    legend = [f"{c}: {text}" for c, text in LEGEND if c != "<block> Hz" or blocks] if fmt != "latex" else []
    return Table("overall", "", ["Run"], groups, ["Seqs"] + metric_cols + freq_cols + ["Excl. frames", "Failed"],
                 rows, notes=legend, stub_align="l")


def challenges_table(runs: Sequence[RunScores], fmt: str = "terminal", table: str = "challenges") -> Table:
    """SR and NT2F per challenge group (``table`` "challenges") or per sequence attribute
    ("attributes"); the number of sequences of each in its header, except in LaTeX (like the
    paper)."""
    subsets = _subsets(table)
    n = {g: max((getattr(r.summary, subsets)[g].n_sequences for r in runs if g in getattr(r.summary, subsets)),
                default=0) for g in _subset_names(runs, subsets)}
    names = [g for g in n if n[g] > 0]  # a group no sequence belongs to would be a column of "-"
    rows = []
    for r in runs:
        row = [r.name]
        for g in names:
            s = getattr(r.summary, subsets).get(g)
            row += [pct(s.sr), pct(s.nt2f)] if s is not None else ["-", "-"]
        rows.append(row)
    labels = [((f"{g[:1].upper()}{g[1:]}" if subsets == "groups" else g) + ("" if fmt == "latex" else f" ({n[g]})"), 2)
              for g in names]
    empty = [g for g in n if n[g] == 0]
    if not names:
        note = "no sequence of these runs has attributes (the dataset gives none)"
    elif subsets == "groups":
        note = ("challenge groups: a sequence is in a group when it has one of the group's attributes "
                "(docs/metrics.md); (n) = sequences in the group; SR and NT2F as in the overall table"
                + (f"; no sequence is in {', '.join(empty)} (left out)" if empty else ""))
    else:
        note = "attributes of the dataset's sequences; (n) = sequences with it; SR and NT2F as in the overall table"
    return Table(table, "", ["Run"], labels, [c for _ in names for c in ("SR", "NT2F")], rows,
                 notes=[note] if fmt != "latex" else [], stub_align="l")


def _subsets(table: str) -> str:
    """The Summary field the table ``table`` is made of: ``groups`` or ``attributes``."""
    return "groups" if table == "challenges" else "attributes"


def _subset_names(runs: Sequence[RunScores], subsets: str) -> list[str]:
    """The challenge groups in the paper's order (:func:`_group_names`), or the attributes sorted."""
    if subsets == "groups":
        return _group_names(runs)
    return sorted({a for r in runs for a in r.summary.attributes})


def has_challenges(runs: Sequence[RunScores]) -> bool:
    """Whether any challenge group has a sequence (else the challenge table is not worth printing)."""
    return any(s.n_sequences > 0 for r in runs for s in r.summary.groups.values())


def mata_deltas(runs: Sequence[RunScores]) -> Table | None:
    """MATA minus its baseline, in points, for every MATA run whose baseline (the same
    configuration without ego-motion and estimator: :func:`_key`, :func:`_same_versions`; the
    one in the same output folder where several are given) is among ``runs``: the experiment's
    takeaway per tracker and protocol. Configurations come from each run folder's manifest;
    None when no run has its baseline here (a table without rows when only its notes say why,
    e.g. a baseline scored under another metric profile)."""
    from ..run.results import read_manifest
    from .paper import is_mata, plugin_label, protocol_label

    configs = []
    for r in runs:
        manifest = read_manifest(Path(r.path)) if Path(r.path).is_dir() else None
        if manifest and isinstance(manifest.get("config"), dict):
            configs.append((r, manifest["config"]))
    baselines: dict[str, list[tuple[RunScores, dict]]] = {}
    for r, cfg in configs:
        if not is_mata(cfg):   # no estimator, or a ``baseline`` one (zoh)
            baselines.setdefault(_key(cfg), []).append((r, cfg))
    rows, notes = [], []
    for r, cfg in configs:
        if not is_mata(cfg):
            continue
        found = [(b, bcfg) for b, bcfg in baselines.get(_key(cfg), []) if _same_versions(cfg, bcfg)]
        if found and not any(b.profile == r.profile for b, _ in found):   # (their difference means nothing)
            notes.append(f"{r.name}: its baseline is scored under another metric profile; not compared")
        found = [(b, bcfg) for b, bcfg in found if b.profile == r.profile]
        if not found:
            continue
        # two outputs of one experiment (report jetson/* desktop/*): the baseline beside the run;
        # of several, the tracker alone before one with a block B or a baseline estimator (zoh)
        base, _ = min(found, key=lambda b: (Path(b[0].path).parent != Path(r.path).parent,
                                            b[1].get("estimator") is not None or b[1].get("egomotion") is not None))
        mine, theirs = r.summary.overall, base.summary.overall
        if set(r.sequences) != set(base.sequences):
            # a sequence that failed (or is missing) in one run only: both means over the
            # sequences the two runs have, so that the difference is MATA's, not the set's
            common = sorted(set(r.sequences) & set(base.sequences))
            mine = summarize([r.sequences[s] for s in common])
            theirs = summarize([base.sequences[s] for s in common])
            notes.append(f"{r.name} - {base.name}: over the {len(common)} sequence(s) both have "
                         f"(not in both: {', '.join(sorted(set(r.sequences) ^ set(base.sequences)))})")
        cells = []
        for m, _ in METRIC_LABELS:
            a, b = getattr(mine, m), getattr(theirs, m)
            cells.append(f"{100.0 * (a - b):+.1f}" if math.isfinite(a) and math.isfinite(b) else "-")
        rows.append([plugin_label("tracker", cfg.get("tracker")), protocol_label(cfg.get("protocol"))[0],
                     f"{r.name} - {base.name}"] + cells)
    if not rows and not notes:
        return None
    return Table("mata_vs_baseline", "MATA minus its baseline, in points (same tracker, data and protocol; "
                 "positive: MATA better)", ["Tracker", "Protocol", "Runs"], [],
                 [lab for _, lab in METRIC_LABELS], rows, notes=notes, stub_align="l")


def _key(cfg: Mapping[str, Any]) -> str:
    """What a MATA run shares with its baseline: the configuration without blocks B and C (and
    without the installed plugins' versions: :func:`_same_versions`)."""
    blocks = ("egomotion", "estimator", "feedback", "plugin_versions")
    from ..run.config import as_a_set

    shared = {k: v for k, v in cfg.items() if k not in blocks}
    if isinstance(shared.get("dataset"), Mapping):
        shared["dataset"] = as_a_set(shared["dataset"])
    return json.dumps(shared, sort_keys=True, default=str)


def _same_versions(mata: Mapping[str, Any], baseline: Mapping[str, Any]) -> bool:
    """Whether the MATA run used the baseline's versions of the baseline's installed plugin
    packages (it may name more: those of its third-party blocks B and C); a MATA run of an
    upgraded tracker is not paired with the old tracker's baseline."""
    mine = mata.get("plugin_versions") or {}
    return all(mine.get(d) == v for d, v in (baseline.get("plugin_versions") or {}).items())


def _csv_table(runs: Sequence[RunScores], table: str) -> Table:
    """The same data at full precision, machine-readable column names, one row per run (or per
    run and challenge group)."""
    metric_cols = [m for m, _ in METRIC_LABELS]
    rows = []
    if table == "overall":
        blocks = _blocks(runs)
        cols = ["profile", "sequences", *metric_cols,
                *(f"{b}_{k}" for b in blocks for k in ("scheduled_hz", "wall_hz")),
                "frames", "scored_frames", "excluded_frames", "invalid_gt_frames", "failed", "missing"]
        for r in runs:
            s = r.summary.overall
            freq = []
            for b in blocks:
                f = r.frequencies.get(b)
                freq += [_num(f.scheduled_hz), _num(f.wall_hz)] if f else ["", ""]
            rows.append([r.name, r.profile, str(s.n_sequences), *(_num(getattr(s, m)) for m in metric_cols),
                         *freq, *(str(v) for v in (s.n_frames, s.n_scored, s.n_excluded, s.n_invalid_gt,
                                                   len(r.failures), len(r.missing)))])
    else:
        subsets = _subsets(table)
        cols = ["group" if subsets == "groups" else "attribute", "sequences", *metric_cols]
        for r in runs:
            for g, s in getattr(r.summary, subsets).items():
                rows.append([r.name, g, str(s.n_sequences), *(_num(getattr(s, m)) for m in metric_cols)])
    return Table(table, "", ["run"], [], cols, rows)


def render_table(runs: Sequence[RunScores], fmt: str = "terminal", table: str = "overall") -> str:
    """The table of ``runs`` in ``fmt`` (terminal, markdown, csv, latex); ``table`` one of
    :data:`TABLES`."""
    if fmt not in FORMATS:
        raise ValueError(f"unknown table format {fmt!r}; expected one of {', '.join(FORMATS)}")
    if table not in TABLES:
        raise ValueError(f"unknown table {table!r}; expected one of {', '.join(TABLES)}")
    runs = list(runs)
    if fmt == "csv":
        return render(_csv_table(runs, table), "csv")
    return render(overall_table(runs, fmt) if table == "overall" else challenges_table(runs, fmt, table), fmt)
