"""The paper's four results tables, rendered from run folders, and a one-page HTML summary.

Each run is placed in its row / column from its manifest (``manifest.json``: the resolved
configuration), never from its name alone:

- Table 1 (``protocols``, paper tab:result_protocol): rows Protocol x VOT (tracker) x MATA,
  column groups per dataset (``+occ`` when the occlusion augmentation was on), SR and NT2F;
- Table 2 (``challenges``, tab:metrics_per_challenges): rows VOT x MATA, column groups per
  challenge group (occlusion, distractor, high dynamic, out of view), SR and NT2F;
- Table 3 (``ablation``, tab:ablation_study): one row per configuration with its ego-motion /
  EKF / score marks, a description, PR, SR, MSR and NT2F;
- Table 4 (``embedded``, tab:embedded_results): rows VOT x MATA; SR, NT2F and tracker frequency
  of the embedded measurement (``vot_rt``: the tracker's real wall time on the machine that ran
  it), then the absolute differences |X - embedded| of EOP and LTP, with their frequencies.

What a table needs to know about a plugin comes from the plugin class, never from a list here:
its display ``label``, whether an estimator is a ``baseline`` (MATA is "on" when the run has an
estimator that is not one), a protocol's ``table_label(params)`` and ``paper_role``, an
estimator's ``ablation(params, egomotion)`` and a tracker's ``explainable_score(params)``.
Rendering: Markdown and LaTeX booktabs by :mod:`.tables`, HTML by :mod:`.html`.
"""

from __future__ import annotations

import inspect
import math
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

from ..run.results import versions_line
from ..score.evaluate import RunScores
from ..score.metrics import DEFAULT_GROUPS
from .html import html_summary
from .tables import Table, mark, pct, render

PAPER_TABLES = ("protocols", "challenges", "ablation", "embedded")
#: the column groups of Table 4, filled by the protocols whose ``paper_role`` they are
EMBEDDED_ROLES = ("Embedded", "EOP", "LTP")

CHALLENGE_ORDER = tuple(DEFAULT_GROUPS)   # the paper's Table 2 order
CAPTIONS = {
    "protocols": "SR and NT2F of each tracker with and without MATA under LTP and EOP (paper Table 1).",
    "challenges": "SR and NT2F per challenge (paper Table 2).",
    "ablation": "Contribution of each MATA block (paper Table 3).",
    "embedded": "Embedded measurement (tracker at its real speed) and the absolute differences of EOP "
                "and LTP with respect to it (paper Table 4). Freq. is the tracker's rate in Hz.",
}


class PlacementError(ValueError):
    """A run cannot be placed in the requested table (the message names the run folder)."""


# --- where a run goes -------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class PlacedRun:
    """A scored run and the coordinates the paper's tables use for it."""

    scores: RunScores
    config: Mapping[str, Any]
    tracker: str  # display name, e.g. "VitTrack"
    mata: bool
    protocol: str  # display label, e.g. "EOP @ 10 Hz"
    protocol_order: tuple
    dataset: str  # display label, e.g. "Synthetic+occ"
    dataset_key: tuple  # (dataset name, occlusion on)

    @property
    def name(self) -> str:
        return self.scores.name


def _plugin_class(kind: str, block: Mapping[str, Any] | None) -> Any:
    """The installed plugin class of a resolved config block, or None (no block, or the plugin is
    no longer installed: its name is then used as it is)."""
    if not isinstance(block, Mapping) or not block.get("name"):
        return None
    from ..core.registry import load_registry

    try:
        return load_registry().get(kind, block["name"]).cls
    except KeyError:
        return None


def plugin_label(kind: str, block: Mapping[str, Any] | None) -> str:
    """Display name of a plugin block: the plugin class's ``label`` (e.g. "VitTrack"), else its
    name."""
    name = (block or {}).get("name", "?")
    return getattr(_plugin_class(kind, block), "label", None) or name


def protocol_label(block: Mapping[str, Any] | None) -> tuple[str, tuple]:
    """Display label and sort key of a protocol block, from the protocol plugin's
    ``table_label(params)`` (paper Table 1 order: LTP, then EOP from the fastest tracker rate
    down, then the others); the name and a last place for a protocol without one."""
    cls = _plugin_class("protocol", block)
    if cls is not None and hasattr(cls, "table_label"):
        return cls.table_label({k: v for k, v in block.items() if k != "name"})
    return str((block or {}).get("name", "?")), (99, 0.0)


def is_mata(config: Mapping[str, Any]) -> bool:
    """MATA is on when the run has an estimator that is not a ``baseline`` one (a plugin class
    attribute: the zero-order hold only holds the tracker's box)."""
    est = config.get("estimator")
    return isinstance(est, Mapping) and bool(est.get("name")) and not getattr(
        _plugin_class("estimator", est), "baseline", False)


def place(scores: RunScores, manifest: Mapping[str, Any] | None) -> PlacedRun:
    """Place a run from its manifest; raises :class:`PlacementError` without one."""
    if not manifest or not isinstance(manifest.get("config"), Mapping):
        raise PlacementError(f"{scores.path}: no manifest.json with the run's configuration; the paper's "
                             f"tables place runs from it (run the experiment with `mata-eval run`)")
    cfg = manifest["config"]
    dataset = (cfg.get("dataset") or {}).get("name", "?")
    occ = cfg.get("occlusion") is not None
    label, order = protocol_label(cfg.get("protocol"))
    ds = plugin_label("dataset", cfg.get("dataset")) + ("+occ" if occ else "")
    return PlacedRun(scores, cfg, plugin_label("tracker", cfg.get("tracker")), is_mata(cfg), label, order, ds,
                     (dataset, occ))


def load_runs(run_dirs: Sequence[str | Path]) -> list[PlacedRun]:
    """Score (when needed) and place every run folder."""
    from ..run import results
    from ..score.evaluate import scores_for

    placed = []
    for d in run_dirs:
        scores = scores_for(Path(d))
        manifest = results.read_manifest(Path(scores.path)) if Path(scores.path).is_dir() else None
        placed.append(place(scores, manifest))
    return placed


# --- table structure --------------------------------------------------------------------------


def _unique(cells: dict, key, run: PlacedRun, table: str) -> None:
    if key in cells:
        raise PlacementError(f"{table} table: runs {cells[key].name!r} ({cells[key].scores.path}) and "
                             f"{run.name!r} ({run.scores.path}) fall in the same cell {key}; report them separately")
    cells[key] = run


def _protocol_order(runs: Sequence[PlacedRun]) -> list[str]:
    """The runs' protocol labels in the paper's order (LTP, then EOP from the fastest rate down)."""
    return [label for _, label in sorted({(r.protocol_order, r.protocol) for r in runs})]


def _tracker_order(runs: Sequence[PlacedRun]) -> list[str]:
    seen: list[str] = []
    for r in runs:
        if r.tracker not in seen:
            seen.append(r.tracker)
    return seen


def _dataset_order(runs: Sequence[PlacedRun]) -> list[tuple[str, bool]]:
    first: dict[str, int] = {}
    for i, r in enumerate(runs):
        first.setdefault(r.dataset_key[0], i)
    keys = {r.dataset_key for r in runs}
    return sorted(keys, key=lambda k: (first[k[0]], k[1]))


def protocols_table(runs: Sequence[PlacedRun]) -> Table:
    """Paper Table 1: Protocol x VOT x MATA rows, one SR / NT2F column pair per dataset."""
    cells: dict = {}
    for r in runs:
        _unique(cells, (r.protocol, r.tracker, r.mata, r.dataset_key), r, "protocols")
    datasets = _dataset_order(runs)
    label_of = {r.dataset_key: r.dataset for r in runs}
    rows, blocks = [], []
    for proto in _protocol_order(runs):
        blocks.append(len(rows))
        for tracker in _tracker_order(runs):
            for mata in (False, True):
                vals = [cells.get((proto, tracker, mata, d)) for d in datasets]
                if not any(vals):
                    continue
                row = [proto, tracker, mark(mata)]
                for v in vals:
                    s = v.scores.summary.overall if v else None
                    row += [pct(s.sr), pct(s.nt2f)] if s else ["-", "-"]
                rows.append(row)
    return Table("protocols", CAPTIONS["protocols"], ["Protocol", "VOT", "MATA"],
                      [(label_of[d], 2) for d in datasets], ["SR", "NT2F"] * len(datasets), rows, blocks)


def challenges_table(runs: Sequence[PlacedRun]) -> Table:
    """Paper Table 2: VOT x MATA rows, one SR / NT2F column pair per challenge group (the group's
    sequence count in brackets). Protocol / dataset columns are added when they vary."""
    names: list[str] = [g for g in CHALLENGE_ORDER if any(g in r.scores.summary.groups for r in runs)]
    for r in runs:
        names += [g for g in r.scores.summary.groups if g not in names]
    n = {g: max((r.scores.summary.groups[g].n_sequences for r in runs if g in r.scores.summary.groups), default=0)
         for g in names}
    vary_p = len({r.protocol for r in runs}) > 1
    vary_d = len({r.dataset_key for r in runs}) > 1
    stub = (["Dataset"] if vary_d else []) + (["Protocol"] if vary_p else []) + ["VOT", "MATA"]
    cells: dict = {}
    for r in runs:
        _unique(cells, (r.dataset_key, r.protocol, r.tracker, r.mata), r, "challenges")
    order = sorted({(r.dataset_key, r.protocol_order, r.protocol) for r in runs},
                   key=lambda k: (_dataset_order(runs).index(k[0]), k[1]))
    rows, blocks = [], []
    for dkey, _, proto in order:
        for tracker in _tracker_order(runs):
            if not any((dkey, proto, tracker, m) in cells for m in (False, True)):
                continue
            blocks.append(len(rows))
            for mata in (False, True):
                r = cells.get((dkey, proto, tracker, mata))
                if r is None:
                    continue
                row = ([r.dataset] if vary_d else []) + ([proto] if vary_p else []) + [tracker, mark(mata)]
                for g in names:
                    s = r.scores.summary.groups.get(g)
                    row += [pct(s.sr), pct(s.nt2f)] if s is not None and s.n_sequences else ["-", "-"]
                rows.append(row)
    groups = [(f"{g[:1].upper()}{g[1:]} ({n[g]})", 2) for g in names]
    notes = [f"{g}: attributes {', '.join(runs[0].scores.summary.group_definitions.get(g, ()))}"
             for g in names if runs and runs[0].scores.summary.group_definitions.get(g)]
    return Table("challenges", CAPTIONS["challenges"], stub, groups, ["SR", "NT2F"] * len(names),
                      rows, blocks, notes)


def ablation_marks(config: Mapping[str, Any], name_egomotion: bool = False) -> tuple[bool, bool, bool | None, str]:
    """(ego-motion used, EKF used, explainable score used or None when the tracker has no choice,
    description) of one configuration, from its resolved config (paper Table 3 columns). The
    plugins say what their parameters mean: the estimator's ``ablation(params, egomotion)`` gives
    the first two and the description, the tracker's ``explainable_score(params)`` the third.
    The description names block B (its ``label``) when it is not one of mata-eval's own plugins,
    or when ``name_egomotion`` (the table's runs use more than one)."""
    est = config.get("estimator") or {}
    tracker = config.get("tracker") or {}
    egomotion = config.get("egomotion") is not None
    tcls = _plugin_class("tracker", tracker)
    params = {k: v for k, v in tracker.items() if k != "name"}
    score = tcls.explainable_score(params) if hasattr(tcls, "explainable_score") else None
    if not is_mata(config):
        details = f"{plugin_label('tracker', tracker)} (baseline)" + (", explainable score" if score else "")
        return egomotion, False, score, details
    ecls = _plugin_class("estimator", est)
    if not hasattr(ecls, "ablation"):
        ego, ekf, details = egomotion, False, f"estimator {plugin_label('estimator', est)}"
    else:
        ego, ekf, details = _estimator_ablation(ecls, est, egomotion)
    if ego and (name_egomotion or not _own_plugin(_plugin_class("egomotion", config.get("egomotion")))):
        details += f"; block B: {plugin_label('egomotion', config.get('egomotion'))}"
    if ego and (changed := _non_defaults("egomotion", config.get("egomotion"))):
        details += f"; {config['egomotion']['name']}: {changed}"   # a block B setting is a configuration too
    return ego, ekf, score, details


def _estimator_ablation(ecls: type, est: Mapping[str, Any], egomotion: bool) -> tuple[bool, bool, str]:
    """The estimator class's ``ablation(params, egomotion)``: a classmethod returning (ego-motion
    used, EKF used, description); anything else is a :class:`PlacementError` naming the plugin."""
    expected = "expected @classmethod ablation(cls, params, egomotion) -> (ego-motion used, EKF used, description)"
    if not isinstance(inspect.getattr_static(ecls, "ablation"), (classmethod, staticmethod)):
        raise PlacementError(f"estimator {est.get('name')!r}: ablation(params, egomotion) is not a classmethod; "
                             f"{expected}")
    try:
        out = ecls.ablation({k: v for k, v in est.items() if k != "name"}, egomotion)
    except Exception as exc:   # the plugin's own bug: named, not a traceback
        raise PlacementError(f"estimator {est.get('name')!r}: ablation(params, egomotion) raised "
                             f"{type(exc).__name__}: {exc}") from exc
    if not (isinstance(out, tuple) and len(out) == 3 and isinstance(out[2], str)):
        raise PlacementError(f"estimator {est.get('name')!r}: ablation(params, egomotion) returned {out!r}; {expected}")
    return bool(out[0]), bool(out[1]), out[2]


def _own_plugin(cls: Any) -> bool:
    """Whether a plugin class is one of mata-eval's own (False for a class no longer installed)."""
    return cls is not None and cls.__module__.split(".")[0] in ("mata_eval", "mata_eval_plugins")


def _non_defaults(kind: str, block: Mapping[str, Any] | None) -> str:
    """``key = value`` of each parameter of a resolved plugin block that is not its default."""
    cls = _plugin_class(kind, block)
    if cls is None or not hasattr(cls, "Params"):
        return ""
    defaults = cls.Params()
    return ", ".join(f"{k} = {v}" for k, v in block.items()
                     if k != "name" and hasattr(defaults, k) and v != getattr(defaults, k))


#: a configuration's number: the leading number of a matrix label ("2-mata", "occ-2-mata-ltp")
_CONFIG_NUMBER = re.compile(r"(?:^|-)(\d+)[-_ ]")


def ablation_table(runs: Sequence[PlacedRun]) -> Table:
    """Paper Table 3: one row per configuration (numbered by the first matrix label of the run
    name that starts with a number, e.g. ``2`` for ``occ-2-mata-ltp``, else in the order given),
    its block marks, description, PR, SR, MSR, NT2F. A Dataset column is added when the runs use
    more than one data set (``+occ``: with the occlusion augmentation), a VOT column when they use
    more than one tracker, a Protocol column when they use more than one protocol (rows then
    grouped by data set, tracker, then protocol). Block B is named in the description when the
    runs use more than one."""
    def number(i_r):
        i, r = i_r
        m = _CONFIG_NUMBER.search(r.name)
        return (int(m.group(1)) if m else 10_000 + i)

    datasets = _dataset_order(runs)
    trackers = _tracker_order(runs)
    protocols = _protocol_order(runs)
    vary_d, vary_t, vary_p = len(datasets) > 1, len(trackers) > 1, len(protocols) > 1
    name_ego = len({(r.config.get("egomotion") or {}).get("name") for r in runs if r.config.get("egomotion")}) > 1
    ordered = sorted(enumerate(runs), key=lambda i_r: (datasets.index(i_r[1].dataset_key),
                                                      trackers.index(i_r[1].tracker),
                                                      protocols.index(i_r[1].protocol), number(i_r)))
    rows, blocks, group = [], [], None
    count = 0
    for i, r in ordered:
        if (vary_d or vary_t or vary_p) and group != (r.dataset_key, r.tracker, r.protocol):
            blocks.append(len(rows))
            group, count = (r.dataset_key, r.tracker, r.protocol), 0
        count += 1
        ego, ekf, score, details = ablation_marks(r.config, name_ego)
        m = _CONFIG_NUMBER.search(r.name)
        s = r.scores.summary.overall
        rows.append(([r.dataset] if vary_d else []) + ([r.tracker] if vary_t else [])
                    + ([r.protocol] if vary_p else [])
                    + [m.group(1) if m else str(count), mark(ego), mark(ekf), mark(score), details,
                       pct(s.pr), pct(s.sr), pct(s.msr), pct(s.nt2f)])
    if not (vary_d or vary_t or vary_p):
        blocks = [0, 2, 3] if len(rows) >= 4 else [0]
    stub = (["Dataset"] if vary_d else []) + (["VOT"] if vary_t else []) + (["Protocol"] if vary_p else []) + \
        ["Configuration", "Ego motion", "EKF", "Score", "Details"]
    return Table("ablation", CAPTIONS["ablation"], stub, [], ["PR", "SR", "MSR", "NT2F"], rows, blocks)


def embedded_role(run: PlacedRun) -> str | None:
    """The protocol's ``paper_role`` (a plugin class attribute), the column group of Table 4 it
    fills: ``Embedded`` (the tracker's measured wall time sets its rate and latency), ``EOP`` or
    ``LTP``; anything else is not part of Table 4."""
    return getattr(_plugin_class("protocol", run.config.get("protocol")), "paper_role", None)


def _tracker_hz(run: PlacedRun) -> float:
    f = run.scores.frequencies.get("tracker")
    return f.scheduled_hz if f is not None else float("nan")


def _diff(a: float, b: float) -> str:
    return "-" if not (math.isfinite(a) and math.isfinite(b)) else f"{100.0 * abs(a - b):.1f}"


def embedded_table(runs: Sequence[PlacedRun]) -> Table:
    """Paper Table 4: per tracker x MATA, the embedded measurement's SR, NT2F, Freq., then
    |SR - SR_embedded|, |NT2F - NT2F_embedded| and Freq. of EOP and of LTP. A note gives the mean
    discrepancies and their LTP / EOP ratio (the paper's "6.4x for SR and 4.7x for NT2F")."""
    cells: dict = {}
    for r in runs:
        role = embedded_role(r)
        if role not in EMBEDDED_ROLES:
            raise PlacementError(f"embedded table: run {r.name!r} ({r.scores.path}) uses protocol {r.protocol!r}; "
                                 f"expected a protocol whose paper_role is one of {', '.join(EMBEDDED_ROLES)}")
        _unique(cells, (r.dataset_key, r.tracker, r.mata, role), r, "embedded")
    rows, blocks = [], []
    diffs: dict[str, list[tuple[float, float]]] = {"EOP": [], "LTP": []}
    for dkey in _dataset_order(runs):
        for tracker in _tracker_order(runs):
            if not any((dkey, tracker, m, role) in cells for m in (False, True) for role in EMBEDDED_ROLES):
                continue
            blocks.append(len(rows))
            for mata in (False, True):
                emb = cells.get((dkey, tracker, mata, "Embedded"))
                if emb is None and not any((dkey, tracker, mata, ro) in cells for ro in ("EOP", "LTP")):
                    continue
                e = emb.scores.summary.overall if emb else None
                row = [tracker, mark(mata)]
                row += [pct(e.sr), pct(e.nt2f), f"{_tracker_hz(emb):.1f}"] if e else ["-", "-", "-"]
                for role in ("EOP", "LTP"):
                    r = cells.get((dkey, tracker, mata, role))
                    if r is None:
                        row += ["-", "-", "-"]
                        continue
                    s = r.scores.summary.overall
                    if e is not None:
                        row += [_diff(s.sr, e.sr), _diff(s.nt2f, e.nt2f)]
                        diffs[role].append((abs(s.sr - e.sr), abs(s.nt2f - e.nt2f)))
                    else:
                        row += ["-", "-"]
                    row.append(f"{_tracker_hz(r):.1f}")
                rows.append(row)
    notes = []
    if diffs["EOP"] and diffs["LTP"]:
        def mean(role, k):
            vals = [d[k] for d in diffs[role] if math.isfinite(d[k])]
            return sum(vals) / len(vals) if vals else float("nan")
        for k, m in ((0, "SR"), (1, "NT2F")):
            e, l_ = mean("EOP", k), mean("LTP", k)
            ratio = (f"LTP / EOP = {l_ / e:.1f}x" if e > 0 else     # not "infx" when EOP is exact
                     "EOP equals the embedded runs" if e == 0 else "no finite difference")
            notes.append(f"mean |Delta {m}|: EOP {100 * e:.1f}, LTP {100 * l_:.1f} points ({ratio})")
    return Table("embedded", CAPTIONS["embedded"], ["VOT", "MATA"],
                      [("Embedded", 3), ("EOP", 3), ("LTP", 3)],
                      ["SR", "NT2F", "Freq.", "|dSR|", "|dNT2F|", "Freq.", "|dSR|", "|dNT2F|", "Freq."], rows, blocks,
                      notes)


def sequence_comparison(base: RunScores, other: RunScores) -> Table:
    """Per-sequence evidence for a pair of runs (e.g. baseline and MATA): attributes, SR and NT2F
    of each, their difference in points, and the frame of the first failure (NT2F's T_f; "-"
    when the tracker never failed). Sequences in both runs, in the base run's order; the last
    row is the mean (the tables' value)."""
    common = [s for s in base.sequences if s in other.sequences]
    if not common:
        raise PlacementError(f"runs {base.name!r} and {other.name!r} have no sequence in common")
    rows = []

    def ff(v):
        return "-" if v is None else str(v)

    for s in common:
        a, b = base.sequences[s], other.sequences[s]
        attrs = " ".join(sorted(base.attributes.get(s, ())))
        rows.append([s, attrs, pct(a.sr), pct(b.sr), _signed(b.sr - a.sr), pct(a.nt2f), pct(b.nt2f),
                     _signed(b.nt2f - a.nt2f), ff(a.failure_frame), ff(b.failure_frame)])

    # each metric's means over the sequences where it is defined in both runs (QA pass: A's mean
    # over 2 and B's over 3 were subtracted)
    both = {m: [s for s in common if math.isfinite(getattr(base.sequences[s], m))
                and math.isfinite(getattr(other.sequences[s], m))] for m in ("sr", "nt2f")}

    def mean(run, m):
        vals = [getattr(run.sequences[s], m) for s in both[m]]
        return sum(vals) / len(vals) if vals else float("nan")

    ma, mb = {m: mean(base, m) for m in ("sr", "nt2f")}, {m: mean(other, m) for m in ("sr", "nt2f")}
    rows.append([f"mean ({len(common)})", "", pct(ma["sr"]), pct(mb["sr"]), _signed(mb["sr"] - ma["sr"]),
                 pct(ma["nt2f"]), pct(mb["nt2f"]), _signed(mb["nt2f"] - ma["nt2f"]), "", ""])
    notes = [f"A: {base.name} ({base.path}); B: {other.name} ({other.path})"]
    notes += [f"{m.upper()} means over the {len(both[m])} sequence(s) where both runs have it"
              for m in ("sr", "nt2f") if len(both[m]) != len(common)]
    if base.profile != other.profile:
        notes.append(f"A and B are scored under different metric profiles ({base.profile}, {other.profile}): "
                     "their numbers do not compare")

    def why(run: RunScores, label: str, s: str) -> str:
        return f"failed in {label}" if s in run.failures else f"no result in {label}"

    left = [f"{s} ({why(other, 'B', s)})" for s in base.sequences if s not in other.sequences] + \
           [f"{s} ({why(base, 'A', s)})" for s in other.sequences if s not in base.sequences]
    if left:
        notes.append(f"not in both runs, left out: {', '.join(left)}")
    return Table("sequences", f"Per sequence: {base.name} (A) against {other.name} (B).",
                 ["Sequence", "Attributes"], [("SR", 3), ("NT2F", 3), ("First failure", 2)],
                 ["A", "B", "B-A", "A", "B", "B-A", "A", "B"], rows, [len(rows) - 1], notes)


def _signed(v: float) -> str:
    return "-" if not math.isfinite(v) else f"{100.0 * v:+.1f}"


BUILDERS: dict[str, Callable[[Sequence[PlacedRun]], Table]] = {
    "protocols": protocols_table, "challenges": challenges_table,
    "ablation": ablation_table, "embedded": embedded_table,
}


def build_table(kind: str, runs: Sequence[PlacedRun]) -> Table:
    if kind not in BUILDERS:
        raise ValueError(f"unknown paper table {kind!r}; expected one of {', '.join(PAPER_TABLES)}")
    if not runs:
        raise PlacementError(f"{kind} table: no runs given")
    t = BUILDERS[kind](list(runs))
    profiles = sorted({r.scores.profile for r in runs})
    if len(profiles) > 1:   # (QA pass: rows of two profiles side by side without a word)
        t.notes.append(f"these rows are scored under different metric profiles ({', '.join(profiles)}): "
                       "their numbers do not compare")
    for r in runs:  # a mean over fewer sequences must not pass unnoticed
        if r.scores.failures or r.scores.missing:
            t.notes.append(f"{r.name}: {len(r.scores.failures)} failed and {len(r.scores.missing)} missing "
                           f"sequence(s) are not in its means (over {r.scores.summary.overall.n_sequences} sequence(s))")
        if mixed := r.scores.meta.get("mixed_versions"):   # a run resumed after an upgrade
            t.notes.append(f"{r.name}: its results were made with different package versions ({versions_line(mixed)})")
    return t


def run_meta(runs: Sequence[PlacedRun]) -> list[str]:
    """Provenance lines for the summary: experiments, commits and machines of the runs (of
    every setup that made their scored results: a resumed run may have several)."""
    from ..run import results

    exps, commits, machines = [], [], []
    for r in runs:
        m = results.read_manifest(Path(r.scores.path)) if Path(r.scores.path).is_dir() else None
        if not m:
            continue
        made = [(exps, m.get("experiment"))]
        for setup in results.setups_of(m, r.scores.sequences) or [results.setup_identity(m)]:
            made += [(commits, setup.get("git_commit")), (machines, _machine_line(setup.get("machine")))]
        for lst, v in made:
            if v and v not in lst:
                lst.append(v)
    out = [f"{len({r.scores.path for r in runs})} run(s); metric profile {', '.join(sorted({r.scores.profile for r in runs}))}"]
    if exps:
        out.append("experiments: " + ", ".join(exps))
    if commits:
        out.append("git commit: " + ", ".join(str(c)[:12] for c in commits))
    if machines:
        out.append("machine: " + "; ".join(machines))
    return out


def _machine_line(m: Any) -> str | None:
    if not isinstance(m, Mapping):
        return None
    return ", ".join(f"{k}={v}" for k, v in m.items())


def write_paper_report(sections: Sequence[tuple[str, Sequence[PlacedRun]]], out: Path,
                       plots: bool = True) -> list[Path]:
    """For each (table kind, runs): ``<kind>.md``, ``<kind>.tex`` and the success / precision /
    NT2F plots of those runs in ``<kind>/``; then ``summary.html``, one page with every table and
    its plots embedded. Returns the written paths."""
    from .plots import plot_curves

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    written: list[Path] = []
    body = []
    all_runs: list[PlacedRun] = []
    for kind, runs in sections:
        t = build_table(kind, runs)
        all_runs += list(runs)
        for fmt, ext in (("markdown", "md"), ("latex", "tex")):
            p = out / f"{t.key}.{ext}"
            p.write_text(render(t, fmt))
            written.append(p)
        pngs = plot_curves([r.scores for r in runs], out / t.key) if plots else []
        written += pngs
        body.append((t, pngs))
    title = "mata-eval report: " + ", ".join(t.key for t, _ in body)
    p = out / "summary.html"
    p.write_text(html_summary(title, body, run_meta(all_runs)))
    written.append(p)
    return written


def experiment_runs(path: str) -> tuple[str, list[str], list[str]]:
    """(experiment name, its run folders that exist, the names of its runs without one) of an
    experiment file."""
    from ..run.config import load_experiment

    exp = load_experiment(path)
    dirs = [str(exp.output / r.name) for r in exp.runs if (exp.output / r.name).is_dir()]
    if not dirs:
        raise FileNotFoundError(f"{path}: none of its {len(exp.runs)} run folders exists under {exp.output}; "
                                f"run `mata-eval run {path}` first")
    return exp.name, dirs, [r.name for r in exp.runs if not (exp.output / r.name).is_dir()]
