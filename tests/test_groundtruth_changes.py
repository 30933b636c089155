"""An edited ground-truth file is noticed (QA pass: never noticed, so tables were silently wrong):
`report` scores a run again when the ground truth of a scored sequence changed (and again once it
is restored), a rerun refuses to keep results whose tracker started from the old box, and `eval`
says which sequences were run on other ground truth. An older run folder without the record
still resumes and reports; a copied folder whose experiment cannot be read is trusted.

The tracker `Stay` returns the box it started from, and each sequence's target stands still at
2,3,4,5: every predicted box is the ground truth (IoU 1, SR 1) until the ground truth moves by
200 px (IoU 0, SR 0)."""

from __future__ import annotations

import json
import re
import textwrap

import cv2
import numpy as np
import pytest

from mata_eval import cli
from mata_eval.data.datasets.annotations import read_boxes
from mata_eval.run import runner, tasks
from mata_eval.run.config import load_experiment

STAY = '''
    from dataclasses import dataclass

    from mata_eval.types import TrackerOutput


    class Stay:
        """Returns the box it started from."""

        @dataclass(frozen=True)
        class Params:
            pass

        def __init__(self, params):
            pass

        def initialize(self, image, box):
            self.box = box

        def track(self, image, prior=None):
            return TrackerOutput(self.box, 1.0)
'''

BOX, MOVED = "2,3,4,5\n", "202,3,4,5\n"
N = 4


def main(argv: list[str]) -> int:
    """``mata-eval ARGV``, as a process of its own: the annotations its caches hold are read anew."""
    tasks._BASE.clear()
    runner._SEQUENCES.clear()
    return cli.main(argv)


@pytest.fixture
def workdir(tmp_path, monkeypatch):
    """`gt_change_trackers/stay.py`, sequences a and b (4 frames, the target at 2,3,4,5), exp.yaml;
    mata-eval runs there, and has run once."""
    (tmp_path / "gt_change_trackers").mkdir()
    (tmp_path / "gt_change_trackers" / "__init__.py").write_text("")
    (tmp_path / "gt_change_trackers" / "stay.py").write_text(textwrap.dedent(STAY))
    for name in ("a", "b"):
        seq = tmp_path / "data" / name
        (seq / "img").mkdir(parents=True)
        for k in range(N):
            cv2.imwrite(str(seq / "img" / f"{k:04d}.png"), np.zeros((20, 30, 3), np.uint8))
        (seq / "groundtruth_rect.txt").write_text(BOX * N)
    (tmp_path / "exp.yaml").write_text("output: out\ndataset: {name: folder, root: data}\n"
                                       "tracker: {name: 'gt_change_trackers.stay:Stay'}\n")
    monkeypatch.chdir(tmp_path)
    monkeypatch.syspath_prepend(str(tmp_path / "nowhere"))  # restores sys.path after the test
    assert main(["run", "exp.yaml", "-q", "-j", "1", "--no-report"]) == 0
    return tmp_path


def _move(workdir, box=MOVED):
    (workdir / "data" / "a" / "groundtruth_rect.txt").write_text(box * N)


def _sr(run) -> dict:
    scores = json.loads((run / "scores.json").read_text())
    return {"overall": scores["summary"]["overall"]["sr"], **{k: v["sr"] for k, v in scores["sequences"].items()}}


def test_report_scores_again_when_the_ground_truth_changed_and_when_it_is_restored(workdir, capsys):
    run = workdir / "out" / "exp"
    assert main(["report", str(run)]) == 0
    assert _sr(run) == {"overall": 1.0, "a": 1.0, "b": 1.0}
    capsys.readouterr()
    _move(workdir)
    assert main(["report", str(run)]) == 0
    out, err = capsys.readouterr()
    assert (f"{run}: scored again against the experiment's annotations: those of a differ from the ones its "
            f"scores.json was scored on") in err
    assert _sr(run) == {"overall": 0.5, "a": 0.0, "b": 1.0}    # a's boxes 200 px off its new ground truth
    assert "1 sequence(s) were run on other ground truth than they are scored on here" in out
    assert "--force --sequences a to run them on this one" in out
    _move(workdir, BOX)                                         # restored: the first numbers again
    assert main(["report", str(run)]) == 0
    out, err = capsys.readouterr()
    assert "scored again against the experiment's annotations: those of a differ" in err
    assert "other ground truth" not in out
    assert _sr(run) == {"overall": 1.0, "a": 1.0, "b": 1.0}
    assert main(["report", str(run)]) == 0                      # unchanged since: trusted
    assert "scored again" not in capsys.readouterr().err


def test_a_rerun_refuses_to_keep_results_made_on_other_ground_truth(workdir, capsys):
    run = workdir / "out" / "exp"
    b_before = (run / "b.txt").read_text()
    _move(workdir)
    capsys.readouterr()
    assert main(["run", "exp.yaml", "-q", "-j", "1", "--no-report"]) == 2
    err = capsys.readouterr().err
    assert (f"{run} holds results of 1 sequence(s) whose ground truth changed since they were made (a): "
            f"their tracker started from another box; rerun with --force --sequences a to redo them") in err
    np.testing.assert_allclose(read_boxes(run / "a.txt"), [[2, 3, 4, 5]] * N)   # nothing redone or kept silently
    assert main(["run", "exp.yaml", "-q", "-j", "1", "--force", "--sequences", "a"]) == 0
    np.testing.assert_allclose(read_boxes(run / "a.txt"), [[202, 3, 4, 5]] * N)  # started from the new box
    assert (run / "b.txt").read_text() == b_before
    assert _sr(run) == {"overall": 1.0, "a": 1.0, "b": 1.0}
    assert main(["run", "exp.yaml", "-q", "-j", "1", "--no-report"]) == 0       # recorded: kept now
    assert "2 finished sequence(s) kept" in capsys.readouterr().out


def test_eval_names_the_sequences_run_on_other_ground_truth(workdir, capsys):
    run = workdir / "out" / "exp"
    capsys.readouterr()
    assert main(["eval", str(run), "--dataset", "folder", "--root", "data"]) == 0
    assert "other ground truth" not in capsys.readouterr().out
    _move(workdir)
    assert main(["eval", str(run), "--dataset", "folder", "--root", "data"]) == 0
    out = capsys.readouterr().out
    assert ("1 sequence(s) were run on other ground truth than they are scored on here (their tracker started "
            "from another box, or occluders were placed from other boxes): a; rerun them with --force --sequences a "
            "to run them on this one") in out
    assert _sr(run) == {"overall": 0.5, "a": 0.0, "b": 1.0}


def test_a_folder_without_the_record_resumes_and_reports_and_a_copied_one_is_trusted(workdir, capsys):
    """As an older mata-eval wrote it: no `groundtruth` in manifest.json or scores.json."""
    run = workdir / "out" / "exp"
    assert main(["report", str(run)]) == 0
    for name, key in (("manifest.json", None), ("scores.json", "meta")):
        data = json.loads((run / name).read_text())
        (data[key] if key else data).pop("groundtruth")
        (run / name).write_text(json.dumps(data))
    _move(workdir)                        # not compared: nothing says what the results were made on
    capsys.readouterr()
    assert main(["run", "exp.yaml", "-q", "-j", "1", "--no-report"]) == 0
    assert "2 finished sequence(s) kept" in capsys.readouterr().out
    assert main(["report", str(run)]) == 0
    assert "scored again" not in capsys.readouterr().err and _sr(run)["a"] == 1.0
    assert main(["eval", str(run), "--dataset", "folder", "--root", "data"]) == 0   # with the record now
    assert _sr(run)["a"] == 0.0
    _move(workdir, BOX)
    assert main(["report", str(run)]) == 0   # scored again on the restored box
    capsys.readouterr()
    scores = json.loads((run / "scores.json").read_text())
    scores["meta"].pop("frequency_rule")  # rates of an older mata-eval: scored again while it can be
    (run / "scores.json").write_text(json.dumps(scores))
    assert main(["report", str(run)]) == 0
    assert "scored again: its scores.json counted frame 0 in its block rates" in capsys.readouterr().err
    (run / "scores.json").write_text(json.dumps(scores))
    _move(workdir)
    (workdir / "exp.yaml").unlink()       # a copied folder: its experiment cannot be read, scores.json trusted
    assert main(["report", str(run)]) == 0   # (also one of an older rule: QA review, the report failed)
    out, err = capsys.readouterr()
    assert "scored again:" not in err and _sr(run)["a"] == 1.0
    assert f"{run}: its block rates (Hz) count frame 0, as an older mata-eval did; not scored again here (the " \
           f"experiment file '{workdir / 'exp.yaml'}' named in its manifest cannot be read)" in err
    assert f"{run}: its block rates (Hz) count frame 0, the initialisation, as an older mata-eval did" in out


def test_a_box_the_run_did_not_read_changes_the_scores_not_the_results(workdir, capsys):
    """Review: without the occlusion augmentation a run reads only the start box; a later box
    fixed by hand was refused as if the tracker had started elsewhere."""
    run = workdir / "out" / "exp"
    (workdir / "data" / "a" / "groundtruth_rect.txt").write_text(BOX * (N - 1) + MOVED)   # the last frame's only
    capsys.readouterr()
    assert main(["run", "exp.yaml", "-q", "-j", "1"]) == 0
    out = capsys.readouterr().out
    assert "2 finished sequence(s) kept" in out and "other ground truth" not in out
    assert _sr(run) == {"overall": 0.875, "a": 0.75, "b": 1.0}   # a: 3 of 4 frames still on the target


def test_a_later_box_edited_in_a_run_with_occlusion_is_refused(workdir, capsys):
    """The occluders are placed from every box: with `occlusion: {}` a later box edited by
    hand means the run read other input (the start box alone would not show it)."""
    exp = workdir / "exp.yaml"
    exp.write_text(exp.read_text() + "occlusion: {}\n")
    assert main(["run", "exp.yaml", "-q", "-j", "1", "--no-report", "--force"]) == 0
    (workdir / "data" / "a" / "groundtruth_rect.txt").write_text(BOX * (N - 1) + MOVED)   # the last frame's only
    capsys.readouterr()
    assert main(["run", "exp.yaml", "-q", "-j", "1", "--no-report"]) == 2
    err = capsys.readouterr().err
    assert "whose ground truth changed since they were made (a): their tracker started from another box or " \
           "the occluders were placed from other boxes" in err


def test_a_record_of_every_box_as_a_development_version_wrote_it_is_read(workdir, capsys):
    """Review: a development version recorded every box's sha256 also without occlusion; read as
    the start box's it refused to resume for a false reason. Such a record that still matches is
    unchanged; one whose start box changed is still refused."""
    from mata_eval.run import results

    run = workdir / "out" / "exp"
    manifest = json.loads((run / "manifest.json").read_text())
    seqs = {s.name: s for s in runner.load_sequences(load_experiment("exp.yaml").runs[0])}
    manifest["groundtruth"] = {k: results.groundtruth_sha256(s) for k, s in seqs.items()}
    (run / "manifest.json").write_text(json.dumps(manifest))
    capsys.readouterr()
    assert main(["run", "exp.yaml", "-q", "-j", "1", "--no-report"]) == 0
    assert "2 finished sequence(s) kept" in capsys.readouterr().out
    # read on that resume as the start box's: a later box fixed by hand afterwards keeps the results
    (workdir / "data" / "a" / "groundtruth_rect.txt").write_text(BOX * (N - 1) + MOVED)
    assert main(["run", "exp.yaml", "-q", "-j", "1", "--no-report"]) == 0
    assert "2 finished sequence(s) kept" in capsys.readouterr().out
    (run / "manifest.json").write_text(json.dumps(manifest))
    _move(workdir)
    assert main(["run", "exp.yaml", "-q", "-j", "1", "--no-report"]) == 2
    assert "whose ground truth changed since they were made (a)" in capsys.readouterr().err


def test_a_report_does_not_build_a_generated_dataset_to_compare_it(tmp_path, monkeypatch, capsys):
    """Review: the comparison read the dataset on every report, and the synthetic suite is built
    when read: a report of an up-to-date run generated the whole suite into an emptied cache."""
    import shutil

    monkeypatch.setenv("MATA_EVAL_CACHE", str(tmp_path / "cache"))
    (tmp_path / "exp.yaml").write_text(f"output: {tmp_path / 'out'}\ndataset: {{name: synthetic, n_sequences: 1, "
                                       "n_frames: 12, width: 160, height: 120}\ntracker: {name: kcf}\n")
    assert main(["run", str(tmp_path / "exp.yaml"), "-j", "1", "-q"]) == 0
    shutil.rmtree(tmp_path / "cache")
    assert main(["report", str(tmp_path / "out" / "exp")]) == 0
    assert not (tmp_path / "cache").exists()
    # nor for a scores.json whose rates follow an older rule (QA pass 16d: the suite was rendered for them)
    path = tmp_path / "out" / "exp" / "scores.json"
    scores = json.loads(path.read_text())
    scores["meta"].pop("frequency_rule")
    path.write_text(json.dumps(scores))
    capsys.readouterr()
    assert main(["report", str(tmp_path / "out" / "exp")]) == 0
    assert not (tmp_path / "cache").exists()
    assert "not scored again here (its dataset is generated, and not rendered again" in capsys.readouterr().err


def test_the_record_outlives_an_absent_sequence_and_judges_only_the_selected_ones(workdir, capsys):
    """QA pass 13: a sequence moved away for one rerun lost its record, so an edit made after
    it came back went unnoticed; and an edit to a sequence --sequences left out refused the run."""
    run = workdir / "out" / "exp"
    (workdir / "data" / "a").rename(workdir / "a.away")
    assert main(["run", "exp.yaml", "-q", "-j", "1", "--no-report"]) == 0
    (workdir / "a.away").rename(workdir / "data" / "a")
    _move(workdir)
    capsys.readouterr()
    assert main(["run", "exp.yaml", "-q", "-j", "1", "--no-report", "--sequences", "b"]) == 0   # a: not asked for
    assert main(["run", "exp.yaml", "-q", "-j", "1", "--no-report"]) == 2
    assert "whose ground truth changed since they were made (a)" in capsys.readouterr().err
    np.testing.assert_allclose(read_boxes(run / "a.txt"), [[2, 3, 4, 5]] * N)


def test_a_sequence_unscorable_on_a_broken_annotation_file_is_scored_once_the_file_is_fixed(workdir, capsys):
    """QA pass 13: report kept saying "cannot score" after the annotation file was restored (the
    unscorable sequence's ground truth was not recorded, so never compared again)."""
    run = workdir / "out" / "exp"
    gt = workdir / "data" / "a" / "groundtruth_rect.txt"
    gt.write_text(BOX * (N + 1))   # one line too many: a's results no longer fit
    assert main(["report", str(run)]) == 0
    assert "cannot score exp/a" in capsys.readouterr().out
    gt.write_text(BOX * N)         # fixed
    assert main(["report", str(run)]) == 0
    out = capsys.readouterr().out
    assert "cannot score" not in out and _sr(run) == {"overall": 1.0, "a": 1.0, "b": 1.0}


def test_report_scores_again_a_result_file_edited_or_cut_since_its_scores_were_written(workdir, capsys):
    """QA pass 14: report kept showing the old numbers after a prediction file was edited or
    truncated (only the set of finished sequences was compared), while eval and run disagreed."""
    run = workdir / "out" / "exp"
    assert main(["report", str(run)]) == 0
    assert _sr(run) == {"overall": 1.0, "a": 1.0, "b": 1.0}
    (run / "b.txt").write_text(MOVED * N)                       # edited: 200 px off
    capsys.readouterr()
    assert main(["report", str(run)]) == 0
    assert f"{run}: scored again: the result files of b changed since its scores.json was written" in \
        capsys.readouterr().err
    assert _sr(run) == {"overall": 0.5, "a": 1.0, "b": 0.0}
    (run / "b.txt").write_text(BOX * (N - 1))                   # cut short
    assert main(["report", str(run)]) == 0
    assert "cannot score exp/b" in capsys.readouterr().out
    assert main(["report", str(run)]) == 0                      # unchanged since: trusted
    assert "scored again" not in capsys.readouterr().err


def test_run_and_report_name_sequences_left_out_and_results_of_a_removed_sequence(tmp_path, workdir, capsys):
    """QA pass 14: run's table did not say which sequences --sequences left without results, and
    the results of a sequence removed from the dataset left the run and report tables silently."""
    import shutil

    shutil.rmtree(workdir / "out")
    capsys.readouterr()
    assert main(["run", "exp.yaml", "-q", "-j", "1", "--sequences", "a"]) == 0
    assert "1 sequence(s) without results: b" in capsys.readouterr().out
    assert main(["run", "exp.yaml", "-q", "-j", "1"]) == 0
    (workdir / "data" / "b").rename(tmp_path / "b.away")
    capsys.readouterr()
    for command in (["run", "exp.yaml", "-q", "-j", "1"], ["report", str(workdir / "out" / "exp")]):
        assert main(command) == 0
        assert "1 result file(s) match no sequence of folder: b (not in the table)" in capsys.readouterr().out


def test_a_copied_run_folder_is_reported_from_itself(workdir, tmp_path):
    """QA pass 14: the reports read a run's configuration from the path saved in its scores.json,
    so a copy (or a moved folder) showed the original folder's tracker, or nothing."""
    import shutil

    from mata_eval.score.evaluate import load_scores, scores_for

    run = workdir / "out" / "exp"
    assert main(["report", str(run)]) == 0
    copy = tmp_path / "elsewhere" / "exp"
    shutil.copytree(run, copy)
    shutil.rmtree(run)                           # moved
    assert load_scores(copy).path == scores_for(copy).path == str(copy.resolve())
    assert main(["report", str(copy)]) == 0


def test_eval_of_a_run_on_other_dataset_parameters_leaves_its_scores_json(workdir, capsys):
    """QA pass 15c: `eval RUN --set sequences=[a]` wrote a one-sequence scores.json into the run
    folder, which `report` then showed as the run's (Seqs 1) with b called "no sequence of the
    dataset". Only the run's own dataset writes it there."""
    run = workdir / "out" / "exp"
    assert main(["eval", str(run), "--dataset", "folder", "--root", "data", "--set", "sequences=[a]"]) == 0
    assert f"{run}: scores.json not written there: scored on another dataset" in capsys.readouterr().out
    assert not (run / "scores.json").exists()
    assert main(["report", str(run)]) == 0
    out = capsys.readouterr().out
    assert re.search(r"^exp\s+2\s", out, re.M) and "no sequence" not in out
    assert main(["eval", str(run), "--dataset", "folder", "--root", str(workdir / "data")]) == 0   # the same root
    assert "not written" not in capsys.readouterr().out and (run / "scores.json").is_file()


def test_changed_runs_are_all_refused_before_loading_and_validate_says_so(workdir, capsys):
    """QA pass 15c: a changed parameter refused one run (another was affected too), suggested a
    --force that redid every run, was found only after the dataset was loaded (a synthetic suite
    rendered for minutes), and `validate` said the runs were ready."""
    (workdir / "exp.yaml").write_text("output: out\ndataset: {name: folder, root: data}\n"
                                      "tracker: {name: 'gt_change_trackers.stay:Stay'}\n"
                                      "matrix:\n  protocol:\n    one: {name: dsp, n: 2}\n    two: {name: dsp, n: 3}\n"
                                      "    three: {name: ltp}\n")
    assert main(["run", "exp.yaml", "-q", "-j", "1", "--no-report"]) == 0
    text = (workdir / "exp.yaml").read_text()
    (workdir / "exp.yaml").write_text(text.replace("n: 2", "n: 4").replace("n: 3", "n: 5"))
    capsys.readouterr()
    assert main(["validate", "exp.yaml"]) == 0   # (validate has no --force: a warning)
    assert ("warning: run without --force refuses this: " in (out := capsys.readouterr().out)
            and "(1 more run(s) refused: two); `--force --runs one two` redoes only these runs" in out
            and "preflight: 3 run(s) ready; their output folders hold results that `run` refuses" in out)
    import mata_eval.run.runner as runner

    loaded = []
    original = runner.load_sequences
    runner.load_sequences = lambda spec: loaded.append(spec.name) or original(spec)
    try:
        assert main(["run", "exp.yaml", "-q", "-j", "1", "--no-report"]) == 2
    finally:
        runner.load_sequences = original
    assert "`--force --runs one two`" in capsys.readouterr().err and loaded == []
    assert main(["run", "exp.yaml", "-q", "-j", "1", "--no-report", "--force", "--runs", "one", "two"]) == 0
    assert main(["validate", "exp.yaml"]) == 0 and "refuses" not in capsys.readouterr().out


def test_run_runs_keeps_the_experiments_other_runs_in_its_plots(workdir, monkeypatch, capsys):
    """QA pass 15c: `run --runs one` rewrote the experiment's plots with run one alone (two
    drivers on disjoint --runs replaced each other's plots)."""
    import mata_eval.report.plots as plots

    (workdir / "exp.yaml").write_text("output: out\ndataset: {name: folder, root: data}\n"
                                      "tracker: {name: 'gt_change_trackers.stay:Stay'}\n"
                                      "matrix:\n  protocol:\n    one: {name: ltp}\n    two: {name: dsp, n: 2}\n"
                                      "    three: {name: dsp, n: 3}\n")
    assert main(["run", "exp.yaml", "-q", "-j", "1", "--no-report", "--runs", "one", "two"]) == 0
    plotted = []
    monkeypatch.setattr(plots, "plot_curves", lambda runs, out: plotted.append([r.name for r in runs]) or [])
    assert main(["run", "exp.yaml", "-q", "-j", "1", "--runs", "two"]) == 0
    assert plotted == [["one", "two"]]   # in the experiment's order; three has no results: not plotted
    (workdir / "out" / "two" / "scores.json").write_text("{")   # (review) one that cannot be read: left out, said
    assert main(["run", "exp.yaml", "-q", "-j", "1", "--runs", "one"]) == 0
    assert plotted[-1] == ["one"] and "plots: two left out" in capsys.readouterr().out


def test_eval_of_two_runs_writes_only_the_scores_of_the_run_whose_dataset_it_loaded(workdir, capsys):
    """Review of QA pass 15c's fix: without --root the dataset is loaded with the first folder's
    parameters, and a second run of other parameters had its scores.json replaced; the rows
    record the dataset they were scored on."""
    (workdir / "one.yaml").write_text("output: out1\ndataset: {name: folder, root: data, sequences: [a]}\n"
                                      "tracker: {name: 'gt_change_trackers.stay:Stay'}\n")
    assert main(["run", "one.yaml", "-q", "-j", "1", "--no-report"]) == 0
    run, one = workdir / "out" / "exp", workdir / "out1" / "one"
    (run / "scores.json").unlink(missing_ok=True)
    capsys.readouterr()
    assert main(["eval", str(one), str(run), "--dataset", "folder"]) == 0
    out = capsys.readouterr().out
    assert f"wrote {one / 'scores.json'}" in out and f"{run}: scores.json not written there" in out
    assert not (run / "scores.json").exists()
    assert json.loads((one / "scores.json").read_text())["meta"]["dataset"] == "folder"
    # a first folder that is no run folder of the dataset (pysot layout) does not hide the run's
    # parameters (QA pass 16a: "missing required parameter(s): root"; the other order worked)
    foreign = workdir / "pysot" / "Stay"
    foreign.mkdir(parents=True)
    for name in ("a", "b"):
        (foreign / f"{name}.txt").write_text((run / f"{name}.txt").read_text())
    assert main(["eval", str(foreign), str(run), "--dataset", "folder", "--no-save"]) == 0
    assert f"dataset folder with the parameters of {run / 'manifest.json'}" in capsys.readouterr().out


def test_report_follows_the_sequences_the_experiment_lists_now(workdir, capsys):
    """The dataset's `sequences` list is not in the config hash (a run folder resumes when it
    changes), so a run's scores.json may be of another list than its experiment holds now (the
    list edited and another run of the matrix resumed alone, or none): a report scores it again
    against the list, naming listed sequences without results and leaving removed ones out of
    the row (QA pass: the old scores.json was shown as it was, without a word)."""
    run, exp = workdir / "out" / "exp", workdir / "exp.yaml"
    listed = lambda names: exp.write_text(exp.read_text().replace("root: data}", f"root: data, sequences: {names}}}")
                                          if "sequences" not in exp.read_text() else
                                          re.sub(r"sequences: \[.*\]", f"sequences: {names}", exp.read_text()))
    assert main(["report", str(run)]) == 0                      # scores.json of a and b
    listed("[a]")
    capsys.readouterr()
    assert main(["report", str(run)]) == 0
    out, err = capsys.readouterr()
    assert f"{run}: scored again: the sequences of its experiment's dataset changed since its scores.json" in err
    assert "1 result file(s) match no sequence of folder: b (not in the table)" in out
    assert sorted(json.loads((run / "scores.json").read_text())["sequences"]) == ["a"]
    assert main(["report", str(run)]) == 0                      # scored on the list: trusted
    assert "scored again" not in capsys.readouterr().err
    (workdir / "data" / "c").mkdir()
    (workdir / "data" / "b" / "img").rename(workdir / "data" / "c" / "img")
    (workdir / "data" / "c" / "groundtruth_rect.txt").write_text(BOX * N)
    listed("[c, b, a]")
    assert main(["report", str(run)]) == 0
    out, err = capsys.readouterr()
    assert "scored again: the sequences of its experiment's dataset" in err and "1 sequence(s) without results: c" in out
    assert sorted(json.loads((run / "scores.json").read_text())["sequences"]) == ["a", "b"]


def test_report_of_an_experiments_output_folder_points_at_its_run_folders(workdir, capsys):
    """QA pass 16d: it said "not a mata-eval run folder; run mata-eval eval ... --root PATH"."""
    assert main(["report", str(workdir / "out")]) == 2
    assert f"{workdir / 'out'}: no scores.json and no manifest.json: it holds run folders; report them " \
           f"(`mata-eval report {workdir / 'out'}/*`" in capsys.readouterr().err
    assert main(["eval", str(workdir / "out")]) == 2   # eval too (QA pass 16e)
    assert f"{workdir / 'out'} holds run folders: `mata-eval eval {workdir / 'out'}/*`" in capsys.readouterr().err
