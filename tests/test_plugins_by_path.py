"""`name: "package.module:Class"` in a plugin block: a class loaded directly, without packaging,
from the folder mata-eval runs from. Its Params are validated like any plugin's, it runs through
the runner, and a bad path is a one-line error naming the file, the line and the YAML key."""

from __future__ import annotations

import textwrap

import cv2
import numpy as np
import pytest

from mata_eval.core.errors import ConfigError
from mata_eval.core.registry import load_registry
from mata_eval.data.datasets.annotations import read_boxes
from mata_eval.run.config import load_experiment
from mata_eval.run.runner import run_experiment

TRACKER_MODULE = '''
    from dataclasses import dataclass

    from mata_eval.params import param
    from mata_eval.types import Box, TrackerOutput


    class Drift:
        """Moves its box by `step` pixels to the right every frame."""

        @dataclass(frozen=True)
        class Params:
            step: float = param(1.0, "pixels per frame")

        def __init__(self, params):
            self.params = params

        def initialize(self, image, box):
            self.box = box

        def track(self, image, prior=None):
            b = self.box
            self.box = Box(b.x + self.params.step, b.y, b.w, b.h)
            return TrackerOutput(self.box, 1.0)


    class NoParams:
        pass


    class NoTrack:
        @dataclass(frozen=True)
        class Params:
            pass

        def initialize(self, image, box):
            pass


    class ComplexParam(Drift):
        @dataclass(frozen=True)
        class Params:
            gain: complex = param(1j, "no YAML value is one")


    def not_a_class():
        pass
'''


@pytest.fixture
def workdir(tmp_path, monkeypatch):
    """A folder with a module `my_trackers/drift.py` and a 3-frame sequence; mata-eval runs there."""
    pkg = tmp_path / "my_trackers"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("")
    (pkg / "drift.py").write_text(textwrap.dedent(TRACKER_MODULE))
    (pkg / "broken.py").write_text("import not_a_module_anywhere\n")
    seq = tmp_path / "data" / "toy"
    (seq / "img").mkdir(parents=True)
    for k in range(3):
        cv2.imwrite(str(seq / "img" / f"{k:04d}.png"), np.zeros((20, 30, 3), np.uint8))
    (seq / "groundtruth_rect.txt").write_text("2,3,4,5\n" * 3)
    monkeypatch.chdir(tmp_path)
    monkeypatch.syspath_prepend(str(tmp_path / "nowhere"))  # restores sys.path after the test
    return tmp_path


def experiment(workdir, tracker: str):
    path = workdir / "exp.yaml"
    path.write_text(f"output: out\ndataset: {{name: folder, root: data}}\ntracker: {tracker}\n")
    return path


def test_a_class_by_path_is_validated_and_runs(workdir):
    exp = load_experiment(experiment(workdir, '{name: "my_trackers.drift:Drift", step: 2}'), load_registry())
    spec = exp.runs[0]
    assert spec.tracker.params.step == 2.0 and spec.resolved["tracker"] == {"name": "my_trackers.drift:Drift",
                                                                           "step": 2.0}
    run_experiment(exp, progress=False, log=lambda line: None)
    boxes = read_boxes(workdir / "out" / "exp" / "toy.txt")
    # frame 0 is the ground truth, then 2 px to the right per tracker call (LTP: every frame)
    np.testing.assert_allclose(boxes, [[2, 3, 4, 5], [4, 3, 4, 5], [6, 3, 4, 5]])


@pytest.mark.parametrize("name, message", [
    ('"my_trackers.drift:Drift", step: fast', "tracker.step: expected float, got 'fast'"),
    ('"my_trackers.drift:Drift", speed: 2', "tracker.speed: unknown parameter 'speed'; this plugin takes: step"),
    ('"my_trackers.nothere:Drift"', "tracker.name: tracker 'my_trackers.nothere:Drift': cannot import "
                                    "'my_trackers.nothere' (ModuleNotFoundError"),
    ('"my_trackers.broken:Drift"', "cannot import 'my_trackers.broken' (ModuleNotFoundError: No module named "
                                   "'not_a_module_anywhere')"),
    ('"my_trackers.drift:Dirft"', "module 'my_trackers.drift'"),
    ('"my_trackers.drift:not_a_class"', "'not_a_class' is a function, not a class"),
    ('"my_trackers.drift:NoParams"', "class NoParams has no Params dataclass"),
    ('"my_trackers.drift:NoTrack"', "class NoTrack has no track method (a tracker plugin needs initialize, track"),
    ('"my_trackers/drift.py:Drift"', "is not a class path; expected 'package.module:Class', a tracker class"),
    # QA pass: loaded and listed, then every value refused ("expected complex, got 2")
    ('"my_trackers.drift:ComplexParam"', "class ComplexParam has parameters of a type no experiment file value "
                                         "can be: gain: complex"),
])
def test_a_bad_class_path_says_where_and_what_was_expected(workdir, name, message):
    path = experiment(workdir, f"{{name: {name}}}")
    with pytest.raises(ConfigError) as err:
        load_experiment(path, load_registry())
    text = str(err.value)
    assert text.startswith(f"{path}:3: tracker.") and message in text, text
    assert "\n" not in text


def test_an_unknown_plugin_lists_each_failed_entry_point_set_off():
    """The notes on entry points that failed to load follow the names that exist, each set off
    by '; note:' (QA pass: printed on one line, they ran together)."""
    from mata_eval.core.registry import LoadFailure, Registry

    reg = Registry({"tracker": {}}, (LoadFailure("a_plugin", "pkg-a", "ImportError: x"),
                                     LoadFailure("b_plugin", "pkg-b", "SyntaxError: y")))
    with pytest.raises(KeyError) as err:
        reg.get("tracker", "mine")
    assert err.value.args[0] == ("unknown tracker 'mine'; available: (none); note: a_plugin (pkg-a) failed to load: "
                                 "ImportError: x; note: b_plugin (pkg-b) failed to load: SyntaxError: y")
