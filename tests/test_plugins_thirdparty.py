"""A real third-party plugin distribution (tests/thirdparty_plugin) is discovered through the
entry-point group, listed, and usable from YAML without touching mata-eval; a broken plugin is
reported and the others keep working."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

HERE = Path(__file__).resolve().parent


def _env(site: Path) -> dict:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(site), env.get("PYTHONPATH", "")]).rstrip(os.pathsep)
    return env


def _cli(args, site, cwd=None):
    return subprocess.run([sys.executable, "-m", "mata_eval.cli", *args], env=_env(site), cwd=cwd,
                          capture_output=True, text=True, timeout=300)


@pytest.fixture(scope="module")
def site(tmp_path_factory) -> Path:
    """Install the plugin distribution (built from its own pyproject.toml) into a fresh folder on
    the path, plus a hand-made distribution whose module fails to import."""
    target = tmp_path_factory.mktemp("site")
    subprocess.run([sys.executable, "-m", "pip", "install", "--quiet", "--no-deps", "--no-build-isolation",
                    "--target", str(target), str(HERE / "thirdparty_plugin")], check=True, timeout=300)
    broken = target / "broken_plugin-0.1.dist-info"
    broken.mkdir()
    (broken / "METADATA").write_text("Metadata-Version: 2.1\nName: broken-plugin\nVersion: 0.1\n")
    (broken / "entry_points.txt").write_text("[mata_eval]\nbroken = broken_plugin_module\n")
    (target / "broken_plugin_module.py").write_text("import not_a_real_dependency_xyz\n")
    half = target / "half_plugin-0.1.dist-info"   # classes that are not whole plugins
    half.mkdir()
    (half / "METADATA").write_text("Metadata-Version: 2.1\nName: half-plugin\nVersion: 0.1\n")
    (half / "entry_points.txt").write_text("[mata_eval]\nhalf = half_plugin_module\n")
    (target / "half_plugin_module.py").write_text(textwrap.dedent("""\
        from dataclasses import dataclass
        from mata_eval.hooks import hookimpl

        class NoParams:
            name = "noparams"
            def initialize(self, image, box): pass
            def track(self, image, prior=None): pass

        class NoTrack:
            name = "notrack"
            @dataclass(frozen=True)
            class Params:
                pass
            def initialize(self, image, box): pass

        @hookimpl
        def mata_eval_trackers():
            return [NoParams, NoTrack]
        """))
    return target


def test_list_shows_third_party_tracker_and_the_broken_plugin(site):
    out = _cli(["list"], site)
    assert out.returncode == 0, out.stderr
    line = next(l for l in out.stdout.splitlines() if "template_tracker" in l)
    assert "[mata-eval-template-tracker]" in line
    assert "Normalised cross-correlation against the first-frame template" in line
    assert "broken  [broken-plugin]  ModuleNotFoundError: No module named 'not_a_real_dependency_xyz'" in out.stdout
    # QA pass: these were listed, then failed validate with an AttributeError from inside mata-eval
    assert "tracker 'noparams'  [half-plugin]  not used: it has no Params dataclass" in out.stdout
    assert ("tracker 'notrack'  [half-plugin]  not used: it has no track method (a tracker plugin needs "
            "initialize, track" in out.stdout)
    assert "noparams  [half-plugin]" not in out.stdout and "notrack  [half-plugin]" not in out.stdout


def test_third_party_tracker_runs_from_yaml(site, tmp_path):
    import cv2
    import numpy as np

    # A 12-frame sequence in the generic folder layout: a textured square moving 3 px per frame.
    seq = tmp_path / "data" / "square"
    (seq / "img").mkdir(parents=True)
    rng = np.random.default_rng(0)
    patch = rng.integers(0, 255, (20, 20, 3), dtype=np.uint8)
    lines = []
    for k in range(12):
        img = np.full((120, 160, 3), 90, np.uint8)
        x, y = 30 + 3 * k, 40 + k
        img[y:y + 20, x:x + 20] = patch
        cv2.imwrite(str(seq / "img" / f"{k + 1:04d}.png"), img)
        lines.append(f"{x},{y},20,20")
    (seq / "groundtruth.txt").write_text("\n".join(lines) + "\n")
    exp = tmp_path / "exp.yaml"
    exp.write_text(textwrap.dedent(f"""\
        seed: 0
        output: {tmp_path / 'results'}
        dataset: {{name: folder, root: {tmp_path / 'data'}}}
        tracker: {{name: template_tracker, search: 3.0}}
        protocol: {{name: ltp}}
        """))
    out = _cli(["run", str(exp), "--jobs", "1", "--quiet"], site, cwd=tmp_path)
    assert out.returncode == 0, out.stdout + out.stderr
    pred = np.loadtxt(tmp_path / "results" / "exp" / "square.txt", delimiter=",")
    gt = np.loadtxt(seq / "groundtruth.txt", delimiter=",")
    assert pred.shape == (12, 4)
    np.testing.assert_allclose(pred, gt, atol=1.0)
    # the plugin's distribution and version are part of the run's configuration (manifest and
    # hash): results of an upgraded plugin are not mixed with these (QA pass)
    import json

    manifest = json.loads((tmp_path / "results" / "exp" / "manifest.json").read_text())
    assert manifest["config"]["plugin_versions"] == {"mata-eval-template-tracker": "1.0.0"}


def test_readme_example_is_the_tested_plugin():
    readme = (HERE.parent / "README.md").read_text()
    code = (HERE / "thirdparty_plugin" / "mata_eval_template_tracker" / "__init__.py").read_text()
    body = code.split("\n", 2)[2].lstrip("\n")  # without the module docstring
    assert f"```python\n{body}```" in readme
