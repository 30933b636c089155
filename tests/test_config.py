"""Experiment files: matrix expansion, validation, and errors that name file, line and key."""

import textwrap
from dataclasses import dataclass

import pytest

from mata_eval.run.config import load_experiment
from mata_eval.core.errors import ConfigError
from mata_eval.params import param
from mata_eval.core.registry import PluginEntry, Registry


def _plugin(kind, name, **fields):
    ns = {"__annotations__": {k: type(v) for k, v in fields.items()}}
    ns.update({k: param(v, k) for k, v in fields.items()})
    params = dataclass(frozen=True)(type("Params", (), ns))
    cls = type(name, (), {"name": name, "Params": params, "__doc__": f"{name} plugin",
                          "__init__": lambda self, p: setattr(self, "params", p)})
    return PluginEntry(kind, name, cls, "test", f"{name} plugin")


REG = Registry({
    "dataset": {"toy": _plugin("dataset", "toy", root="x")},
    "tracker": {"a": _plugin("tracker", "a", padding=2.0), "b": _plugin("tracker", "b", depth=4)},
    "egomotion": {"grid_lk": _plugin("egomotion", "grid_lk", grid=16)},
    "estimator": {"ekf": _plugin("estimator", "ekf", model="cv", tau=0.5)},
    "protocol": {"ltp": _plugin("protocol", "ltp"), "eop": _plugin("protocol", "eop", tracker_hz=10.0)},
}, ())


def write(tmp_path, text):
    p = tmp_path / "exp.yaml"
    p.write_text(textwrap.dedent(text))
    return p


def test_matrix_expands_to_named_runs_with_merged_blocks(tmp_path):
    p = write(tmp_path, """\
        seed: 3
        output: out
        dataset: {name: toy}
        tracker: {name: a, padding: 3}
        egomotion: {name: grid_lk}
        estimator: {name: ekf}
        protocol: ltp
        matrix:
          mata:
            off: {egomotion: null, estimator: null}
            on: {}
            ca: {estimator: {model: ca}}
          protocol:
            ltp: {name: ltp}
            eop10: {name: eop, tracker_hz: 10}
        """)
    exp = load_experiment(p, REG)
    assert [r.name for r in exp.runs] == ["off-ltp", "off-eop10", "on-ltp", "on-eop10", "ca-ltp", "ca-eop10"]
    runs = {r.name: r for r in exp.runs}
    assert runs["off-ltp"].egomotion is None and runs["off-ltp"].estimator is None
    assert runs["ca-eop10"].estimator.params.model == "ca"
    assert runs["ca-eop10"].estimator.params.tau == 0.5       # merged, not replaced
    assert runs["on-eop10"].protocol.params.tracker_hz == 10.0
    assert runs["on-ltp"].tracker.params.padding == 3.0
    assert all(r.seed == 3 for r in exp.runs)
    assert exp.output == tmp_path.cwd() / "out" or exp.output.name == "out"
    assert len({r.config_hash for r in exp.runs}) == 6


def test_block_with_other_name_replaces(tmp_path):
    p = write(tmp_path, """\
        dataset: toy
        tracker: {name: a, padding: 3}
        matrix:
          tracker:
            a: {}
            b: {name: b, depth: 8}
        """)
    runs = {r.name: r for r in load_experiment(p, REG).runs}
    assert runs["b"].tracker.name == "b" and runs["b"].tracker.params.depth == 8
    assert runs["a"].tracker.params.padding == 3.0


def error(tmp_path, text):
    with pytest.raises(ConfigError) as err:
        load_experiment(write(tmp_path, text), REG)
    return str(err.value)


def test_every_problem_of_a_file_is_said_once_each(tmp_path):
    """Each plugin block, the other keys and each run of the matrix are checked, so a file with
    three mistakes takes one round, not three (QA pass); one found in every run is said once."""
    p = write(tmp_path, """        dataset: {name: toy, root: 3}
        tracker: {name: a, padding: fast}
        protocol: {name: eop, tracker_hz: x}
        seed: y
        matrix:
          m:
            one: {}
            two: {estimator: {name: ekf, tau: z}}
        """)
    with pytest.raises(ConfigError) as err:
        load_experiment(p, REG)
    assert str(err.value).splitlines() == [
        f"{p}:1: dataset.root: expected str, got 3 (int)",
        f"{p}:2: tracker.padding: expected float, got 'fast' (str)",
        f"{p}:3: protocol.tracker_hz: expected float, got 'x' (str)",
        f"{p}:4: seed: expected an integer seed, got 'y'",
        f"{p}:8: estimator.tau: expected float, got 'z' (str)"]
    assert err.value.location == f"{p}:1" and err.value.keypath == ("dataset", "root")   # reads as the first
    one = write(tmp_path, "dataset: {name: toy}\ntracker: {name: a, padding: fast}\n")
    with pytest.raises(ConfigError) as err:
        load_experiment(one, REG)
    assert str(err.value) == f"{one}:2: tracker.padding: expected float, got 'fast' (str)"


def test_unknown_plugin_lists_available_names_and_line(tmp_path):
    msg = error(tmp_path, """\
        dataset: toy
        tracker:
          name: mixformer
        """)
    assert "exp.yaml:3" in msg and "tracker.name" in msg
    assert "unknown tracker 'mixformer'; available: a, b" in msg


def test_bad_parameter_type_points_at_its_line(tmp_path):
    msg = error(tmp_path, """\
        dataset: toy
        tracker:
          name: a
          padding: wide
        """)
    assert "exp.yaml:4: tracker.padding: expected float, got 'wide'" in msg


def test_bad_parameter_inside_matrix_points_at_the_matrix_line(tmp_path):
    msg = error(tmp_path, """\
        dataset: toy
        tracker: a
        estimator: ekf
        matrix:
          variant:
            good: {}
            bad:
              estimator: {tau: high}
        """)
    assert "exp.yaml:8" in msg and "estimator.tau" in msg and "expected float" in msg


@dataclass(frozen=True)
class _Checked:
    """Params with a cross-field check, as a plugin's ``__post_init__`` makes one."""
    model: str = param("homography", "model")
    method: str = param("ransac", "method")

    def __post_init__(self):
        if self.method != "ransac" and self.model != "homography":
            raise ValueError(f"method {self.method} needs model homography")


def test_a_cross_field_error_points_at_the_matrix_entry_that_made_the_combination(tmp_path):
    """A plugin's own check of several keys (``__post_init__``) fails for one run of the matrix:
    the line is that matrix entry's, not the base block's (QA pass); an invalid base block still
    gets its own line."""
    checked = PluginEntry("egomotion", "checked", type("checked", (), {"Params": _Checked, "name": "checked"}),
                          "test", "checked")
    reg = Registry({**REG.plugins, "egomotion": {"checked": checked}}, ())
    text = """\
        dataset: toy
        tracker: a
        egomotion: {name: checked%s}
        matrix:
          egomotion:
            plain: {}
            fast:
              method: usac
              model: affine
        """
    with pytest.raises(ConfigError) as err:
        load_experiment(write(tmp_path, text % ""), reg)
    assert "exp.yaml:7: egomotion: method usac needs model homography" in str(err.value)
    with pytest.raises(ConfigError) as err:
        load_experiment(write(tmp_path, text % ", model: affine, method: usac"), reg)
    assert "exp.yaml:3: egomotion: method usac needs model homography" in str(err.value)


def test_unknown_top_level_key(tmp_path):
    msg = error(tmp_path, "dataset: toy\ntracker: a\ntrackers: b\n")
    assert "exp.yaml:3" in msg and "unknown key" in msg and "tracker" in msg


def test_missing_tracker(tmp_path):
    assert "missing required key 'tracker'" in error(tmp_path, "dataset: toy\n")


def test_invalid_yaml_names_line(tmp_path):
    msg = error(tmp_path, "dataset: toy\ntracker: [a\nseed: 1\n")
    assert "exp.yaml:" in msg and "not valid YAML" in msg


def test_python_tags_are_refused(tmp_path):
    msg = error(tmp_path, "dataset: toy\ntracker: !!python/object/apply:os.system ['true']\n")
    assert "not valid YAML" in msg


def test_seed_must_be_integer(tmp_path):
    assert "seed: expected an integer seed" in error(tmp_path, "dataset: toy\ntracker: a\nseed: x\n")


def test_unknown_metric_profile(tmp_path):
    msg = error(tmp_path, "dataset: toy\ntracker: a\nmetrics: {profile: vot2099}\n")
    assert "exp.yaml:3" in msg and "unknown metric profile 'vot2099'" in msg and "pysot-toolkit" in msg


def test_a_misspelt_plugin_axis_suggests_the_plugin_key(tmp_path):
    """``trackr:`` as a matrix axis reads its labels' values as top-level overrides, so its
    ``name`` key is refused; the error suggests the axis ``tracker`` (QA pass: no hint)."""
    msg = error(tmp_path, """\
        dataset: toy
        tracker: a
        matrix:
          trackr:
            b: {name: b}
        """)
    assert "exp.yaml:5" in msg and "cannot override 'name' in a matrix" in msg
    assert "did you mean the axis 'tracker'?" in msg


def test_runs_of_the_built_in_plugins_record_no_plugin_versions():
    """Third-party plugins' versions enter the configuration (and so the hash); mata-eval's own
    plugins do not, so that no stored run of them changes its hash."""
    from mata_eval.run.config import find_experiment

    exp = load_experiment(find_experiment("quickstart"))
    assert exp.runs and all("plugin_versions" not in r.resolved for r in exp.runs)


@pytest.mark.parametrize("text, message", [
    ("dataset: toy\ntracker: a\nseed: -1\n", "seed: expected an integer seed >= 0, got -1"),
    ("dataset: toy\ntracker: a\nmatrix: [a, b]\n", "matrix: expected a mapping of axes"),
    ("dataset: toy\ntracker: a\nmatrix: {o: {x: {output: /elsewhere}, y: {}}}\n", "cannot override 'output' in a matrix"),
    ("dataset: toy\ntracker: a\nmatrix: {m: {A: {}, a: {}}}\n", "duplicate run names (letter case aside)"),
    ("dataset: toy\ntracker: a\nmatrix: {m: {" + "x" * 101 + ": {}}}\n", "at most 100 characters"),
    ("dataset: toy\ntracker: a\nmatrix: {m: {\"a|b\": {}}}\n", "expected one folder name"),
    ("dataset: toy\ntracker: a\nmatrix: {m: {\"a\\nb\": {}}}\n", "expected one folder name"),
])
def test_what_passed_validate_and_failed_later_is_refused_when_loaded(tmp_path, text, message):
    """QA pass (adversarial inputs): each passed `validate`, then failed every sequence, was
    ignored, or wrote folders a file system refuses or merges."""
    assert message in error(tmp_path, text)


def test_an_experiment_file_is_utf8_whatever_the_locale(tmp_path, monkeypatch):
    p = tmp_path / "exp.yaml"
    p.write_bytes("# café\ndataset: toy\ntracker: a\n".encode("utf-8"))
    monkeypatch.setattr("locale.getpreferredencoding", lambda *a, **k: "ascii")
    assert load_experiment(p, REG).runs[0].name == "exp"
    p.write_bytes(b"# caf\xe9\ndataset: toy\ntracker: a\n")     # Latin-1
    with pytest.raises(ConfigError, match="not UTF-8 text .byte 5.: save the experiment file as UTF-8"):
        load_experiment(p, REG)
