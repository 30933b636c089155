"""ONNX inference backends: ONNX Runtime on the CPU with the real VitTrack graph, and clear
errors for backends this machine lacks."""

import importlib.util

import numpy as np
import pytest

from mata_eval_plugins.trackers.backends import BackendUnavailable, open_onnx

ort = pytest.importorskip("onnxruntime")


def test_onnxruntime_cpu_runs_the_real_vittrack_graph(shared_data):
    run = open_onnx(shared_data / "models/vittrack/object_tracking_vittrack_2023sep.onnx", threads=1)
    rng = np.random.default_rng(0)
    feeds = {"template": rng.random((1, 3, 128, 128), np.float32), "search": rng.random((1, 3, 256, 256), np.float32)}
    out = run(feeds)
    assert sorted(v.shape for v in out.values()) == [(1, 1, 16, 16), (1, 2, 16, 16), (1, 2, 16, 16)]
    again = run(feeds)  # deterministic on the CPU
    for k in out:
        np.testing.assert_array_equal(out[k], again[k])


def test_missing_device_names_available_providers(shared_data):
    if "CUDAExecutionProvider" in ort.get_available_providers():
        pytest.skip("this onnxruntime has CUDA")
    with pytest.raises(BackendUnavailable, match="CUDAExecutionProvider.*CPUExecutionProvider"):
        open_onnx(shared_data / "models/vittrack/object_tracking_vittrack_2023sep.onnx", device="cuda")


def test_tensorrt_absent_gives_clear_error(shared_data):
    if importlib.util.find_spec("tensorrt") is not None:
        pytest.skip("TensorRT is installed here")
    with pytest.raises(BackendUnavailable, match="TensorRT is not installed"):
        open_onnx(shared_data / "models/vittrack/object_tracking_vittrack_2023sep.onnx", backend="tensorrt")


def test_missing_file(tmp_path):
    with pytest.raises(FileNotFoundError, match="nothing.onnx"):
        open_onnx(tmp_path / "nothing.onnx")
