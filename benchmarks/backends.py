"""Backend benchmark (issue 9): milliseconds per frame of each tracker model on each inference
backend available on this machine, and the parity of the outputs between backends, in one command:

    python benchmarks/backends.py [--models nanotrack,vittrack,mixformerv2,ostrack] [--frames 30]
                                  [--threads 2] [--variant S]

Frames: the real 1280x720 UAV123_10fps ``wakeboard7`` frames from ../shared/data (decoded once
beforehand), else a synthetic 1280x720 sequence. Each tracker is initialised on frame 0 and runs
``track`` on the next frames; the figure is the median ``track`` time after 3 warm-up frames. The backends of a model
run interleaved, frame by frame, so that load changes on a shared machine hit them alike.
Baseline measured in the same run: the model's first backend (torch where the model has a torch
implementation), printed as a ratio (baseline ms / backend ms; > 1 = faster than the baseline).
Parity: the largest box difference (pixels) and confidence difference from the baseline over the
sequence (same frames, same initial box), and for exported graphs the largest |onnxruntime -
torch| on the network outputs measured by ``mata-eval export``.

MixFormerV2 and OSTrack run with seeded random weights unless $MATA_MIXFORMERV2_S / $MATA_OSTRACK
name the official checkpoints (latency does not depend on the weights, MODELS.md 6). NanoTrack
uses ``nanotrackv2.pth`` and the published ONNX pair. The ONNX graphs of the torch models are
exported into a temporary folder first. TensorRT rows appear where TensorRT and a CUDA device
are present; ONNX Runtime CUDA / TensorRT providers where onnxruntime offers them.
"""

from __future__ import annotations

import argparse
import importlib.util
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "benchmarks"))


def shared_data_dir() -> Path:
    return Path(os.environ.get("MATA_SHARED_DATA", REPO.parent / "shared" / "data"))


def load_frames(n: int) -> tuple[list[np.ndarray], np.ndarray, str]:
    """Decoded frames and the initial box: wakeboard7 when present, else a synthetic square."""
    folder = shared_data_dir() / "sequences/uav123_10fps/wakeboard7"
    if folder.is_dir():
        from trackers import load_sequence

        frames, gt = load_sequence(folder, limit=n)
        return frames, gt[0], "UAV123_10fps wakeboard7 (real, 1280x720)"
    rng = np.random.default_rng(0)
    base = rng.integers(0, 255, (720, 1280, 3), dtype=np.uint8)
    frames = []
    for k in range(n):
        f = base.copy()
        f[300 + 2 * k:340 + 2 * k, 600 + 3 * k:660 + 3 * k] = (20, 220, 250)
        frames.append(f)
    return frames, np.array([600.0, 300.0, 60.0, 40.0]), "synthetic 1280x720"


def run_lockstep(trackers: list, frames, init) -> list[tuple[np.ndarray, np.ndarray, list[float]]]:
    """Boxes, confidences and per-frame ms of each tracker, all advanced frame by frame in turn
    (interleaved: a load change on a shared machine hits every backend alike)."""
    from mata_eval.types import Box

    for t in trackers:
        t.initialize(frames[0], Box.from_array(init))
    res = [([], [], []) for _ in trackers]
    for f in frames[1:]:
        for t, (boxes, conf, ms) in zip(trackers, res):
            t0 = time.perf_counter()
            out = t.track(f)
            ms.append(1e3 * (time.perf_counter() - t0))
            boxes.append(out.box.as_array())
            conf.append(out.confidence)
    return [(np.array(b), np.array(c), ms) for b, c, ms in res]


def ort_devices() -> list[str]:
    import onnxruntime as ort

    have = ort.get_available_providers()
    return [d for d, p in (("cpu", "CPUExecutionProvider"), ("cuda", "CUDAExecutionProvider"),
                           ("tensorrt", "TensorrtExecutionProvider")) if p in have]


def tensorrt_usable() -> bool:
    if importlib.util.find_spec("tensorrt") is None:
        return False
    import torch

    return torch.cuda.is_available()


def configurations(model: str, tmp: Path, threads: int, variant: str) -> tuple[list[tuple[str, object]], dict]:
    """(label, tracker) per backend, baseline first; and the export parity (graph -> max error)."""
    from mata_eval.deploy import export as E

    parity: dict[str, float] = {}
    rows: list[tuple[str, object]] = []
    data = shared_data_dir() / "models"
    if model == "nanotrack":
        from mata_eval_plugins.trackers.nanotrack import NanoTrack

        pth = data / "nanotrack/pth/nanotrackv2.pth"
        if not pth.is_file():
            return [], {}
        res = E.export_nanotrack(tmp / "nanotrack", pth)
        parity.update({f"export {g.role}": g.max_abs_error for g in res.graphs})
        rows.append(("torch (nanotrackv2.pth)", NanoTrack(NanoTrack.Params(backend="torch", checkpoint=str(pth), threads=threads))))
        for dev in ort_devices():
            rows.append((f"onnxruntime {dev} (published pair)", NanoTrack(NanoTrack.Params(
                backbone=str(data / "nanotrack/v2/nanotrack_backbone_sim.onnx"),
                head=str(data / "nanotrack/v2/nanotrack_head_sim.onnx"), device=dev, threads=threads))))
            rows.append((f"onnxruntime {dev} (exported)", NanoTrack(NanoTrack.Params(
                backbone=str(tmp / "nanotrack"), head=str(tmp / "nanotrack"), device=dev, threads=threads))))
        if tensorrt_usable():
            rows.append(("tensorrt (published pair)", NanoTrack(NanoTrack.Params(
                backbone=str(data / "nanotrack/v2/nanotrack_backbone_sim.onnx"),
                head=str(data / "nanotrack/v2/nanotrack_head_sim.onnx"), backend="tensorrt"))))
    elif model == "vittrack":
        from mata_eval_plugins.trackers.vittrack import VitTrack

        onnx = data / "vittrack/object_tracking_vittrack_2023sep.onnx"
        if not onnx.is_file():
            return [], {}
        for dev in ort_devices():
            rows.append((f"onnxruntime {dev}", VitTrack(VitTrack.Params(model=str(onnx), device=dev, threads=threads))))
        if tensorrt_usable():
            rows.append(("tensorrt", VitTrack(VitTrack.Params(model=str(onnx), backend="tensorrt"))))
    elif model == "mixformerv2":
        from mata_eval_plugins.trackers.mixformerv2 import VARIANTS, MixFormerV2

        ckpt = os.environ.get(VARIANTS[variant].env_var)
        weights = dict(checkpoint=ckpt) if ckpt else dict(random_weights=True, seed=0)
        torch_tracker = MixFormerV2(MixFormerV2.Params(variant=variant, threads=threads, **weights))
        res = E.export_mixformerv2(tmp / "mixformerv2", network=torch_tracker.network(), variant=variant)
        parity.update({f"export {g.role}": g.max_abs_error for g in res.graphs})
        net = torch_tracker.network()
        rows.append((f"torch {variant} (template K/V cache)", torch_tracker))
        rows.append((f"torch {variant} (full forward)", MixFormerV2(MixFormerV2.Params(variant=variant, threads=threads,
                                                                                     template_cache=False), network=net)))
        for dev in ort_devices():
            rows.append((f"onnxruntime {dev} (two graphs)", MixFormerV2(MixFormerV2.Params(
                variant=variant, backend="onnxruntime", onnx=str(tmp / "mixformerv2"), device=dev, threads=threads))))
            rows.append((f"onnxruntime {dev} (one graph)", MixFormerV2(MixFormerV2.Params(
                variant=variant, backend="onnxruntime", onnx=str(tmp / "mixformerv2"), device=dev, threads=threads,
                template_cache=False))))
        if tensorrt_usable():
            rows.append(("tensorrt (two graphs)", MixFormerV2(MixFormerV2.Params(
                variant=variant, backend="tensorrt", onnx=str(tmp / "mixformerv2")))))
    elif model == "ostrack":
        from mata_eval_plugins.trackers.ostrack import ENV_VAR, OSTrack

        ckpt = os.environ.get(ENV_VAR)
        weights = dict(checkpoint=ckpt) if ckpt else dict(random_weights=True, seed=0)
        torch_tracker = OSTrack(OSTrack.Params(threads=threads, **weights))
        res = E.export_ostrack(tmp / "ostrack", network=torch_tracker.network())
        parity.update({f"export {g.role}": g.max_abs_error for g in res.graphs})
        rows.append(("torch", torch_tracker))
        for dev in ort_devices():
            rows.append((f"onnxruntime {dev}", OSTrack(OSTrack.Params(backend="onnxruntime", onnx=str(tmp / "ostrack"),
                                                                       device=dev, threads=threads))))
        if tensorrt_usable():
            rows.append(("tensorrt", OSTrack(OSTrack.Params(backend="tensorrt", onnx=str(tmp / "ostrack")))))
    else:
        raise SystemExit(f"unknown model {model!r}")
    return rows, parity


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--models", default="nanotrack,vittrack,mixformerv2,ostrack")
    ap.add_argument("--frames", type=int, default=30, help="frames per run (the first initialises)")
    ap.add_argument("--threads", type=int, default=2, help="CPU threads for torch and ONNX Runtime")
    ap.add_argument("--variant", choices=("S", "B"), default="S", help="MixFormerV2 variant")
    args = ap.parse_args(argv)

    import torch

    torch.set_num_threads(args.threads)
    frames, init, source = load_frames(args.frames + 1)
    from mata_eval.deploy.profile import cpu_model, gpu_description

    load = ", ".join(f"{v:.1f}" for v in os.getloadavg()) if hasattr(os, "getloadavg") else "n/a"
    print(f"machine: {cpu_model()}, {os.cpu_count()} cores, threads {args.threads}; GPU: {gpu_description() or 'none'}; "
          f"load average {load}")
    print(f"frames: {source}, {len(frames) - 1} tracked, median ms after 3 warm-up frames")
    print(f"{'model':<12} {'backend':<38} {'ms/frame':>9} {'x baseline':>10} {'max |dbox| px':>14} {'max |dconf|':>11}")
    with tempfile.TemporaryDirectory(prefix="mata_backends_") as tmp:
        for model in [m.strip() for m in args.models.split(",") if m.strip()]:
            rows, parity = configurations(model, Path(tmp), args.threads, args.variant)
            if not rows:
                print(f"{model:<12} (model files not found in {shared_data_dir()}; skipped)")
                continue
            base_ms = base_boxes = base_conf = None
            results = run_lockstep([t for _, t in rows], frames, init)
            for (label, _), (boxes, conf, ms) in zip(rows, results):
                med = statistics.median(ms[3:] if len(ms) > 3 else ms)
                if base_ms is None:
                    base_ms, base_boxes, base_conf = med, boxes, conf
                    print(f"{model:<12} {label:<38} {med:9.2f} {'baseline':>10} {'-':>14} {'-':>11}")
                else:
                    dbox = float(np.abs(boxes - base_boxes).max())
                    dconf = float(np.abs(conf - base_conf).max())
                    print(f"{model:<12} {label:<38} {med:9.2f} {base_ms / med:10.2f} {dbox:14.3g} {dconf:11.3g}")
            for name, err in parity.items():
                print(f"{model:<12} {name + ': max |onnxruntime - torch| on the network outputs':<38} {err:.2e}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
