"""Inference backends for ONNX graphs: ONNX Runtime (CPU, CUDA or TensorRT execution provider)
and a TensorRT engine built from the ONNX file. Each returns a callable
``run(feeds: dict[str, ndarray]) -> dict[str, ndarray]``; trackers do their own pre- and
post-processing around it. The heavy packages are imported only when a backend is chosen."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Callable, Literal

import numpy as np

Runner = Callable[[dict[str, np.ndarray]], dict[str, np.ndarray]]
Backend = Literal["onnxruntime", "tensorrt"]
Device = Literal["cpu", "cuda", "tensorrt"]

_ORT_PROVIDERS = {
    "cpu": ["CPUExecutionProvider"],
    "cuda": ["CUDAExecutionProvider", "CPUExecutionProvider"],
    "tensorrt": ["TensorrtExecutionProvider", "CUDAExecutionProvider", "CPUExecutionProvider"],
}


def check_weights_and_device(tracker: str, params: object) -> None:
    """Load-time checks of a transformer tracker's ``Params``: ``random_weights`` and a
    ``checkpoint`` exclude each other (random weights would ignore it without a word), the
    onnxruntime backend's ``device`` is one it has providers for, ``threads`` is not negative."""
    if params.random_weights and params.checkpoint:
        raise ValueError(f"{tracker}: random_weights: true ignores checkpoint {params.checkpoint!r}; give one of them")
    if params.backend == "onnxruntime" and params.device not in _ORT_PROVIDERS:
        raise ValueError(f"{tracker}: device: expected one of {', '.join(_ORT_PROVIDERS)} with backend onnxruntime "
                         f"(torch device names are for backend torch), got {params.device!r}")
    if params.threads < 0:
        raise ValueError(f"{tracker}: threads: expected 0 (leave the library's setting) or more, got {params.threads}")


class BackendUnavailable(RuntimeError):
    """The chosen backend or device is not installed or not usable on this machine."""


# Input shapes of a TensorRT optimization profile: name -> (min, opt, max) shapes, for graphs
# whose inputs have free dims (the NanoTrack backbone takes 127 and 255 px crops).
Shapes = dict[str, tuple[tuple[int, ...], tuple[int, ...], tuple[int, ...]]]


def open_onnx(path: str | Path, backend: Backend = "onnxruntime", device: Device = "cpu",
              threads: int = 0, fp16: bool = False, shapes: Shapes | None = None) -> Runner:
    """Open an ONNX graph with the chosen backend. ``shapes``: the TensorRT optimization profile
    of inputs with free dims (ignored by ONNX Runtime)."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"ONNX file not found: {path}")
    if backend == "onnxruntime":
        return _onnxruntime(path, device, threads)
    if backend == "tensorrt":
        return TensorRTRunner(build_engine(path, fp16=fp16, shapes=shapes))
    raise ValueError(f"unknown backend {backend!r}; expected 'onnxruntime' or 'tensorrt'")


def check_device(backend: str, device: str) -> None:
    """Preflight of a transformer tracker's ``backend`` and ``device``: a torch device string
    torch parses and has here (``cuda`` needs a CUDA build and a GPU), or what
    :func:`check_backend` accepts for the exported graphs."""
    if backend != "torch":
        check_backend(backend, device)   # type: ignore[arg-type]
        return
    try:
        import torch
    except ImportError:
        raise BackendUnavailable("the torch backend needs torch: pip install 'mata-eval[torch]'") from None

    try:
        dev = torch.device(device)
    except RuntimeError:
        raise BackendUnavailable(f"device {device!r} is not a torch device (cpu, cuda, cuda:1, ...)") from None
    if dev.type == "cuda" and not torch.cuda.is_available():
        raise BackendUnavailable(f"device {device!r}, but this torch ({torch.__version__}) has no CUDA device; "
                                 "use device: cpu")
    if dev.type not in ("cpu", "cuda"):
        raise BackendUnavailable(f"device {device!r}: the torch backend runs on cpu or cuda")


def check_inputs(path: str | Path, expected: tuple[str, ...], model: str,
                 outputs: tuple[tuple[int, ...], ...] | None = None) -> None:
    """Raise :class:`BackendUnavailable` when the ONNX graph at ``path`` does not take the
    inputs ``expected`` (another tracker's model, or the other half of a pair) or, with
    ``outputs``, does not give outputs of those shapes (another version of the model: NanoTrack
    v3's head gives 15x15 maps, v2's 16x16): caught by the preflight instead of failing every
    sequence in ONNX Runtime or at the first reshape. ``model`` names the file expected. Reads
    the graph on the CPU (about 0.1 s)."""
    import onnxruntime as ort

    try:
        session = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    except Exception as exc:   # not an ONNX graph at all
        raise BackendUnavailable(f"{path}: not an ONNX model ONNX Runtime can read ({type(exc).__name__}); "
                                 f"expected {model}") from None
    names = tuple(i.name for i in session.get_inputs())
    if sorted(names) != sorted(expected):
        raise BackendUnavailable(f"{path} takes the inputs {', '.join(names)}, not {', '.join(expected)}: "
                                 f"it is not {model} (another tracker's model?)")
    if outputs is not None:
        got = [tuple(o.shape) for o in session.get_outputs()]
        fits = len(got) == len(outputs) and all(
            len(g) == len(w) and all(not isinstance(a, int) or a == b for a, b in zip(g, w))   # a named dim fits
            for g, w in zip(got, outputs))
        if not fits:
            raise BackendUnavailable(f"{path} gives outputs of shape {', '.join(map(str, got))}, not "
                                     f"{', '.join(map(str, outputs))}: it is not {model} (another version?)")


def check_exported_graphs(folder: str | Path, model: str, roles: tuple[str, ...]) -> None:
    """Preflight of a ``mata-eval export`` folder: each graph of ``roles`` that its export.json
    lists is there and ONNX Runtime reads it, with the inputs export.json gives (a graph deleted
    or cut short passed, and every sequence failed at its first frame)."""
    from mata_eval.deploy.export import read_manifest

    root = Path(folder).expanduser()
    graphs = read_manifest(root, model).get("graphs", {})
    for role in roles:
        path = root / graphs[role]["file"]
        if not path.is_file():
            raise BackendUnavailable(f"{path}: the {role} graph export.json lists is missing; export again "
                                     f"(mata-eval export {model} --out {folder})")
        check_inputs(path, tuple(graphs[role]["inputs"]), f"the {role} graph of a {model} export")


def check_backend(backend: Backend, device: Device = "cpu") -> None:
    """Raise :class:`BackendUnavailable` (one line: what is missing, what to install) when
    ``backend`` cannot run on ``device`` here; cheap: no model is opened (preflight)."""
    if backend == "onnxruntime":
        _ort_providers(device)
    elif backend == "tensorrt":
        try:
            import tensorrt  # noqa: F401
        except ImportError:
            raise BackendUnavailable("TensorRT is not installed (on a Jetson it comes with JetPack: "
                                     "python3 -c 'import tensorrt')") from None
    else:
        raise ValueError(f"unknown backend {backend!r}; expected 'onnxruntime' or 'tensorrt'")


def _ort_providers(device: Device) -> list[str]:
    try:
        import onnxruntime as ort
    except ImportError:
        raise BackendUnavailable("onnxruntime is not installed (a dependency of mata-eval): "
                                 "pip install onnxruntime") from None
    available = ort.get_available_providers()
    wanted = _ORT_PROVIDERS[device]
    if wanted[0] not in available:
        raise BackendUnavailable(f"device {device!r} needs {wanted[0]}, but this onnxruntime offers only "
                                 f"{', '.join(available)}: install onnxruntime-gpu in place of onnxruntime (on a "
                                 "Jetson, the wheel of its JetPack, docs/jetson.md), or use device: cpu")
    return [p for p in wanted if p in available]


def _onnxruntime(path: Path, device: Device, threads: int) -> Runner:
    import onnxruntime as ort

    providers = _ort_providers(device)
    options = ort.SessionOptions()
    if threads:
        options.intra_op_num_threads = threads
    session = ort.InferenceSession(str(path), options, providers=providers)
    names = [o.name for o in session.get_outputs()]

    def run(feeds: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        return dict(zip(names, session.run(names, feeds)))

    return run


def engine_path_for(onnx_path: Path, fp16: bool, shapes: Shapes | None = None) -> Path:
    tag = ""
    if shapes:
        import hashlib

        tag = "." + hashlib.sha256(repr(sorted(shapes.items())).encode()).hexdigest()[:8]
    return onnx_path.with_suffix(f"{tag}.{'fp16' if fp16 else 'fp32'}.engine")


def build_engine(onnx_path: Path, fp16: bool = False, engine_path: Path | None = None,
                 shapes: Shapes | None = None) -> Path:
    """Build (or reuse, when newer than the ONNX file) a serialized TensorRT engine; inputs with
    free dims need their (min, opt, max) shapes in ``shapes``."""
    try:
        import tensorrt as trt
    except ImportError:
        raise BackendUnavailable("TensorRT is not installed (on a Jetson it comes with JetPack: "
                                 "python3 -c 'import tensorrt')") from None
    engine_path = engine_path or engine_path_for(onnx_path, fp16, shapes)
    if engine_path.is_file() and engine_path.stat().st_mtime >= onnx_path.stat().st_mtime:
        return engine_path
    logger = trt.Logger(trt.Logger.WARNING)
    builder = trt.Builder(logger)
    network = builder.create_network(0)
    parser = trt.OnnxParser(network, logger)
    if not parser.parse(onnx_path.read_bytes()):
        errors = "; ".join(str(parser.get_error(i)) for i in range(parser.num_errors))
        raise RuntimeError(f"TensorRT cannot parse {onnx_path}: {errors}")
    config = builder.create_builder_config()
    dynamic = [network.get_input(i) for i in range(network.num_inputs) if -1 in tuple(network.get_input(i).shape)]
    if dynamic:
        missing = [t.name for t in dynamic if t.name not in (shapes or {})]
        if missing:
            raise ValueError(f"{onnx_path}: inputs {missing} have free dims; TensorRT needs their (min, opt, max) "
                             "shapes (open_onnx(..., shapes=...))")
        profile = builder.create_optimization_profile()
        for t in dynamic:
            lo, opt, hi = shapes[t.name]
            profile.set_shape(t.name, tuple(lo), tuple(opt), tuple(hi))
        config.add_optimization_profile(profile)
    if fp16:
        config.set_flag(trt.BuilderFlag.FP16)
    serialized = builder.build_serialized_network(network, config)
    if serialized is None:
        raise RuntimeError(f"TensorRT failed to build an engine from {onnx_path}")
    tmp = engine_path.with_suffix(".tmp")
    tmp.write_bytes(bytes(serialized))
    os.replace(tmp, engine_path)
    return engine_path


class TensorRTRunner:
    """Runs a serialized TensorRT engine (TensorRT 10 tensor API), with torch CUDA tensors as
    device buffers (torch is on every Jetson image; no pycuda needed)."""

    def __init__(self, engine_path: Path):
        import tensorrt as trt
        import torch

        if not torch.cuda.is_available():
            raise BackendUnavailable("the TensorRT backend needs a CUDA device")
        self._torch = torch
        runtime = trt.Runtime(trt.Logger(trt.Logger.WARNING))
        self.engine = runtime.deserialize_cuda_engine(Path(engine_path).read_bytes())
        self.context = self.engine.create_execution_context()
        self.stream = torch.cuda.Stream()
        self.buffers: dict[str, "torch.Tensor"] = {}
        self.dtypes: dict[str, "torch.dtype"] = {}
        self.inputs, self.outputs = [], []
        self.dynamic = False
        for i in range(self.engine.num_io_tensors):
            name = self.engine.get_tensor_name(i)
            self.dtypes[name] = torch.from_numpy(np.empty(0, trt.nptype(self.engine.get_tensor_dtype(name)))).dtype
            shape = tuple(self.engine.get_tensor_shape(name))
            is_input = self.engine.get_tensor_mode(name) == trt.TensorIOMode.INPUT
            (self.inputs if is_input else self.outputs).append(name)
            if -1 in shape:
                self.dynamic = True
            else:
                self._bind(name, shape)

    def _bind(self, name: str, shape: tuple[int, ...]) -> None:
        """(Re)allocate the device buffer of ``name`` when its shape changes."""
        buf = self.buffers.get(name)
        if buf is None or tuple(buf.shape) != tuple(shape):
            buf = self._torch.empty(tuple(shape), dtype=self.dtypes[name], device="cuda")
            self.buffers[name] = buf
            self.context.set_tensor_address(name, buf.data_ptr())

    def __call__(self, feeds: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        torch = self._torch
        if self.dynamic:   # free dims: shapes of this call, then the outputs' shapes follow
            for name in self.inputs:
                shape = tuple(np.shape(feeds[name]))
                self.context.set_input_shape(name, shape)
                self._bind(name, shape)
            for name in self.outputs:
                self._bind(name, tuple(self.context.get_tensor_shape(name)))
        with torch.cuda.stream(self.stream):
            for name in self.inputs:
                self.buffers[name].copy_(torch.from_numpy(np.ascontiguousarray(feeds[name])), non_blocking=True)
            self.context.execute_async_v3(self.stream.cuda_stream)
            out = {name: self.buffers[name].to("cpu", non_blocking=False).numpy() for name in self.outputs}
        self.stream.synchronize()
        return out


# --- exported torch trackers behind their torch interface --------------------------------------
# `mata-eval export mixformerv2 | ostrack` writes the graphs and an export.json (network constants,
# graph files). These adapters give the trackers the same calls as their torch networks, with
# torch tensors in and out, so only the network changes with the backend.

def _np(t) -> np.ndarray:
    return np.ascontiguousarray(t.detach().cpu().numpy().astype(np.float32, copy=False))


class _ExportedGraphs:
    def __init__(self, folder: str | Path, model: str, backend: Backend, device: Device, threads: int, fp16: bool):
        from mata_eval.deploy.export import read_manifest

        self.folder = Path(folder).expanduser()
        self.doc = read_manifest(self.folder, model)
        self._open = lambda role: open_onnx(self.folder / self.doc["graphs"][role]["file"], backend, device, threads, fp16)
        self._runners: dict[str, Runner] = {}

    def open(self, *roles: str) -> None:
        """Open these graphs now (a missing backend fails here, not in the first frame)."""
        for role in roles:
            self.run_for(role)

    def run_for(self, role: str) -> Runner:
        if role not in self._runners:
            if role not in self.doc["graphs"]:
                raise FileNotFoundError(f"{self.folder / 'export.json'}: no {role!r} graph in this export "
                                        f"(it has: {', '.join(self.doc['graphs'])})")
            self._runners[role] = self._open(role)
        return self._runners[role]

    def run(self, role: str, feeds: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        return self.run_for(role)(feeds)

    def eval(self):
        return self

    def to(self, device):
        return self


class ExportedMixFormerV2(_ExportedGraphs):
    """``MixFormerV2Net``'s calls (``__call__``, ``encode_templates``, ``forward_search``) on the
    exported graphs; the template cache is the template graph's key/value outputs."""

    def __init__(self, folder: str | Path, backend: Backend = "onnxruntime", device: Device = "cpu",
                 threads: int = 0, fp16: bool = False):
        from .vit import MixFormerV2Config

        super().__init__(folder, "mixformerv2", backend, device, threads, fp16)
        c = self.doc["config"]
        self.cfg = MixFormerV2Config(template_size=c["template_size"], search_size=c["search_size"], depth=c["depth"],
                                     embed_dim=c["embed_dim"], num_heads=c["num_heads"], feat_sz=c["feat_sz"])

    def _outputs(self, out: dict[str, np.ndarray]):
        import torch

        pmfs = np.stack([out[f"pmf_{s}"] for s in ("left", "top", "right", "bottom")], axis=1)
        return torch.from_numpy(out["box"]), torch.from_numpy(out["score_logit"]), torch.from_numpy(pmfs)

    def __call__(self, z, oz, x):
        return self._outputs(self.run("full", {"template": _np(z), "online_template": _np(oz), "search": _np(x)}))

    def encode_templates(self, z, oz) -> dict[str, np.ndarray]:
        return self.run("template", {"template": _np(z), "online_template": _np(oz)})

    def forward_search(self, x, cache: dict[str, np.ndarray]):
        return self._outputs(self.run("search", {"search": _np(x), **cache}))


class ExportedOSTrack(_ExportedGraphs):
    """``OSTrackNet.__call__(template, search, keep_ratio)`` on the exported graph (candidate
    elimination fixed at the exported keep ratio)."""

    def __init__(self, folder: str | Path, backend: Backend = "onnxruntime", device: Device = "cpu",
                 threads: int = 0, fp16: bool = False):
        from .vit import OSTrackConfig

        super().__init__(folder, "ostrack", backend, device, threads, fp16)
        c = self.doc["config"]
        self.cfg = OSTrackConfig(template_size=c["template_size"], search_size=c["search_size"],
                                 ce_loc=tuple(c["ce_loc"]), ce_keep_ratio=tuple(c["ce_keep_ratio"]))
        self.open("full")

    def __call__(self, z, x, keep_ratio: float | None = None):
        import torch

        if keep_ratio is not None and any(abs(keep_ratio - r) > 1e-9 for r in self.cfg.ce_keep_ratio):
            raise ValueError(f"ostrack: the exported graph in {self.folder} eliminates candidates at keep ratio "
                             f"{self.cfg.ce_keep_ratio}; ce_keep_ratio {keep_ratio} needs the torch backend")
        out = self.run("full", {"template": _np(z), "search": _np(x)})
        return tuple(torch.from_numpy(out[n]) for n in ("score_map", "size_map", "offset_map"))
