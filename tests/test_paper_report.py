"""The paper's tables from run folders: placement from manifests, hand-computed cell values,
Markdown / LaTeX / HTML structure, and the report CLI."""

from __future__ import annotations

import base64
import re
from html.parser import HTMLParser
from pathlib import Path

import numpy as np
import pytest

from mata_eval import cli
from mata_eval.run import results
from mata_eval.score.evaluate import evaluate_run
from mata_eval.report.paper import PlacementError, build_table, load_runs
from mata_eval.report.tables import render, to_latex
from mata_eval.core.sequence import Sequence

N = 20  # frames per sequence; 30 fps -> 2/3 s of camera time
GT = np.array([10.0, 10.0, 20.0, 20.0])
AWAY = np.array([200.0, 200.0, 20.0, 20.0])  # IoU 0 with GT

EKF = {"name": "homography_ekf", "model": "cv", "camera": True, "gating": True, "delay": "ignore"}


def config(tracker="kcf", mata=False, protocol=None, occ=False, dataset="synthetic", **over):
    cfg = {"dataset": {"name": dataset}, "occlusion": {} if occ else None, "tracker": {"name": tracker},
           "egomotion": {"name": "grid_lk"} if mata else None, "estimator": dict(EKF) if mata else None,
           "protocol": protocol or {"name": "ltp"}, "seed": 0, "feedback": True, "metrics": {"profile": "default"}}
    cfg.update(over)
    return cfg


def make_run(root: Path, name: str, cfg: dict, hits: dict[str, int], every: int = 1,
             attrs: dict[str, tuple[str, ...]] | None = None) -> Path:
    """A scored run folder: per sequence, the prediction equals the ground truth on the first
    ``hits`` frames and is disjoint after (so SR = NT2F = PR = hits / N); the tracker starts every
    ``every`` frames (frequency 30 / every Hz)."""
    d = root / name
    results.write_manifest(d, {"experiment": "t", "run": name, "config": cfg, "config_hash": name,
                               "git_commit": "abc123", "machine": {"cpu": "test"}})
    seqs = []
    for seq, h in hits.items():
        boxes = np.array([GT if k < h else AWAY for k in range(N)])
        rows = ["frame,scored,confidence,tracker_ms"]
        rows += [f"{k},1,0.9,{'5.0' if k % every == 0 else ''}" for k in range(N)]
        results.write_sequence(d, seq, boxes, "\n".join(rows) + "\n", "block,event,frame,t\n")
        seqs.append(Sequence(seq, np.tile(GT, (N, 1)), attributes=frozenset((attrs or {}).get(seq, ()))))
    evaluate_run(d, seqs)
    return d


def md_rows(text: str) -> list[list[str]]:
    return [[c.strip() for c in line.strip("|").split("|")] for line in text.splitlines() if line.startswith("|")]


@pytest.fixture
def protocol_runs(tmp_path):
    """2 datasets (clean, +occ) x 3 protocols x KCF x MATA off/on; hits encode the cell."""
    dirs, expect = [], {}
    protos = {"ltp": {"name": "ltp"}, "eop10": {"name": "eop", "tracker_hz": 10},
              "eop30": {"name": "eop", "tracker_hz": 30}}
    h = 1
    for occ in (True, False):  # +occ first on purpose: the table puts the clean set first
        for pname, proto in protos.items():
            for mata in (False, True):
                name = f"{'occ' if occ else 'clean'}-{pname}-{'mata' if mata else 'base'}"
                dirs.append(make_run(tmp_path, name, config(mata=mata, protocol=proto, occ=occ), {"s1": h}))
                expect[name] = h
                h += 1
    return dirs, expect


def test_protocols_table_places_runs_from_manifests(protocol_runs):
    dirs, expect = protocol_runs
    t = build_table("protocols", load_runs(dirs))
    rows = md_rows(render(t, "markdown"))
    assert rows[0] == ["Protocol", "VOT", "MATA", "Synthetic SR", "Synthetic NT2F",
                       "Synthetic+occ SR", "Synthetic+occ NT2F"]
    body = rows[2:]
    # LTP, then EOP from the fastest tracker rate down; baseline before MATA; merged stub cells blank
    assert [r[0] for r in body] == ["LTP", "", "EOP @ 30 Hz", "", "EOP @ 10 Hz", ""]
    assert [r[2] for r in body] == ["✗", "✓"] * 3
    key = {"LTP": "ltp", "EOP @ 30 Hz": "eop30", "EOP @ 10 Hz": "eop10"}
    proto = None
    for r in body:
        proto = key.get(r[0], proto)
        m = "mata" if r[2] == "✓" else "base"
        for col, data in ((3, "clean"), (5, "occ")):
            pct = f"{100 * expect[f'{data}-{proto}-{m}'] / N:.1f}"
            assert r[col] == pct and r[col + 1] == pct  # SR and NT2F both hits / N


def test_protocols_latex_is_booktabs_with_multirow(protocol_runs):
    dirs, _ = protocol_runs
    tex = to_latex(build_table("protocols", load_runs(dirs)))
    assert r"\begin{tabular}{c|c|c|cc|cc}" in tex
    assert tex.count(r"\toprule") == tex.count(r"\bottomrule") == 1
    assert r"\multicolumn{2}{c|}{Synthetic}" in tex and r"\multicolumn{2}{c}{Synthetic+occ}" in tex
    assert r"\multirow{2}{*}{LTP}" in tex and r"\multirow{2}{*}{EOP @ 10 Hz}" in tex
    assert r"\multirow{6}{*}{KCF}" not in tex  # a tracker cell never spans two protocols
    assert tex.count(r"$\checkmark$") == 3 and tex.count(r"$\times$") == 3
    body = tex.split(r"\midrule", 1)[1].split(r"\bottomrule")[0]
    data = [ln for ln in body.splitlines() if ln.strip().endswith(r"\\")]
    assert len(data) == 6 and all(ln.count("&") == 6 for ln in data)


def test_same_cell_twice_is_an_error_naming_both_runs(tmp_path):
    a = make_run(tmp_path, "a", config(), {"s1": 5})
    b = make_run(tmp_path, "b", config(), {"s1": 6})
    with pytest.raises(PlacementError, match=r"'a'.*'b'"):
        build_table("protocols", load_runs([a, b]))


def test_run_without_manifest_cannot_be_placed(tmp_path):
    d = make_run(tmp_path, "a", config(), {"s1": 5})
    (d / "manifest.json").unlink()
    with pytest.raises(PlacementError, match="manifest"):
        load_runs([d])


def test_challenges_table_per_group(tmp_path):
    attrs = {"occ1": ("POC",), "occ2": ("FOC", "FM"), "fast": ("FM",), "plain": ()}
    proto = {"name": "eop", "tracker_hz": 10}
    base = make_run(tmp_path, "base", config(protocol=proto, occ=True),
                    {"occ1": 4, "occ2": 8, "fast": 20, "plain": 20}, attrs=attrs)
    mata = make_run(tmp_path, "mata", config(mata=True, protocol=proto, occ=True),
                    {"occ1": 12, "occ2": 16, "fast": 10, "plain": 20}, attrs=attrs)
    rows = md_rows(render(build_table("challenges", load_runs([mata, base])), "markdown"))
    head = rows[0]
    assert head[:2] == ["VOT", "MATA"]
    assert "Occlusion (2) SR" in head and "High dynamic (2) NT2F" in head and "Distractor (0) SR" in head
    occ, fast, dis = head.index("Occlusion (2) SR"), head.index("High dynamic (2) SR"), head.index("Distractor (0) SR")
    b, m = rows[2], rows[3]  # baseline row first although given second
    assert b[1] == "✗" and m[1] == "✓"
    assert b[occ] == f"{100 * (4 + 8) / 2 / N:.1f}" and m[occ] == f"{100 * (12 + 16) / 2 / N:.1f}"
    assert b[fast] == f"{100 * (8 + 20) / 2 / N:.1f}" and m[fast] == f"{100 * (16 + 10) / 2 / N:.1f}"
    assert b[dis] == "-" and b[dis + 1] == "-"  # an empty group has no value


def test_ablation_says_what_each_row_changes_and_which_protocol_it_ran(tmp_path):
    """QA pass: runs at LTP and EOP landed in one table without saying which row is which, and
    configurations that differ in a preset value or a block B parameter read the same."""
    mata = {"name": "homography_ekf", "preset": "mata"}
    eop = {"name": "eop", "tracker_hz": 10}
    confs = {"2-mata": config(mata=True, estimator=dict(mata)),
             "9-ignore": config(mata=True, estimator={**mata, "delay": "ignore"}),
             "10-qv": config(mata=True, estimator={**mata, "q_v": 1000.0}),
             "12-usac": config(mata=True, estimator=dict(mata),
                               egomotion={"name": "grid_lk", "ransac_method": "usac_fast"})}
    dirs = [make_run(tmp_path, f"{n}-{p}", {**c, "protocol": proto}, {"s": 5})
            for n, c in confs.items() for p, proto in (("ltp", {"name": "ltp"}), ("eop", eop))]
    rows = md_rows(render(build_table("ablation", load_runs(dirs)), "markdown"))
    assert rows[0][:2] == ["Protocol", "Configuration"] and len(rows) == 2 + 8
    assert [r[0] for r in rows[2:] if r[0]] == ["LTP", "EOP @ 10 Hz"]      # one block each, LTP first
    ltp, eop_rows = {r[1]: r[5] for r in rows[2:6]}, {r[1]: r[5] for r in rows[6:10]}
    assert ltp == eop_rows == {"2": "improved block C (preset mata)",
                               "9": "improved block C (preset mata), measurements as current (delay: ignore)",
                               "10": "improved block C (preset mata), q_v = 1000.0",
                               "12": "improved block C (preset mata); grid_lk: ransac_method = usac_fast"}


def test_ablation_rows_marks_and_details(tmp_path):
    proto = {"name": "eop", "tracker_hz": 10}
    confs = {
        "1-baseline": config(protocol=proto),
        "2-mata": config(mata=True, protocol=proto),
        "4-no-camera": config(mata=True, protocol=proto, egomotion=None, estimator={**EKF, "camera": False}),
        "5-ca": config(mata=True, protocol=proto, estimator={**EKF, "model": "ca"}),
        "7-no-threshold": config(mata=True, protocol=proto, estimator={**EKF, "gating": False}),
        "3-score": config(protocol=proto),
    }
    # the tracker plugin says whether a configuration uses the explainable score (mixformerv2 has
    # the choice: `confidence: window` is the paper's PMF window score)
    for c in confs.values():
        c["tracker"] = {"name": "mixformerv2", "confidence": "mlp"}
    confs["3-score"]["tracker"] = {"name": "mixformerv2", "confidence": "window"}
    dirs = [make_run(tmp_path, n, c, {"s": i + 3}) for i, (n, c) in enumerate(confs.items())]
    rows = md_rows(render(build_table("ablation", load_runs(dirs)), "markdown"))
    assert rows[0] == ["Configuration", "Ego motion", "EKF", "Score", "Details", "PR", "SR", "MSR", "NT2F"]
    body = {r[0]: r for r in rows[2:]}
    assert [r[0] for r in rows[2:]] == ["1", "2", "3", "4", "5", "7"]
    assert body["1"][1:5] == ["✗", "✗", "✗", "MixFormerV2 (baseline)"]
    assert body["2"][1:5] == ["✓", "✓", "✗", "MATA, the paper's block C (preset paper)"]
    assert body["3"][1:5] == ["✗", "✗", "✓", "MixFormerV2 (baseline), explainable score"]
    assert body["4"][1:5] == ["✗", "✓", "✗", "no camera compensation"]
    assert body["5"][4] == "constant acceleration model"
    assert body["7"][4] == "no threshold on measurements"
    # values: hits = index + 3 in the given order; MSR of a hit/miss sequence = hits/N * 20/21
    assert body["5"][5:9] == [f"{100 * 6 / N:.1f}", f"{100 * 6 / N:.1f}", f"{100 * 6 / N * 20 / 21:.1f}",
                              f"{100 * 6 / N:.1f}"]


def test_embedded_table_differences_and_frequencies(tmp_path):
    runs = []
    for mata, (he, hp, hl) in ((False, (10, 12, 18)), (True, (14, 13, 20))):
        tag = "mata" if mata else "base"
        runs.append(make_run(tmp_path, f"emb-{tag}", config(mata=mata, protocol={"name": "vot_rt", "time_scale": 6}),
                             {"s": he}, every=3))
        runs.append(make_run(tmp_path, f"eop-{tag}", config(mata=mata, protocol={"name": "eop", "tracker_hz": "profile"}),
                             {"s": hp}, every=2))
        runs.append(make_run(tmp_path, f"ltp-{tag}", config(mata=mata), {"s": hl}, every=1))
    t = build_table("embedded", load_runs(runs))
    rows = md_rows(render(t, "markdown"))
    assert rows[0][:2] == ["VOT", "MATA"] and rows[0][2:5] == ["Embedded SR", "Embedded NT2F", "Embedded Freq."]
    # tracker starts: every 3rd frame of 20 -> 6 intervals after the first in 18 frames (0.6 s) =
    # 10 Hz (the initialisation counted made it 7 starts in 2/3 s, 10.5 Hz); every 2nd -> 15 Hz
    assert rows[2] == ["KCF", "✗", "50.0", "50.0", "10.0", "10.0", "10.0", "15.0", "40.0", "40.0", "30.0"]
    assert rows[3] == ["", "✓", "70.0", "70.0", "10.0", "5.0", "5.0", "15.0", "30.0", "30.0", "30.0"]
    # mean |dSR|: EOP (10 + 5) / 2 = 7.5, LTP (40 + 30) / 2 = 35 -> 4.7x
    assert "mean |Delta SR|: EOP 7.5, LTP 35.0 points (LTP / EOP = 4.7x)" in t.notes
    tex = to_latex(t)  # the paper's column names; differences are absolute (its caption)
    assert r"& SR & NT2F & Freq. & $\Delta$SR & $\Delta$NT2F & Freq. & $\Delta$SR & $\Delta$NT2F & Freq. \\" in tex
    assert "|" not in tex.split(r"\midrule", 1)[1].split(r"\bottomrule")[0]


def test_embedded_table_says_so_when_eop_equals_the_embedded_runs(tmp_path):
    """QA pass: with no EOP difference the note read 'LTP / EOP = infx'."""
    runs = []
    for mata in (False, True):
        tag = "mata" if mata else "base"
        runs.append(make_run(tmp_path, f"emb-{tag}", config(mata=mata, protocol={"name": "vot_rt", "time_scale": 6}),
                             {"s": 10}, every=3))
        runs.append(make_run(tmp_path, f"eop-{tag}", config(mata=mata, protocol={"name": "eop", "tracker_hz": "profile"}),
                             {"s": 10}, every=3))
        runs.append(make_run(tmp_path, f"ltp-{tag}", config(mata=mata), {"s": 18}, every=1))
    notes = build_table("embedded", load_runs(runs)).notes
    assert "mean |Delta SR|: EOP 0.0, LTP 40.0 points (EOP equals the embedded runs)" in notes
    assert not any("inf" in n for n in notes)


def test_embedded_table_rejects_other_protocols(tmp_path):
    d = make_run(tmp_path, "dsp", config(protocol={"name": "dsp", "n": 3}), {"s": 3})
    with pytest.raises(PlacementError, match="paper_role is one of Embedded, EOP, LTP"):
        build_table("embedded", load_runs([d]))


class _Collect(HTMLParser):
    def __init__(self):
        super().__init__()
        self.tags: list[tuple[str, dict]] = []
        self.stack: list[str] = []

    def handle_starttag(self, tag, attrs):
        self.tags.append((tag, dict(attrs)))
        if tag not in ("img", "meta", "br"):
            self.stack.append(tag)

    def handle_endtag(self, tag):
        assert self.stack and self.stack[-1] == tag, f"</{tag}> closes <{self.stack[-1] if self.stack else None}>"
        self.stack.pop()


def test_report_cli_writes_tables_plots_and_one_page_html(protocol_runs, tmp_path, capsys):
    dirs, expect = protocol_runs
    out = tmp_path / "paper"
    assert cli.main(["report", "--paper", "protocols", *map(str, dirs), "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "| Protocol | VOT | MATA |" in printed
    for f in ("protocols.md", "protocols.tex", "summary.html", "protocols/success.png", "protocols/nt2f.png",
              "protocols/precision.png", "protocols/norm_precision.png"):
        assert (out / f).is_file(), f
    page = (out / "summary.html").read_text()
    p = _Collect()
    p.feed(page)
    p.close()
    assert p.stack == []  # every element closed, properly nested
    tags = [t for t, _ in p.tags]
    assert tags.count("html") == 1 and tags.count("table") == 1 and tags.count("link") == 0
    imgs = [a["src"] for t, a in p.tags if t == "img"]
    assert len(imgs) == 4
    pngs = {(out / "protocols" / f).read_bytes() for f in ("success.png", "precision.png", "norm_precision.png",
                                                            "nt2f.png")}
    decoded = {base64.b64decode(s.split(",", 1)[1]) for s in imgs}
    assert all(s.startswith("data:image/png;base64,") for s in imgs) and decoded == pngs
    # the HTML table carries the same numbers as the Markdown one
    cells = re.findall(r"<td>([^<]*)</td>", page)
    assert cells.count(f"{100 * expect['occ-eop10-mata'] / N:.1f}") >= 2
    assert 'rowspan="2"' in page and 'colspan="2"' in page


def test_report_cli_experiment_files(tmp_path, capsys):
    exp = tmp_path / "protocols.yaml"
    out = tmp_path / "res"
    exp.write_text(f"name: protocols\noutput: {out}\ndataset: {{name: synthetic}}\ntracker: {{name: kcf}}\n"
                   "matrix:\n  mata:\n    baseline: {}\n    mata: {estimator: {name: homography_ekf}}\n")
    make_run(out, "baseline", config(), {"s": 4})
    make_run(out, "mata", config(mata=True), {"s": 6})
    assert cli.main(["report", "--experiment", str(exp)]) == 0  # --paper auto: the table named like it
    rows = md_rows(capsys.readouterr().out)
    assert rows[2] == ["LTP", "KCF", "✗", "20.0", "20.0"] and rows[3] == ["", "", "✓", "30.0", "30.0"]
    # a run of the file without a folder yet is named (QA pass 14: left out of the table silently)
    exp.write_text(exp.read_text() + "    paper: {estimator: {name: homography_ekf, preset: paper}}\n")
    assert cli.main(["report", "--experiment", str(exp)]) == 0
    assert (f"{exp}: 1 of 3 runs have no results yet, not in the report: paper"
            in capsys.readouterr().err)
    exp.write_text(exp.read_text().replace("    paper: {estimator: {name: homography_ekf, preset: paper}}\n", ""))
    # a zero-order hold only holds the tracker's box: it is a baseline, in the baseline's cell
    make_run(out, "mata", config(estimator={"name": "zoh"}), {"s": 6})
    assert cli.main(["report", "--experiment", str(exp)]) == 2
    assert "same cell" in capsys.readouterr().err
    other = tmp_path / "other.yaml"
    other.write_text(exp.read_text().replace("name: protocols", "name: other"))
    assert cli.main(["report", "--experiment", str(other)]) == 0  # not a paper table: the run table
    lines = capsys.readouterr().out.splitlines()
    rows = {line.split()[0]: line.split() for line in lines[2:4]}
    assert lines[0].split()[:3] == ["Run", "Seqs", "SR"] and rows["baseline"][2] == "20.0" and rows["mata"][2] == "30.0"
    assert any(line.startswith("- SR: success rate") for line in lines)
    # with --out it says why there is no summary.html (QA pass: silent)
    assert cli.main(["report", "--experiment", str(other), "--out", str(tmp_path / "rep")]) == 0
    assert "no summary.html: no experiment here is one of the paper's tables" in capsys.readouterr().out
    assert not (tmp_path / "rep" / "summary.html").exists()


def test_per_sequence_comparison_cli(tmp_path, capsys):
    a = make_run(tmp_path, "a", config(), {"s1": 4, "s2": 20}, attrs={"s1": ("POC",)})
    b = make_run(tmp_path, "b", config(mata=True), {"s1": 10, "s2": 16}, attrs={"s1": ("POC",)})
    assert cli.main(["report", "--per-sequence", str(a), str(b)]) == 0
    rows = md_rows(capsys.readouterr().out)
    assert rows[0] == ["Sequence", "Attributes", "SR A", "SR B", "SR B-A", "NT2F A", "NT2F B", "NT2F B-A",
                       "First failure A", "First failure B"]
    assert rows[2] == ["s1", "POC", "20.0", "50.0", "+30.0", "20.0", "50.0", "+30.0", "4", "10"]
    assert rows[3] == ["s2", "", "100.0", "80.0", "-20.0", "100.0", "80.0", "-20.0", "-", "16"]
    assert rows[4] == ["mean (2)", "", "60.0", "65.0", "+5.0", "60.0", "65.0", "+5.0", "", ""]
    assert cli.main(["report", "--per-sequence", str(a)]) == 2
    # which run is A and which B, and what is left out, are said under the table (QA pass)
    c = make_run(tmp_path, "c", config(mata=True), {"s1": 10}, attrs={"s1": ("POC",)})
    assert cli.main(["report", "--per-sequence", str(a), str(c)]) == 0
    text = capsys.readouterr().out
    assert f"- A: a ({a}); B: c ({c})" in text and "- not in both runs, left out: s2 (no result in B)" in text
    # --format and --out are honoured (QA pass: they were ignored, Markdown always printed)
    capsys.readouterr()
    assert cli.main(["report", "--per-sequence", str(a), str(b), "--format", "csv"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].startswith("Sequence,Attributes,SR A") and lines[1].startswith("s1,POC,20")
    out = tmp_path / "rep"
    assert cli.main(["report", "--per-sequence", str(a), str(b), "--out", str(out), "--format", "all"]) == 0
    assert sorted(p.name for p in out.iterdir()) == ["per_sequence.csv", "per_sequence.md", "per_sequence.tex"]
    assert (out / "per_sequence.csv").read_text().splitlines()[2].startswith("s2,,100")
    # `report <output>/*/` picks up the plots folder `run` writes beside the runs: skipped, said
    plots = a.parent / "report"
    plots.mkdir()
    (plots / "success.png").write_bytes(b"")
    capsys.readouterr()
    assert cli.main(["report", str(a), str(plots), str(b)]) == 0
    text, err = capsys.readouterr()
    # on stderr: `report ... --format csv > file` got it as the CSV's first line (QA pass 16e)
    assert f"skipped {plots}: the plots `mata-eval run` writes beside the runs, not a run" in err
    assert [line.split()[0] for line in text.splitlines()[2:4]] == ["a", "b"]   # both runs, in order


def test_ablation_with_two_trackers_groups_rows_by_tracker(tmp_path):
    proto = {"name": "eop", "tracker_hz": 10}
    comp = {**EKF, "delay": "compensate", "tau_ewma": 0.05}
    dirs = [make_run(tmp_path, "v-mata", config("vittrack", mata=True, protocol=proto), {"s": 8}),
            make_run(tmp_path, "k-base", config("kcf", protocol=proto), {"s": 4}),
            make_run(tmp_path, "k-comp", config("kcf", mata=True, protocol=proto, estimator=comp), {"s": 6})]
    rows = md_rows(render(build_table("ablation", load_runs(dirs)), "markdown"))
    assert rows[0][:2] == ["VOT", "Configuration"]
    assert [(r[0], r[5]) for r in rows[2:]] == [
        ("VitTrack", "MATA, the paper's block C (preset paper)"), ("KCF", "KCF (baseline)"),
        ("", "delay compensation, confidence gate tau_ewma = 0.05")]


def test_failed_sequences_are_noted_under_the_table(tmp_path):
    d = make_run(tmp_path, "a", config(), {"s1": 5})
    results.write_failure(d, "s2", "BlockError: tracker failed", "traceback")
    assert not (d / "scores.json").exists()  # the failure made the run's old scores stale
    evaluate_run(d, [Sequence("s1", np.tile(GT, (N, 1))), Sequence("s2", np.tile(GT, (N, 1)))])
    t = build_table("protocols", load_runs([d]))
    assert t.notes == ["a: 1 failed and 0 missing sequence(s) are not in its means (over 1 sequence(s))"]
    assert "- a: 1 failed" in render(t, "markdown")


def test_mata_minus_baseline_pairs_a_run_of_an_installed_plugin_with_its_baseline(tmp_path):
    """QA pass: a third-party block B or C is recorded as `plugin_versions` in the MATA run's
    configuration only; the run then found no baseline and left the table."""
    from mata_eval.report.overview import mata_deltas

    base = make_run(tmp_path, "1-baseline", config(), {"s": 5})
    mata = make_run(tmp_path, "2-orb", config(mata=True, egomotion={"name": "orb_ransac"},
                                             plugin_versions={"qa-myblocks": "0.1.0"}), {"s": 8})
    t = mata_deltas([r.scores for r in load_runs([base, mata])])
    assert t is not None
    (row,) = t.rows
    assert row[2] == "2-orb - 1-baseline" and row[3] == "+15.0"   # SR 8/20 - 5/20


def test_mata_minus_baseline_takes_the_baseline_of_its_own_output_and_tracker_version(tmp_path):
    """Review: two outputs of one experiment (report jetson/* desktop/*) paired every MATA run
    with the first baseline found, and a MATA run of an upgraded tracker package with the old
    one's baseline."""
    from mata_eval.report.overview import mata_deltas

    dirs = [make_run(tmp_path / "jetson", "1-baseline", config(), {"s": 2}),
            make_run(tmp_path / "desktop", "1-baseline", config(), {"s": 6}),
            make_run(tmp_path / "desktop", "2-mata", config(mata=True), {"s": 8})]
    (row,) = mata_deltas([r.scores for r in load_runs(dirs)]).rows
    assert row[3] == "+10.0"   # SR 8/20 - 6/20 (the jetson baseline's would be +30.0)
    old = make_run(tmp_path / "v", "1-baseline", config(plugin_versions={"qa-trk": "0.1"}), {"s": 5})
    new = make_run(tmp_path / "v", "2-mata", config(mata=True, plugin_versions={"qa-trk": "0.2", "qa-ego": "1"}),
                   {"s": 8})
    assert mata_deltas([r.scores for r in load_runs([old, new])]) is None
    same = make_run(tmp_path / "w", "2-mata", config(mata=True, plugin_versions={"qa-trk": "0.1", "qa-ego": "1"}),
                    {"s": 8})
    assert mata_deltas([r.scores for r in load_runs([old, same])]).rows[0][3] == "+15.0"
    # a baseline estimator (zoh: baseline = True) makes a baseline too; the tracker alone first
    # (QA pass: only egomotion: null, estimator: null was taken for one)
    zoh = make_run(tmp_path / "z", "1-zoh", config(estimator={"name": "zoh"}), {"s": 4})
    mata = make_run(tmp_path / "z", "2-mata", config(mata=True), {"s": 8})
    (row,) = mata_deltas([r.scores for r in load_runs([zoh, mata])]).rows
    assert row[2:4] == ["2-mata - 1-zoh", "+20.0"]
    alone = make_run(tmp_path / "z", "0-alone", config(), {"s": 6})
    ego_only = make_run(tmp_path / "z", "1-ego", config(egomotion={"name": "grid_lk"}), {"s": 3})
    (row,) = mata_deltas([r.scores for r in load_runs([zoh, ego_only, mata, alone])]).rows
    assert row[2:4] == ["2-mata - 0-alone", "+10.0"]


def test_ablation_keeps_clean_and_occluded_runs_apart_and_their_numbers(tmp_path):
    """QA pass: a matrix with a data axis (clean / occ) put both sets' rows in one block, with no
    Dataset column, and numbered them 1..10 (run names do not start with the number)."""
    proto = {"name": "eop", "tracker_hz": 10}
    dirs = []
    for data, occ in (("occ", True), ("clean", False)):   # occ first: the clean set comes first
        dirs += [make_run(tmp_path, f"{data}-1-baseline-eop10", config(protocol=proto, occ=occ), {"s": 4 + occ}),
                 make_run(tmp_path, f"{data}-2-mata-eop10", config(mata=True, protocol=proto, occ=occ), {"s": 8 + occ})]
    rows = md_rows(render(build_table("ablation", load_runs(dirs)), "markdown"))
    assert rows[0][:2] == ["Dataset", "Configuration"]
    assert [(r[0], r[1], r[7]) for r in rows[2:]] == [
        ("Synthetic", "1", "20.0"), ("", "2", "40.0"), ("Synthetic+occ", "1", "25.0"), ("", "2", "45.0")]


def test_ablation_names_a_block_b_of_its_own_and_a_plugin_label(tmp_path, monkeypatch):
    """QA pass: ORB + RANSAC in place of grid LK read the same as MATA, and an estimator without
    ablation() was named by its YAML name, not its label."""
    (tmp_path / "qa_abl_blocks.py").write_text(
        "from dataclasses import dataclass\n"
        "class Orb:\n    name, label = 'orb', 'ORB+RANSAC'\n"
        "    @dataclass(frozen=True)\n    class Params:\n        pass\n"
        "    def initialize(self, image): pass\n    def estimate(self, image): pass\n"
        "class Hold:\n    name, label = 'hold', 'Hold filter'\n"
        "    @dataclass(frozen=True)\n    class Params:\n        pass\n"
        "    def initialize(self, box, t): pass\n    def step(self, t, motions=(), detections=()): pass\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    confs = {"2-mata": config(mata=True),
             "3-orb": config(mata=True, egomotion={"name": "qa_abl_blocks:Orb"}),
             "4-hold": config(mata=True, estimator={"name": "qa_abl_blocks:Hold"})}
    dirs = [make_run(tmp_path / "runs", n, c, {"s": 5}) for n, c in confs.items()]
    rows = md_rows(render(build_table("ablation", load_runs(dirs)), "markdown"))
    assert {r[0]: r[4] for r in rows[2:]} == {   # two blocks B in the table: each row names its own
        "2": "MATA, the paper's block C (preset paper); block B: grid_lk",
        "3": "MATA, the paper's block C (preset paper); block B: ORB+RANSAC",
        "4": "estimator Hold filter; block B: grid_lk"}
    one = md_rows(render(build_table("ablation", load_runs(dirs[1:2])), "markdown"))
    assert one[2][4] == "MATA, the paper's block C (preset paper); block B: ORB+RANSAC"   # not mata-eval's


@pytest.mark.parametrize("module, ablation, words", [
    # QA pass: ablation() written as an instance method gave a raw TypeError from the report
    ("qa_abl_instance", "    def ablation(self, params, egomotion): return (egomotion, True, 'hold')\n",
     r"is not a classmethod; expected @classmethod .* \(ego-motion used"),
    # QA pass: a classmethod ablation() raising KeyError printed a 31-line traceback and no table
    ("qa_abl_raise", "    @classmethod\n    def ablation(cls, params, egomotion): return params['use_motion']\n",
     r"raised KeyError: 'use_motion'$"),
])
def test_an_estimator_ablation_that_breaks_its_contract_is_named(tmp_path, monkeypatch, module, ablation, words):
    (tmp_path / f"{module}.py").write_text(
        "from dataclasses import dataclass\n"
        "class Hold:\n    name = 'hold'\n"
        "    @dataclass(frozen=True)\n    class Params:\n        pass\n"
        "    def initialize(self, box, t): pass\n    def step(self, t, motions=(), detections=()): pass\n" + ablation)
    monkeypatch.syspath_prepend(str(tmp_path))
    d = make_run(tmp_path / "runs", "2-hold", config(mata=True, estimator={"name": f"{module}:Hold"}), {"s": 5})
    with pytest.raises(PlacementError, match=rf"^estimator '{module}:Hold': ablation\(params, egomotion\) {words}"):
        build_table("ablation", load_runs([d]))


def test_tables_of_runs_under_different_metric_profiles_say_so(tmp_path):
    """QA pass 14: rows scored under two metric profiles sat side by side in the paper tables,
    the per-sequence table and MATA minus its baseline without a word, and the per-sequence
    mean subtracted A's mean over 2 sequences from B's over 3."""
    import dataclasses

    from mata_eval.report.overview import mata_deltas
    from mata_eval.report.paper import sequence_comparison
    from mata_eval.score.evaluate import load_scores

    a = load_scores(make_run(tmp_path, "a", config(), {"s1": 4, "s2": 20, "s3": 10}))
    b = load_scores(make_run(tmp_path, "b", config(mata=True), {"s1": 10, "s2": 16, "s3": 10}))
    b = dataclasses.replace(b, profile="pysot-toolkit")
    a = dataclasses.replace(a, sequences={**a.sequences, "s3": dataclasses.replace(a.sequences["s3"], sr=float("nan"))})
    t = sequence_comparison(a, b)
    assert t.rows[-1][:5] == ["mean (3)", "", "60.0", "65.0", "+5.0"]   # SR over s1, s2: where both have it
    assert "SR means over the 2 sequence(s) where both runs have it" in t.notes
    assert "A and B are scored under different metric profiles (default, pysot-toolkit): their numbers do not " \
           "compare" in t.notes
    t = mata_deltas([a, b])                                             # not a MATA-minus-baseline row: said
    assert not t.rows and t.notes == ["b: its baseline is scored under another metric profile; not compared"]
    placed = load_runs([str(tmp_path / "a"), str(tmp_path / "b")])
    placed = [dataclasses.replace(placed[0], scores=a), dataclasses.replace(placed[1], scores=b)]
    assert "these rows are scored under different metric profiles (default, pysot-toolkit): their numbers do " \
           "not compare" in build_table("protocols", placed).notes


def test_mata_minus_baseline_is_written_in_every_format(tmp_path, capsys):
    """QA pass 14: the table the README calls the experiment's takeaway existed on the terminal only."""
    a = make_run(tmp_path, "a", config(), {"s1": 4, "s2": 20})
    b = make_run(tmp_path, "b", config(mata=True), {"s1": 10, "s2": 16})
    out = tmp_path / "rep"
    assert cli.main(["report", str(a), str(b), "--format", "all", "--out", str(out), "--no-plots"]) == 0
    assert {p.name for p in out.glob("mata_vs_baseline.*")} == {f"mata_vs_baseline.{e}" for e in ("txt", "md", "csv", "tex")}
    md = (out / "mata_vs_baseline.md").read_text()
    assert md.startswith("MATA minus its baseline, in points") and "+5.0" in md          # SR 60.0 -> 65.0
    capsys.readouterr()
    assert cli.main(["report", str(a), str(b), "--format", "csv"]) == 0   # stdout: the one table (> file.csv)
    assert len(capsys.readouterr().out.strip().splitlines()) == 3
    assert cli.main(["report", str(a), "--out", str(out), "--no-plots"]) == 0   # no pair: no stale file,
    assert not list(out.glob("mata_vs_baseline.*"))                                # in any format (review)


def test_one_folder_scored_under_several_profiles_gives_rows_told_apart(tmp_path):
    """QA pass 14: `eval --profile P --output two_P` for three profiles gave three rows named `two`."""
    import dataclasses

    from mata_eval.report.overview import distinct_names
    from mata_eval.score.evaluate import load_scores

    a = load_scores(make_run(tmp_path, "two", config(), {"s1": 4}))
    runs = [dataclasses.replace(a, profile=p) for p in ("default", "pysot-toolkit", "got10k")]
    where = tmp_path.name
    assert [r.name for r in distinct_names(runs)] == ["two (default)", "two (pysot-toolkit)", "two (got10k)"]
    assert [r.name for r in distinct_names([a, a])] == ["two (default, 1)", "two (default, 2)"]
    # two outputs of one run name keep their folder labels beside a profile copy (review)
    b = load_scores(make_run(tmp_path / "out2", "two", config(), {"s1": 4}))
    names = [r.name for r in distinct_names([a, b, dataclasses.replace(a, profile="got10k")])]
    assert names == [f"two ({where}, default)", "two (out2)", f"two ({where}, got10k)"]
    # two machines' outputs, each scored under two profiles: the machine and the profile (review)
    jetson = load_scores(make_run(tmp_path / "jetson" / "results", "two", config(), {"s1": 4}))
    desktop = load_scores(make_run(tmp_path / "desktop" / "results", "two", config(), {"s1": 4}))
    both = [r2 for r in (jetson, desktop) for r2 in (r, dataclasses.replace(r, profile="got10k"))]
    assert [r.name for r in distinct_names(both)] == [
        "two (jetson/results, default)", "two (jetson/results, got10k)",
        "two (desktop/results, default)", "two (desktop/results, got10k)"]


def test_results_of_several_package_versions_are_noted_and_every_setup_is_in_the_summary(tmp_path):
    """A run resumed after an upgrade (manifest ``setups`` / ``made_by``): the paper table notes
    the packages whose versions differ, and the summary's provenance lists each setup's commit
    and machine, not only the last run's (QA pass: neither was said)."""
    from mata_eval.report.paper import run_meta

    d = make_run(tmp_path, "a", config(), {"s1": 5, "s2": 5})
    manifest = results.read_manifest(d)
    old = {"versions": {"numpy": "1.26.4"}, "environment": {}, "git_commit": "0ld", "machine": {"cpu": "laptop"}}
    new = {"versions": {"numpy": "2.1.0"}, "environment": {}, "git_commit": "abc123", "machine": {"cpu": "test"}}
    results.write_manifest(d, {**manifest, "setups": [old, new], "made_by": {"s1": 0, "s2": 1}})
    evaluate_run(d, [Sequence(s, np.tile(GT, (N, 1))) for s in ("s1", "s2")])
    runs = load_runs([d])
    assert build_table("protocols", runs).notes == [
        "a: its results were made with different package versions (numpy 1.26.4, 2.1.0)"]
    meta = run_meta(runs)
    assert "git commit: 0ld, abc123" in meta and "machine: cpu=laptop; cpu=test" in meta
    # a setup whose results are no longer scored (a sequence removed from the list) is not listed
    evaluate_run(d, [Sequence("s2", np.tile(GT, (N, 1)))])
    assert "git commit: abc123" in run_meta(load_runs([d]))
