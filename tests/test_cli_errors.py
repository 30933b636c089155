"""User mistakes get one line naming the file and what to do (no traceback unless --debug); the
exit status is non-zero when any sequence failed."""

from __future__ import annotations

import dataclasses
import re
import textwrap

import numpy as np
import pytest

from mata_eval.cli import main
from mata_eval.core.registry import PluginEntry, _add


def _exp(tmp_path, body):
    p = tmp_path / "exp.yaml"
    p.write_text(textwrap.dedent(body))
    return p


def _one_line_error(capsys, *names):
    err = capsys.readouterr().err.strip()
    assert "Traceback" not in err and len(err.splitlines()) == 1, err
    assert err.startswith("error: ")
    for name in names:
        assert name in err, err
    return err


def test_a_missing_dataset_root_is_one_line(tmp_path, capsys):
    p = _exp(tmp_path, f"""\
        output: {tmp_path / 'out'}
        dataset: {{name: folder, root: {tmp_path / 'nowhere'}}}
        tracker: kcf
        """)
    assert main(["run", str(p), "-j", "1", "-q"]) == 2
    _one_line_error(capsys, str(tmp_path / "nowhere"))
    with pytest.raises(Exception, match="nowhere"):
        main(["--debug", "run", str(p), "-j", "1", "-q"])


def test_an_unknown_run_is_one_line(tmp_path, capsys):
    p = _exp(tmp_path, """\
        dataset: {name: synthetic}
        tracker: kcf
        """)
    assert main(["run", str(p), "--runs", "nope", "-q", "-o", str(tmp_path / "o")]) == 2
    _one_line_error(capsys, "nope", "exp")


def test_force_with_minus_one_jobs_deletes_nothing(tmp_path, capsys):
    run = tmp_path / "o" / "exp"
    run.mkdir(parents=True)
    p = _exp(tmp_path, "dataset: {name: synthetic}\ntracker: kcf\n")
    assert main(["run", str(p), "--force", "-j", "-1", "-q", "-o", str(tmp_path / "o")]) == 2
    _one_line_error(capsys, "jobs")


def test_corrupt_run_files_name_the_file(tmp_path, capsys):
    from mata_eval.run import results

    (tmp_path / "manifest.json").write_text("{not json")
    with pytest.raises(results.CorruptFile, match=r"manifest\.json: not valid JSON"):
        results.read_manifest(tmp_path)
    (tmp_path / "manifest.json").unlink()
    (tmp_path / "a.failed.json").write_text("[]")
    with pytest.raises(results.CorruptFile, match=r"a\.failed\.json"):
        results.read_failures(tmp_path)


def test_a_third_party_plugin_cannot_take_a_built_in_name():
    class KCF:
        pass

    class Other:
        pass

    names = {}
    builtin = PluginEntry("tracker", "kcf", KCF, "mata-eval", "")
    thief = PluginEntry("tracker", "kcf", Other, "evil-trackers", "")
    assert _add(names, thief) is None
    failure = _add(names, builtin)  # registered later, still wins
    assert names["kcf"] is builtin
    assert failure.package == "evil-trackers" and "taken by" in failure.error


def test_eval_on_a_folder_it_cannot_write_says_what_to_do(tmp_path, capsys, monkeypatch):
    """(The tests may run as root, for whom no folder is read-only: the write is made to fail.)"""
    from mata_eval.run import results

    run = tmp_path / "run"
    gt = "1,2,3,4\n" * 3
    (tmp_path / "data" / "seq").mkdir(parents=True)
    (tmp_path / "data" / "seq" / "groundtruth_rect.txt").write_text(gt)
    results.write_sequence(run, "seq", np.array([[1.0, 2, 3, 4]] * 3), "frame,scored\n0,1\n1,1\n2,1\n", "")
    from mata_eval.core.registry import load_registry
    from mata_eval.params import build_params

    folder = load_registry().get("dataset", "folder").cls   # the dataset as a run's manifest resolves it
    dataset = {"name": "folder", **dataclasses.asdict(build_params(folder.Params, {"root": str(tmp_path / "data")}))}
    results.write_manifest(run, {"run": "r", "config": {"dataset": dataset}})

    def refuse(path, text):
        raise PermissionError(13, "Permission denied", str(path))

    monkeypatch.setattr(results, "atomic_write_text", refuse)
    assert main(["eval", str(run), "--dataset", "folder", "--root", str(tmp_path / "data")]) == 2
    _one_line_error(capsys, "scores.json", str(run), "--no-save")
    assert main(["eval", str(run), "--dataset", "folder", "--root", str(tmp_path / "data"), "--no-save"]) == 0


def test_small_cli_mistakes_are_refused(tmp_path, capsys):
    """QA pass (adversarial): `-o ""` ran into the file's output, `--quality 500` and
    `--threads -4` were accepted, an empty `--sequences` augmented nothing and succeeded."""
    from mata_eval.cli import main

    assert main(["run", "quickstart", "-o", ""]) == 2
    assert "-o/--output: expected a folder, got an empty name" in capsys.readouterr().err
    for args in (["synth", str(tmp_path / "s"), "--quality", "500"],
                 ["profile", "quickstart", "--threads", "-4"]):
        with pytest.raises(SystemExit) as exit_:
            main(args)
        assert exit_.value.code == 2
    assert "expected an integer >= 0, got -4" in capsys.readouterr().err


def test_a_hand_edited_scores_file_is_named(tmp_path):
    """QA pass: a scores.json with a wrong type, a null or another format gave tracebacks or was
    read as it was."""
    import json

    from mata_eval.score.evaluate import load_scores

    good = {"format": 1, "name": "r", "path": str(tmp_path), "profile": "default", "layout": "mata",
            "sequences": {}, "attributes": {}, "summary": {}}
    for change, words in (({"name": 5}, "'name': expected text, got 5"), ({"format": 99}, "(got 99)"),
                          ({"sequences": None}, "not a mata-eval scores file")):
        (tmp_path / "scores.json").write_text(json.dumps({**good, **change}))
        with pytest.raises(ValueError, match=re.escape(words)):
            load_scores(tmp_path)


def test_an_interrupt_says_what_the_command_kept(monkeypatch, capsys):
    """QA pass 16b: Ctrl-C in `export` or `profile` said "finished sequences are saved; rerun the
    same command to resume", which neither has."""
    from mata_eval import cli

    def stopped(args):
        raise KeyboardInterrupt

    for command, argv, words in (("profile", ["x.yaml", "--out", "p.json"], "no profile written"),
                                 ("export", ["nanotrack", "--random-weights", "--out", "x"],
                                  "an earlier export there is kept, unless its files were being replaced"),
                                 ("run", ["x.yaml"], "finished sequences are saved; rerun the same command")):
        monkeypatch.setattr(cli, f"cmd_{command}", stopped)
        assert cli.main([command, *argv]) == 130
        assert f"interrupted: {words}" in capsys.readouterr().err


def test_random_weights_are_warned_of_also_in_an_export(tmp_path):
    """QA pass 16b: the graphs of `mata-eval export --random-weights` loaded and scored like real
    ones without a word (export.json says random_weights_seed); `random_weights: true` too."""
    import json
    from types import SimpleNamespace

    from mata_eval.run.preflight import random_weights

    export = tmp_path / "models" / "mixformerv2_s"
    export.mkdir(parents=True)
    (export / "export.json").write_text(json.dumps({"format": "mata-eval export", "random_weights_seed": 5}))
    real = tmp_path / "models" / "real"
    real.mkdir()
    (real / "export.json").write_text(json.dumps({"format": "mata-eval export", "random_weights_seed": None}))

    class Tracker:
        @staticmethod
        def model_files(params):
            return {"search": params.onnx / "search.onnx"} if params.onnx else {}

    spec = lambda run, **params: SimpleNamespace(   # noqa: E731
        name=run, tracker=SimpleNamespace(name="mixformerv2", cls=Tracker,
                                          params=SimpleNamespace(**{"random_weights": False, "onnx": None, **params})))
    lines = random_weights([spec("a", onnx=export), spec("b", onnx=real), spec("c", random_weights=True), spec("d")])
    # (run_experiment writes these lines into the run's manifest.json warnings too)
    assert lines == [f"tracker mixformerv2 (run a) reads {export}, an export of random weights (seed 5): its scores "
                     "measure timing and plumbing, not tracking",
                     "tracker mixformerv2 (run c): random_weights: true, so its scores measure timing and plumbing, "
                     "not tracking"]
