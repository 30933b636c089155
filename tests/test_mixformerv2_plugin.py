"""The MixFormerV2 and OSTrack plugins without torch: both modules import, declare their
parameters and register, so `mata-eval list` works when the torch extra is not installed."""

from __future__ import annotations

import subprocess
import sys


def test_modules_import_without_torch():
    code = (
        "import sys\n"
        "class NoTorch:\n"
        "    def find_spec(self, name, path, target=None):\n"
        "        if name == 'torch' or name.startswith('torch.'):\n"
        "            raise ImportError('torch blocked')\n"
        "sys.meta_path.insert(0, NoTorch())\n"
        "from mata_eval.params import describe\n"
        "from mata_eval_plugins.trackers import mixformerv2, ostrack\n"
        "print(mixformerv2.mata_eval_trackers()[0].name, ostrack.mata_eval_trackers()[0].name,\n"
        "      len(describe(mixformerv2.MixFormerV2.Params)))\n"
    )
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stderr
    assert res.stdout.split()[:2] == ["mixformerv2", "ostrack"]


def test_registry_sees_both_plugins():
    from mata_eval.core.registry import load_registry

    reg = load_registry()
    assert {"mixformerv2", "ostrack"} <= set(reg.plugins["tracker"])
    assert not [f for f in reg.failures if f.entry_point in ("mixformerv2", "ostrack")]
