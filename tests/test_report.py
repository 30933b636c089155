"""Reports: every table format carries the numbers of the scores (percentages, one decimal;
CSV at full precision), LaTeX is booktabs, plots are real PNG files, and the report command
evaluates a run folder only when it can."""

from __future__ import annotations

import csv
import io

import cv2
import numpy as np
import pytest

from mata_eval import cli
from mata_eval.report import overview, plots
from mata_eval.score import evaluate, metrics
from mata_eval.score.metrics import BlockFrequency
from mata_eval.core.sequence import Sequence


def run_scores(name: str, lost_at: list[int], attrs: list[set[str]]) -> evaluate.RunScores:
    seqs, items = {}, []
    for i, (k, a) in enumerate(zip(lost_at, attrs)):
        gt = np.tile([10.0, 10.0, 20.0, 20.0], (20, 1))
        pred = gt.copy()
        pred[k:, 0] += 100
        s = metrics.score_sequence(pred, gt)
        seqs[f"s{i}"] = s
        items.append((s, a))
    return evaluate.RunScores(
        name=name, path="/nowhere", profile="default", layout="mata", sequences=seqs,
        attributes={f"s{i}": tuple(sorted(a)) for i, a in enumerate(attrs)},
        summary=metrics.aggregate(items),
        failures={"bad": "boom"},
        frequencies={"tracker": BlockFrequency(starts=10, camera_seconds=1.0, total_ms=250.0)},
    )


@pytest.fixture
def runs():
    return [run_scores("ostrack_mata", [20, 10], [{"FOC"}, {"FM"}]),
            run_scores("base & co", [5, 15], [{"POC"}, {"OV", "SOB"}])]


def test_terminal_table_has_percentages_with_one_decimal(runs):
    text = overview.render_table(runs, "terminal")
    lines = text.strip().splitlines()
    assert lines[0].split()[:7] == ["Run", "Seqs", "SR", "MSR", "PR", "P@20", "NT2F"]
    row = lines[2].split()
    # ostrack_mata: NT2F of the two sequences 20/20 and 10/20 -> 75.0 %
    assert row[0] == "ostrack_mata" and row[1] == "2" and row[6] == "75.0"
    assert "10.0 (40.0)" in lines[2]  # tracker 10 Hz scheduled, 40 Hz wall clock
    assert lines[2].split()[-1] == "1"  # one failed sequence


def test_markdown_table(runs):
    lines = overview.render_table(runs, "markdown").strip().splitlines()
    assert lines[0].startswith("| Run | Seqs | SR |") and set(lines[1]) <= set("|:-")
    cells = [c.strip() for c in lines[3].strip("|").split("|")]
    assert cells[0] == "base & co" and cells[6] == "50.0"  # NT2F (5 + 15) / 40


def test_csv_keeps_full_precision(runs):
    rows = list(csv.DictReader(io.StringIO(overview.render_table(runs, "csv"))))
    assert [r["run"] for r in rows] == ["ostrack_mata", "base & co"]
    assert float(rows[0]["nt2f"]) == pytest.approx(0.75)
    assert float(rows[0]["msr"]) == pytest.approx(runs[0].summary.overall.msr, abs=1e-6)
    assert float(rows[0]["tracker_wall_hz"]) == pytest.approx(40.0)
    assert rows[0]["failed"] == "1"
    groups = list(csv.DictReader(io.StringIO(overview.render_table(runs, "csv", table="challenges"))))
    occ = [g for g in groups if g["run"] == "ostrack_mata" and g["group"] == "occlusion"][0]
    assert float(occ["nt2f"]) == 1.0 and occ["sequences"] == "1"


def test_latex_rules_are_the_papers():
    """Double rules under the header and between blocks, as the paper's tables have them (QA
    pass: a double one under the header and a single one between blocks)."""
    from mata_eval.report.tables import Table, to_latex

    t = Table("k", "", ["A"], [], ["x"], [["a", "1"], ["b", "2"], ["c", "3"]], [0, 2])
    body = [line.strip() for line in to_latex(t).splitlines()]
    assert body[3:11] == ["\\midrule", "\\midrule", "a & 1 \\\\", "b & 2 \\\\", "\\midrule", "\\midrule",
                          "c & 3 \\\\", "\\bottomrule"]


def test_latex_is_booktabs_and_escaped(runs):
    tex = overview.render_table(runs, "latex")
    lines = tex.strip().splitlines()
    assert lines[0].startswith(r"\begin{tabular}{l|c|ccccc|") and lines[1] == r"\toprule"
    assert lines[3] == r"\midrule" and lines[-2] == r"\bottomrule" and lines[-1] == r"\end{tabular}"
    assert r"ostrack\_mata & 2 &" in tex and r"base \& co" in tex
    assert "75.0" in tex and r"\\" in lines[4]
    n_cols = len(lines[2].split(" & "))
    assert all(len(line.split(" & ")) == n_cols for line in lines[4:6])


def test_challenge_table_like_paper_table_2(runs):
    tex = overview.render_table(runs, "latex", table="challenges")
    assert r"\multicolumn{2}{c|}{Occlusion}" in tex and r"\multicolumn{2}{c}{Out of view}" in tex
    # one renderer for every table: the stub name spans both header rows, like the paper's
    assert r"\multirow{2}{*}{Run} & \multicolumn{2}{c|}{Occlusion}" in tex
    assert "\n & SR & NT2F & SR & NT2F" in tex
    # ostrack_mata: occlusion = s0 (FOC, never lost): SR 100.0, NT2F 100.0; high dynamic = s1 (lost at 10)
    row = [r for r in tex.splitlines() if r.startswith("ostrack")][0].rstrip(r" \\").split(" & ")
    assert row[1:5] == ["100.0", "100.0", "-", "-"]
    assert row[5:7] == ["50.0", "50.0"]
    term = overview.render_table(runs, "terminal", table="challenges")
    assert "Occlusion (1) SR" in term and "Distractor (1) NT2F" in term



def test_the_attribute_table_has_a_column_pair_per_attribute(runs):
    """pysot's per-attribute analysis (QA pass: scores.json held it, no table showed it).
    ostrack_mata: s0 (FOC) never lost, s1 (FM) lost at frame 10 of 20; base & co: s0 (POC) lost at
    5, s1 (OV, SOB) at 15; NT2F = the share of frames before the loss."""
    md = overview.render_table(runs, "markdown", table="attributes")
    rows = {r[0]: r[1:] for r in ([c.strip() for c in line.strip("|").split("|")] for line in md.splitlines()
                                  if line.startswith("|")) if r[0] in ("ostrack_mata", "base & co")}
    head = [line for line in md.splitlines() if line.startswith("|")][0]
    columns = [c.strip() for c in head.strip("|").split("|")]
    assert columns[1::2] == [f"{a} (1) SR" for a in ("FM", "FOC", "OV", "POC", "SOB")]
    nt2f = {name: cells[1::2] for name, cells in rows.items()}
    assert nt2f == {"ostrack_mata": ["50.0", "100.0", "-", "-", "-"], "base & co": ["-", "-", "75.0", "25.0", "75.0"]}
    rows = list(csv.DictReader(io.StringIO(overview.render_table(runs, "csv", table="attributes"))))
    assert {(r["run"], r["attribute"], float(r["nt2f"])) for r in rows} == {
        ("ostrack_mata", "FOC", 1.0), ("ostrack_mata", "FM", 0.5),
        ("base & co", "POC", 0.25), ("base & co", "OV", 0.75), ("base & co", "SOB", 0.75)}


def test_a_table_of_runs_without_attributes_says_so():
    """QA pass: a folder dataset's challenge table was a bare Run column, with no word why."""
    plain = [run_scores("plain", [20], [set()])]
    for table in ("challenges", "attributes"):
        assert "no sequence of these runs has attributes (the dataset gives none)" in overview.render_table(
            plain, "terminal", table=table)


def test_the_challenge_columns_keep_the_papers_order_after_scores_json(tmp_path):
    """QA pass: scores read back from scores.json (keys sorted) put Distractor first."""
    r = run_scores("all", [20, 10, 5, 15], [{"FOC"}, {"SOB"}, {"FM"}, {"OV"}])
    evaluate.save_scores(tmp_path, r)
    back = evaluate.load_scores(tmp_path)
    assert list(back.summary.groups) != list(r.summary.groups)   # the file's order differs
    head = overview.render_table([back], "terminal", table="challenges").splitlines()[0]
    order = [head.index(g) for g in ("Occlusion", "Distractor", "High dynamic", "Out of view")]
    assert order == sorted(order), head


def test_bad_format_is_rejected(runs):
    with pytest.raises(ValueError, match="unknown table format 'html'"):
        overview.render_table(runs, "html")


def test_nt2f_survival_area_is_mean_nt2f():
    vals = [0.1, 0.5, 1.0, 0.75]
    grid = np.linspace(0, 1, 100001)
    surv = plots.nt2f_survival(vals, grid)
    area = float(np.sum((surv[1:] + surv[:-1]) / 2 * np.diff(grid)))  # trapezoid rule
    assert area == pytest.approx(np.mean(vals), abs=1e-4)
    assert surv[0] == 1.0 and surv[-1] == 0.25  # only the never-failed sequence at t = 1


def test_eighteen_runs_have_eighteen_colours_none_the_ground_truths_green():
    """QA pass: a matrix of more than 10 runs repeated colours (tab10)."""
    from matplotlib import colormaps

    colours = [plots.run_colour(i) for i in range(18)]
    assert len(set(colours)) == 18 and plots.run_colour(18) == colours[0]
    greens = {tuple(colormaps["tab20"].colors[j]) for j in (4, 5)}   # tab10's green and its light shade
    assert greens.isdisjoint(colours)


def test_plots_are_png_files(runs, tmp_path):
    paths = plots.plot_curves(runs, tmp_path / "plots")
    assert {p.name for p in paths} == {"success.png", "precision.png", "norm_precision.png", "nt2f.png"}
    for p in paths:
        img = cv2.imread(str(p))
        assert img is not None and img.shape[0] > 100 and img.std() > 0
    # a run name with mathtext in it is drawn as text (QA pass 14: a matplotlib parse error)
    import dataclasses

    odd = [dataclasses.replace(runs[0], name=r"a|b $\frac$ x")] + list(runs[1:])
    assert len(plots.plot_curves(odd, tmp_path / "odd")) == 4


def toy_run_folder(tmp_path):
    from mata_eval.run import results

    d = tmp_path / "run"
    gt = np.tile([10.0, 10.0, 20.0, 20.0], (6, 1))
    results.write_sequence(d, "a", gt, "frame,scored\n" + "".join(f"{k},1\n" for k in range(6)), "")
    return d, [Sequence("a", gt)]


def test_report_cli_writes_every_format_and_plots(tmp_path, capsys):
    d, seqs = toy_run_folder(tmp_path)
    evaluate.evaluate_run(d, seqs)
    out = tmp_path / "rep"
    assert cli.main(["report", str(d), str(d / "scores.json"), "--out", str(out), "--format", "all",
                     "--table", "both"]) == 0
    for name in ("overall.md", "overall.csv", "overall.tex", "challenges.tex", "success.png", "nt2f.png"):
        assert (out / name).is_file(), name
    assert "95.2" in capsys.readouterr().out  # perfect tracker: MSR 20/21 in the terminal table


def test_runs_short_of_the_same_sequences_share_one_line(tmp_path, capsys):
    """`run --sequences a` of a 12-run experiment printed the same "without results" line once
    per run: runs short of the same sequences are named in one line, others in their own."""
    gt = np.tile([10.0, 10.0, 20.0, 20.0], (6, 1))
    folders = []
    for name in ("r1", "r2", "r3"):
        d, seqs = toy_run_folder(tmp_path / name)
        evaluate.evaluate_run(d, seqs + [Sequence(s, gt) for s in (("b", "c") if name != "r3" else ("c",))])
        folders.append(str(d))
    assert cli.main(["report", *folders]) == 0
    out = capsys.readouterr().out
    assert out.count("without results") == 2
    assert f"2 sequence(s) without results in {folders[0]}, {folders[1]}: b, c" in out
    assert f"1 sequence(s) without results in {folders[2]}: c" in out
    assert cli.main(["report", *folders[:2]]) == 0
    assert "2 sequence(s) without results in each of the 2 runs: b, c" in capsys.readouterr().out


def test_rows_scored_on_different_datasets_are_said(tmp_path, capsys):
    """QA pass 15b: `report` put a run on one dataset and a folder scored on another in one table
    without a word; rows of scores.json files without a dataset name are not counted."""
    names = []
    for name, dataset in (("r1", "dtb70"), ("r2", "uav123"), ("r3", None)):
        d, seqs = toy_run_folder(tmp_path / name)
        evaluate.save_scores(d, evaluate.evaluate_results(d, seqs, dataset=dataset))
        names.append(str(d))
    assert cli.main(["report", *names]) == 0
    out = capsys.readouterr().out
    assert "these rows are scored on different datasets, so their numbers do not compare: dtb70: run (r1); uav123: run (r2)" in out
    assert cli.main(["report", names[0], names[2]]) == 0
    assert "different datasets" not in capsys.readouterr().out


def test_report_cli_explains_when_it_cannot_evaluate(tmp_path, capsys):
    d, _ = toy_run_folder(tmp_path)
    assert cli.main(["report", str(d)]) == 2
    err = capsys.readouterr().err
    assert "no scores.json and no manifest.json" in err and "mata-eval eval" in err
    assert cli.main(["report", str(tmp_path / "typo")]) == 2      # not "not a run folder" (QA pass)
    assert f"{tmp_path / 'typo'}: no such file or folder" in capsys.readouterr().err


def test_report_of_an_interrupted_run_names_the_sequences_without_results(tmp_path, capsys):
    """A run stopped after some of its sequences: the report's row averages the finished ones
    only, so the report says which sequences have no results, as ``eval`` does (QA pass: it
    printed the partial row as if complete)."""
    d, seqs = toy_run_folder(tmp_path)
    gt = np.tile([10.0, 10.0, 20.0, 20.0], (6, 1))
    evaluate.evaluate_run(d, seqs + [Sequence("b", gt), Sequence("c", gt)])
    assert cli.main(["report", str(d)]) == 0
    assert "2 sequence(s) without results: b, c" in capsys.readouterr().out
    evaluate.evaluate_run(d, seqs)
    assert cli.main(["report", str(d)]) == 0
    assert "without results" not in capsys.readouterr().out
    # a failed sequence is named too, not only counted (QA pass)
    (d / "b.failed.json").write_text('{"sequence": "b", "reason": "boom", "traceback": ""}')
    evaluate.evaluate_run(d, seqs + [Sequence("b", gt)])
    assert cli.main(["report", str(d)]) == 0
    assert "1 sequence(s) failed: b; <run>/<sequence>.failed.json says why" in capsys.readouterr().out



def test_a_report_of_runs_scored_under_different_profiles_says_so(tmp_path, capsys):
    """QA pass: a pysot-toolkit row and a default row were put in one table without a word."""
    d, seqs = toy_run_folder(tmp_path)
    other = tmp_path / "other"
    evaluate.evaluate_run(d, seqs)   # writes its scores.json
    evaluate.save_scores(other, evaluate.evaluate_results(d, seqs, profile="pysot-toolkit", name="pysot"))
    assert cli.main(["report", str(d), str(other)]) == 0
    assert "different metric profiles, so their numbers do not compare: default: run; pysot-toolkit: pysot" \
        in capsys.readouterr().out
    assert cli.main(["report", str(d)]) == 0
    assert "different metric profiles" not in capsys.readouterr().out


def test_the_hz_columns_keep_one_order_after_a_round_trip_through_scores_json(tmp_path):
    """``run`` printed tracker, egomotion, estimator; ``report`` of the same run, read back from
    scores.json (keys sorted), printed egomotion, estimator, tracker (QA pass)."""
    r = run_scores("mata", [20, 10], [{"FOC"}, {"FM"}])
    freq = BlockFrequency(starts=10, camera_seconds=1.0, total_ms=250.0)
    r = evaluate.RunScores(**{**r.__dict__, "frequencies": {"tracker": freq, "egomotion": freq, "estimator": freq}})
    evaluate.save_scores(tmp_path, r)
    back = evaluate.load_scores(tmp_path)
    assert list(back.frequencies) != list(r.frequencies)   # the file's order differs ...
    header = overview.render_table([back], "csv").splitlines()[0]
    assert header.index("tracker") < header.index("egomotion") < header.index("estimator")  # ... the table's not


def test_two_run_folders_of_one_run_name_get_two_row_labels(tmp_path, capsys):
    """One experiment written to two outputs: `report out1/run out2/run` printed two rows both
    labelled `run` (QA pass); each label now ends with the part of its path that differs."""
    for out in ("out1", "out2"):
        d, seqs = toy_run_folder(tmp_path / out)
        evaluate.evaluate_run(d, seqs)
    assert cli.main(["report", str(tmp_path / "out1" / "run"), str(tmp_path / "out2" / "run"), "--format", "csv"]) == 0
    rows = [line.split(",")[0] for line in capsys.readouterr().out.splitlines()[1:3]]
    assert rows == ["run (out1)", "run (out2)"]
    assert evaluate.load_scores(tmp_path / "out1" / "run").name == "run"   # only the table's label


def test_report_out_writes_the_table_of_the_default_format_too(tmp_path, capsys):
    """`report RUN --out DIR` wrote only the plots, though --out says tables too (QA pass)."""
    d, seqs = toy_run_folder(tmp_path)
    evaluate.evaluate_run(d, seqs)
    assert cli.main(["report", str(d), "--out", str(tmp_path / "rep"), "--no-plots"]) == 0
    table = (tmp_path / "rep" / "overall.txt").read_text()
    assert table.splitlines()[0].split()[:2] == ["Run", "Seqs"] and "95.2" in table
    assert "95.2" in capsys.readouterr().out   # still printed
    assert cli.main(["report", str(d), "--format", "md"]) == 0   # the extension names the format too
    assert capsys.readouterr().out.startswith("| Run |")
    (tmp_path / "afile").write_text("x")
    assert cli.main(["report", str(d), "--out", str(tmp_path / "afile"), "--no-plots"]) == 2
    assert capsys.readouterr().err.strip() == (f"error: {tmp_path / 'afile'}: a file is there; expected a folder "
                                               "(or a name that does not exist yet)")   # QA pass: "File exists"


def test_an_unreadable_scores_json_says_what_to_do(tmp_path, capsys):
    d, _ = toy_run_folder(tmp_path)
    for text in ("{", "\xff"):
        (d / "scores.json").write_text(text, encoding="latin-1")
        assert cli.main(["report", str(d)]) == 2
        err = capsys.readouterr().err
        assert f"{d / 'scores.json'}: invalid JSON" in err and "delete it (report then scores a run folder again)" in err
