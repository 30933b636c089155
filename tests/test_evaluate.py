"""Scoring results folders: our run folder (scored frames, failures, block frequencies,
scores.json round trip) and the foreign pysot / got10k / pytracking layouts, which must give
the same numbers for the same boxes."""

from __future__ import annotations

import dataclasses
import json
import re
import zipfile

import numpy as np
import pytest

import mata_eval as me

from mata_eval import cli
from mata_eval.run import results
from mata_eval.score import evaluate
from mata_eval.score.run_dataset import as_the_run_saw_them
from mata_eval.core.sequence import Sequence

N = 12


def make_sequences() -> list[Sequence]:
    gt = np.tile([20.0, 20.0, 10.0, 10.0], (N, 1))
    gt[:, 0] += np.arange(N)  # a target moving right 1 px per frame
    b = gt.copy()
    b[5] = np.nan  # out of view
    ann = np.zeros(N, bool)
    ann[::3] = True
    return [
        Sequence("car1", gt, fps=30.0, attributes=frozenset({"FM", "SV"})),
        Sequence("car2", b, fps=30.0, attributes=frozenset({"POC"})),
        Sequence("bike", gt.copy(), fps=30.0, attributes=frozenset({"OV"}), annotated=ann),
        Sequence("gone", gt.copy(), fps=30.0),
    ]


def predictions(seqs) -> dict[str, np.ndarray]:
    """car1: lost (shifted 30 px) from frame 8 on; car2: exact; bike: exact."""
    p = {s.name: np.where(np.isnan(s.groundtruth), 0.0, s.groundtruth) for s in seqs}
    p["car1"] = p["car1"].copy()
    p["car1"][8:, 0] += 30
    p["car2"][5] = [25, 20, 10, 10]
    return p


def frames_csv(scored: np.ndarray, tracker_ms: np.ndarray) -> str:
    lines = ["frame,scored,confidence,tracker_ms,egomotion_ms,source_frame"]
    for k in range(len(scored)):
        t = "nan" if np.isnan(tracker_ms[k]) else f"{tracker_ms[k]:g}"
        lines.append(f"{k},{int(scored[k])},0.9,{t},2,{k}")
    return "\n".join(lines) + "\n"


@pytest.fixture
def run_dir(tmp_path):
    seqs = make_sequences()
    preds = predictions(seqs)
    d = tmp_path / "exp" / "eop10"
    results.write_manifest(d, {"run": "eop10", "experiment": "exp", "config_hash": "abc",
                               "config": {"dataset": {"name": "toy"}}})
    tracker = np.full(N, np.nan)
    tracker[::3] = 40.0  # 10 Hz on a 30 Hz stream, 40 ms per call
    for s in seqs[:3]:
        scored = np.ones(N, bool) if s.name != "car2" else (np.arange(N) % 2 == 0)
        results.write_sequence(d, s.name, preds[s.name], frames_csv(scored, tracker), "block,event,frame,t\n")
    results.write_failure(d, "gone", "RuntimeError: tracker exploded", "Traceback ...")
    return d, seqs


def test_evaluate_run_scores_and_writes_scores_json(run_dir):
    d, seqs = run_dir
    sc = evaluate.evaluate_run(d, seqs)
    assert sc.name == "eop10" and sc.layout == "mata" and sc.profile == "default"
    assert set(sc.sequences) == {"car1", "car2", "bike"}
    assert sc.failures == {"gone": "RuntimeError: tracker exploded"} and sc.missing == ()
    # car1: IoU 0 from frame 8 of 12 -> NT2F 8/12, SR 8/12
    assert sc.sequences["car1"].nt2f == pytest.approx(8 / 12)
    assert sc.sequences["car1"].sr == pytest.approx(8 / 12)
    # car2: scored every 2nd frame (6 frames); frame 5 is odd, so nothing excluded; exact boxes
    c2 = sc.sequences["car2"]
    assert c2.n_scored == 6 and c2.n_excluded == 0 and c2.sr == 1.0
    # bike: annotated every 3rd frame -> 4 scored frames
    assert sc.sequences["bike"].n_scored == 4
    assert sc.summary.overall.n_sequences == 3
    assert sc.summary.overall.nt2f == pytest.approx((8 / 12 + 1 + 1) / 3)
    assert sc.summary.groups["occlusion"].n_sequences == 1      # car2 (POC)
    assert sc.summary.groups["high dynamic"].nt2f == pytest.approx(8 / 12)  # car1 (FM)
    # tracker: 4 starts per 12 frames at 30 fps -> 10 Hz scheduled, 25 Hz wall clock
    assert sc.frequencies["tracker"].scheduled_hz == pytest.approx(10.0)
    assert sc.frequencies["tracker"].wall_hz == pytest.approx(25.0)
    assert sc.frequencies["egomotion"].scheduled_hz == pytest.approx(30.0)

    data = json.loads((d / "scores.json").read_text())
    assert data["profile"] == "default" and data["failures"] == {"gone": "RuntimeError: tracker exploded"}
    assert data["sequences"]["car1"]["n_frames"] == N
    assert data["profile_policies"]["invalid_success"] == "exclude"
    back = evaluate.load_scores(d)
    assert back.summary.overall.msr == pytest.approx(sc.summary.overall.msr)
    assert back.sequences["car1"].failure_frame == 8
    assert back.frequencies["tracker"].wall_hz == pytest.approx(25.0)
    assert not list(d.glob("*.tmp")) and not list(d.glob(".scores.json*"))  # atomic write left nothing


def test_excluded_frames_are_counted(run_dir):
    d, seqs = run_dir
    (d / "car2.frames.csv").unlink()  # no sidecar: every frame scored, NaN frame 5 excluded
    sc = evaluate.evaluate_run(d, seqs)
    assert sc.sequences["car2"].n_excluded == 1 and sc.summary.overall.n_excluded == 1
    assert evaluate.evaluate_run(d, seqs, profile="pysot").sequences["car2"].n_excluded == 0


def test_missing_sequence_is_reported(run_dir):
    d, seqs = run_dir
    (d / "bike.txt").unlink()
    sc = evaluate.evaluate_run(d, seqs)
    assert sc.missing == ("bike",) and "bike" not in sc.sequences


def test_bad_files_get_clear_errors(run_dir):
    """A sequence whose files cannot be scored is named with the file and the reason, counted as
    failed, and the others are still scored (QA pass: the first bad file stopped the scoring of
    every sequence, with a traceback under `run`)."""
    d, seqs = run_dir

    def unscorable(profile="default"):
        sc = evaluate.evaluate_run(d, seqs, profile=profile)
        assert set(sc.sequences) == {"car2", "bike"} and "car1" in sc.failures
        return sc.meta["unscorable"]["car1"]

    (d / "car1.frames.csv").write_text("frame,scored\n0,maybe\n")
    assert re.search(r"car1\.frames\.csv:2: expected 1/0 or true/false", unscorable())
    # a row shorter than the header (QA pass: a raw IndexError while scoring and reporting)
    (d / "car1.frames.csv").write_text("frame,scored,tracker_ms,est_a,b\n0,1,5.0,1\nd,1,1\n")
    assert re.search(r"car1\.frames\.csv:2: expected 5 comma-separated values as in the header \(line 1\), got 4",
                     unscorable())
    (d / "car1.frames.csv").write_text("frame,tracker_ms,scored\n0,5.0,1\n1\n")
    assert re.search(r"car1\.frames\.csv:3: expected 3 comma-separated values .* got 1", unscorable())
    (d / "car1.frames.csv").unlink()
    (d / "car1.txt").write_text("1,2,3\n")
    assert re.search(r"car1\.txt:1: expected 4 numbers", unscorable())
    (d / "car1.txt").write_text("1,2,3,4\n")
    assert re.search(r"car1\.txt: predictions have 1 rows but the ground truth has 12", unscorable())
    # blank lines are skipped, as got10k's and pytracking's np.loadtxt skip them; the row-count
    # error then says where they are (QA pass: it did not)
    (d / "car1.txt").write_text("1,2,3,4\n1,2,3,4\n\n1,2,3,4\n\n")
    assert re.search(r"car1\.txt: predictions have 3 rows .*; line 3 is blank \(blank lines are skipped\)",
                     unscorable())
    # an empty file: the got10k profile truncated the ground truth to it and left the sequence
    # out of the means without a word (QA pass); every profile refuses it
    (d / "car1.txt").write_text("")
    for profile in ("default", "got10k", "pytracking"):
        assert re.search(r"car1\.txt: empty prediction file; sequence 'car1' has 12 frames", unscorable(profile))
    with pytest.raises(FileNotFoundError, match="no scores file"):
        evaluate.load_scores(d.parent)


def write_foreign(tmp_path, preds, layout):
    d = tmp_path / layout
    d.mkdir()
    for name, b in preds.items():
        if layout == "pysot":
            (d / f"{name}.txt").write_text("".join(",".join(f"{v:.3f}" for v in r) + "\n" for r in b))
        elif layout == "pytracking":
            (d / f"{name}.txt").write_text("".join("\t".join(str(int(v)) for v in r) + "\n" for r in b))
            (d / f"{name}_time.txt").write_text("".join("0.02\n" for _ in b))
        else:
            (d / name).mkdir()
            (d / name / f"{name}_001.txt").write_text("".join(",".join(f"{v:.3f}" for v in r) + "\n" for r in b))
            (d / name / f"{name}_time.txt").write_text("0\n" + "".join("0.05\n" for _ in b[1:]))
    return d


@pytest.mark.parametrize("layout", ["pysot", "got10k", "pytracking"])
def test_foreign_layouts_are_detected_and_give_the_same_scores(tmp_path, layout):
    seqs = make_sequences()[:3]
    preds = predictions(seqs)
    d = write_foreign(tmp_path, preds, layout)
    assert evaluate.detect_layout(d) == layout
    sc = evaluate.evaluate_results(d, seqs)
    assert sc.layout == layout and sc.name == layout
    assert sc.sequences["car1"].nt2f == pytest.approx(8 / 12)
    assert sc.sequences["car2"].n_excluded == 1
    assert sc.summary.overall.sr == pytest.approx((8 / 12 + 1 + 1) / 3)
    if layout == "got10k":  # frame 0 is the initialisation (time 0): 11 timed frames of 50 ms
        assert sc.frequencies["tracker"].wall_hz == pytest.approx(20.0)
    if layout == "pytracking":
        assert sc.frequencies["tracker"].wall_hz == pytest.approx(50.0)
    forced = evaluate.evaluate_results(d, seqs, layout=layout, profile="pytracking")
    assert forced.profile == "pytracking"


def test_unknown_layout_and_empty_folder(tmp_path):
    with pytest.raises(FileNotFoundError, match="no results found"):
        evaluate.detect_layout(tmp_path)
    with pytest.raises(ValueError, match="unknown results layout 'vot'"):
        evaluate.read_results(tmp_path, "vot")
    # pysot-toolkit's results/<dataset>/<tracker>/<seq>.txt, given the dataset folder (QA pass)
    for tracker in ("SiamAPN", "SiamRPN"):
        (tmp_path / tracker).mkdir()
        (tmp_path / tracker / "car1.txt").write_text("1,2,3,4\n")
    with pytest.raises(FileNotFoundError, match=r"sub-folders SiamAPN, SiamRPN hold result files: pass them"):
        evaluate.detect_layout(tmp_path)


def test_eval_cli_with_a_dataset_plugin(tmp_path, monkeypatch, capsys):
    seqs = make_sequences()[:3]
    d = write_foreign(tmp_path, predictions(seqs), "pysot")
    calls = {}

    def fake_load(name, root, extra=None):
        calls.update(name=name, root=root, extra=extra)
        return seqs

    monkeypatch.setattr(cli, "load_dataset", fake_load)
    out_dir = tmp_path / "scores"
    rc = cli.main(["eval", str(d), "--dataset", "toy", "--root", "/data/toy", "--profile", "pysot-toolkit",
                   "--output", str(out_dir), "--challenges", "--attributes"])
    assert rc == 0
    assert calls == {"name": "toy", "root": "/data/toy", "extra": {}}
    text = capsys.readouterr().out
    assert "NT2F" in text and "pysot" in text and "Occlusion" in text
    assert "FM (1) SR" in text and "POC (1) NT2F" in text   # car1's and car2's attributes
    assert evaluate.load_scores(out_dir).profile == "pysot-toolkit"
    # report of the foreign folder says how to keep its scores, and the hint works (QA pass: it looped)
    assert cli.main(["report", str(d)]) == 2
    assert "(with --output DIR, then `mata-eval report DIR` reports it again)" in capsys.readouterr().err
    assert cli.main(["report", str(out_dir)]) == 0 and "pysot" in capsys.readouterr().out


def test_eval_says_that_got10k_repetitions_past_the_first_are_not_scored(tmp_path, monkeypatch, capsys):
    """QA pass 14: <seq>_002.txt, _003.txt were left without a word."""
    seqs = make_sequences()[:2]
    d = write_foreign(tmp_path, predictions(seqs), "got10k")
    name = seqs[0].name
    (d / name / f"{name}_002.txt").write_text((d / name / f"{name}_001.txt").read_text())
    monkeypatch.setattr(cli, "load_dataset", lambda name, root, extra=None: seqs)
    assert cli.main(["eval", str(d), "--dataset", "toy", "--root", "x", "--no-save"]) == 0
    assert (f"1 sequence(s) have repetitions beyond <seq>_001.txt: only the first is scored ({name})"
            in capsys.readouterr().out)


def test_eval_cli_reports_unknown_dataset(tmp_path, capsys):
    d = write_foreign(tmp_path, predictions(make_sequences()), "pysot")
    assert cli.main(["eval", str(d), "--dataset", "no_such_dataset", "--root", "x"]) == 2
    assert "unknown dataset 'no_such_dataset'" in capsys.readouterr().err


def test_eval_cli_on_real_dtb70_results(shared_data, tmp_path, capsys):
    """End to end with the dtb70 dataset plugin, when it is installed."""
    from mata_eval.core.registry import load_registry

    if "dtb70" not in load_registry().names("dataset"):
        pytest.skip("dataset plugin 'dtb70' not available yet")
    with zipfile.ZipFile(shared_data / "results" / "DTB70.zip") as z:
        z.extractall(tmp_path, [n for n in z.namelist() if n.startswith("DTB70/SiamAPN++/")])
    ann = shared_data / "annotations" / "DTB70"  # annotation-only folder: <seq>.txt + att/
    rc = cli.main(["eval", str(tmp_path / "DTB70" / "SiamAPN++"), "--dataset", "dtb70",
                   "--root", str(ann), "--set", f"annotations={ann}", "--profile", "pysot-toolkit",
                   "--output", str(tmp_path / "out"), "--challenges"])
    assert rc == 0
    # DTB70 has no attribute of the high-dynamic group: its column is left out, and said (QA pass 14)
    assert "; no sequence is in high dynamic (left out)" in capsys.readouterr().out
    sc = evaluate.load_scores(tmp_path / "out")
    assert round(sc.summary.overall.msr, 3) == 0.594 and round(sc.summary.overall.precision20, 3) == 0.789


def test_real_got10k_layout_is_read(shared_data, tmp_path):
    """NanoTrack v3's GOT-10k val results (got10k toolkit layout): detected, one box per timed
    frame, tracker wall-clock rate from the _time.txt files."""
    prefix = "NanoTrackV3/GOT-10k/nanotrack/"
    with zipfile.ZipFile(shared_data / "results" / "NanoTrackV3.zip") as z:
        names = [n for n in z.namelist() if n.startswith(prefix + "GOT-10k_Val_00000")]
        z.extractall(tmp_path, names)
    d = tmp_path / prefix
    assert evaluate.detect_layout(d) == "got10k"
    layout, found = evaluate.read_results(d)
    assert len(found) == 9
    for name, res in found.items():
        times = np.loadtxt(d / name / f"{name}_time.txt")
        assert res.boxes.shape == (len(times), 4) and np.all(res.boxes[:, 2:] > 0)
        assert np.isnan(res.wall_ms["tracker"]).sum() == np.sum(times <= 0)
        seq = Sequence(name, res.boxes.copy())  # its own boxes as ground truth: a perfect score
        s = evaluate.score_results({name: res}, [seq])[0][name]
        assert s.msr == pytest.approx(20 / 21) and s.nt2f == 1.0


def test_eval_of_a_run_folder_takes_the_runs_dataset_parameters(tmp_path, monkeypatch, capsys):
    """``eval RUN --dataset synthetic`` without ``--set`` generated the default 20 x 300 suite
    at 1280 x 720 (1.1 GB, a minute) and then failed on the frame count (QA pass): for a run
    folder of that dataset the run's own parameters are used, and said so; ``--set`` changes
    one of them (it replaced them all: QA pass, the default suite again), ``KEY=null`` puts one
    back to its default; given ``--root``, the user's parameters are used as they are."""
    seqs = make_sequences()[:2]
    d = tmp_path / "run"
    for s in seqs:
        results.write_sequence(d, s.name, s.groundtruth, "frame,scored\n" + "".join(f"{k},1\n" for k in range(len(s))), "")
    results.write_json(d / "manifest.json", {"config": {"dataset": {"name": "synthetic", "n_frames": 60,
                                                                    "width": 320, "root": None}}})
    calls = []
    monkeypatch.setattr(cli, "load_dataset", lambda name, root, extra=None: (calls.append(extra), seqs)[1])
    assert cli.main(["eval", str(d), "--dataset", "synthetic", "--no-save"]) == 0
    assert calls[-1] == {"n_frames": 60, "width": 320}
    assert f"dataset synthetic with the parameters of {d / 'manifest.json'}" in capsys.readouterr().out
    assert cli.main(["eval", str(d), "--dataset", "synthetic", "--set", "n_frames=30", "--no-save"]) == 0
    assert calls[-1] == {"n_frames": 30, "width": 320}
    assert "manifest.json, with --set n_frames=30" in capsys.readouterr().out
    assert cli.main(["eval", str(d), "--dataset", "synthetic", "--set", "width=null", "--no-save"]) == 0
    assert calls[-1] == {"n_frames": 60, "width": None}   # None: the default (the plugin's parameters drop it)
    capsys.readouterr()
    assert cli.main(["eval", str(d), "--no-save"]) == 0   # its dataset too (QA pass 16b: --dataset was required)
    assert calls[-1] == {"n_frames": 60, "width": 320}
    assert f"dataset synthetic, as {d / 'manifest.json'} names it" in capsys.readouterr().out
    assert cli.main(["eval", str(tmp_path), "--no-save"]) == 2
    assert "is not a mata-eval run folder with a readable manifest.json naming its dataset: give --dataset" in \
        capsys.readouterr().err
    foreign = tmp_path / "pysot"   # a folder of another toolkit first: the first run folder names it (QA pass 16c)
    foreign.mkdir()
    for s in seqs:
        (foreign / f"{s.name}.txt").write_text((d / f"{s.name}.txt").read_text())
    assert cli.main(["eval", str(foreign), str(d), "--no-save"]) == 0
    assert f"dataset synthetic, as {d / 'manifest.json'} names it" in capsys.readouterr().out
    other = tmp_path / "other"   # run folders of two datasets: which one is for --dataset to say (QA review)
    results.write_json(other / "manifest.json", {"config": {"dataset": {"name": "folder", "root": "x"}}})
    capsys.readouterr()
    assert cli.main(["eval", str(d), str(other), "--no-save"]) == 2
    assert "were made on different datasets (folder, synthetic); eval scores them against one" in capsys.readouterr().err
    assert cli.main(["eval", str(d), "--dataset", "dtb70", "--root", "/x", "--no-save"]) == 0
    assert calls[-1] == {}


def test_eval_of_an_occluded_run_folder_gives_back_the_runs_own_scores(tmp_path, monkeypatch, capsys):
    """A run made with ``occlusion: {}`` scored again by ``eval RUN --dataset synthetic`` (what
    ``report`` tells a user to do when the experiment file changed): the same scores, the AOC
    occlusion group and the occluded-frame scores included (QA pass: both were lost)."""
    monkeypatch.setenv("MATA_EVAL_CACHE", str(tmp_path / "cache"))
    exp = tmp_path / "occ.yaml"
    exp.write_text(f"output: {tmp_path / 'out'}\nseed: 3\n"
                   "dataset: {name: synthetic, n_sequences: 2, n_frames: 40, width: 160, height: 120}\n"
                   "occlusion: {}\ntracker: {name: kcf}\n")
    assert cli.main(["run", str(exp), "-j", "1", "-q"]) == 0
    run = tmp_path / "out" / "occ"
    own = json.loads((run / "scores.json").read_text())
    assert own["summary"]["groups"]["occlusion"]["n_sequences"] >= 1   # the suite is occluded
    capsys.readouterr()
    assert cli.main(["eval", str(run), "--dataset", "synthetic", "--output", str(tmp_path / "again")]) == 0
    assert "with the run's occlusion augmentation (seed 3)" in capsys.readouterr().out
    again = json.loads((tmp_path / "again" / "scores.json").read_text())
    assert again["summary"] == own["summary"] and again["sequences"] == own["sequences"]
    # the Python API, from another folder: the same (it scored the default 20 x 300 suite, unoccluded)
    monkeypatch.chdir(tmp_path / "out")
    api = me.evaluate(run, dataset="synthetic").to_dict()
    assert api["summary"] == own["summary"] and api["sequences"] == own["sequences"]
    with pytest.raises(ValueError, match="unknown parameter 'n_framez'"):   # (QA pass 16c: None hid a typo)
        me.evaluate(run, dataset="synthetic", n_framez=None)
    n_frames = me.evaluate(run, dataset="synthetic", n_frames=30)   # a keyword on top of the run's parameters
    assert set(n_frames.meta["unscorable"]) == set(own["sequences"]) and not n_frames.sequences   # 40 lines, 30 frames


def test_rescoring_an_occluded_run_without_its_frames_says_what_is_lost(capsys):
    """The occluders' placement needs each sequence's image size (frame 0): annotations only,
    the run is scored without the augmentation and the user is told, not given a traceback."""
    seqs = make_sequences()[:1]          # annotations only: no frames
    import dataclasses

    from mata_eval.data.occlusion import OcclusionParams

    config = {"dataset": {"name": "toy"}, "occlusion": dataclasses.asdict(OcclusionParams()), "seed": 1}
    assert as_the_run_saw_them(seqs, config, lambda line: print(f"RUN: {line}")) is seqs
    assert "RUN: scored without the run's occlusion augmentation (no AOC group" in capsys.readouterr().out


def test_a_run_folders_sequence_named_like_a_timing_file_is_scored(tmp_path, capsys):
    """A mata run folder writes no <seq>_time.txt, so a sequence named ``lap_time`` is a
    sequence (QA pass: its lap_time.txt was skipped as a pytracking timing file and the finished
    sequence counted as without results)."""
    seqs = [Sequence("lap_time", np.tile([20.0, 20.0, 10.0, 10.0], (N, 1)), fps=30.0)]
    d = tmp_path / "exp" / "run"
    results.write_manifest(d, {"run": "run", "experiment": "exp", "config_hash": "abc", "config": {}})
    results.write_sequence(d, "lap_time", seqs[0].groundtruth, frames_csv(np.ones(N, bool), np.full(N, 5.0)), "")
    sc = evaluate.evaluate_run(d, seqs)
    assert list(sc.sequences) == ["lap_time"] and not sc.missing
    assert sc.sequences["lap_time"].sr > 0.9   # exact boxes
    assert evaluate.stale_reason(sc, d) is None
    # a scores.json whose block rates counted the initialisation (an older mata-eval) is scored again
    older = dataclasses.replace(sc, meta={k: v for k, v in sc.meta.items() if k != "frequency_rule"})
    assert evaluate.older_rates(older) and not evaluate.older_rates(sc)
    # given as a file (no rescoring there), its table says so (QA pass 16c: shown as it was)
    cli._print_incomplete([older])
    assert f"{d}: its block rates (Hz) count frame 0, the initialisation" in capsys.readouterr().out


def test_a_foreign_folder_whose_first_file_is_not_text_scores_the_others(tmp_path):
    """Review: detecting the layout read the first prediction file as text, so a binary one
    failed the whole eval with a decode error that named no file."""
    seqs = make_sequences()
    d = tmp_path / "pysot"
    d.mkdir()
    (d / "bike.txt").write_bytes(b"\xff\xfe\x00\x01garbage")   # sorted first
    np.savetxt(d / "car2.txt", predictions(seqs)["car2"], fmt="%g", delimiter=",")
    sc = evaluate.evaluate_results(d, seqs, layout="auto")
    assert sc.layout == "pysot" and list(sc.sequences) == ["car2"]
    assert re.search(r"bike\.\*: not text", sc.meta["unscorable"]["bike"])


def test_a_sequences_list_in_another_order_is_the_same_dataset(tmp_path):
    """`eval RUN --set sequences=[b, a]` of a run made with [a, b] scores the run's own dataset,
    so its scores.json is written (QA pass: the order made it "other dataset parameters")."""
    key = lambda names: cli._dataset_key({"name": "folder", "root": "data", "sequences": names}, tmp_path)
    assert key(["b", "a"]) == key(["a", "b"]) != key(["a"])


def test_null_gives_a_parameters_default_and_a_misspelt_one_is_named(tmp_path):
    """QA passes 16a-c: `--set fps=null` was refused ("expected float, got None") and
    `--set fpz=null` accepted without a word."""
    _, params = cli._dataset_params("folder", str(tmp_path), {"fps": None, "sequences": None})
    assert params.fps == 30.0 and params.sequences is None
    with pytest.raises(ValueError, match="unknown parameter 'fpz'"):
        cli._dataset_params("folder", str(tmp_path), {"fpz": None})


def test_a_mata_run_pairs_with_a_baseline_whose_sequences_list_is_in_another_order():
    """QA review: eval counts a reordered list as the same dataset, but the MATA-minus-baseline
    table did not pair such runs; different names still do not pair."""
    from mata_eval.report.overview import _key

    cfg = lambda names, **blocks: {"dataset": {"name": "folder", "sequences": names}, "tracker": {"name": "kcf"},  # noqa: E731
                                   **blocks}
    assert _key(cfg(["a", "b"])) == _key(cfg(["b", "a"], egomotion={"name": "grid_lk"})) != _key(cfg(["a"]))
