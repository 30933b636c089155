"""A synthetic suite on disk in the UAV123 layout (frames, ground truth, attribute flags,
``configSeqs.m``, true homographies), written atomically by :func:`write_suite` in a small
process pool, and read back by :func:`read_suite_info` / :func:`load_true_homographies`."""

from __future__ import annotations

import dataclasses
import functools
import glob
import json
import os
import shutil
import socket
import time
from pathlib import Path

import cv2
import numpy as np

from .render import RenderedSequence, render
from .spec import GENERATOR_VERSION, SequenceSpec, suite_specs


def format_box(b: np.ndarray, exact: bool = False) -> str:
    """``x,y,w,h`` to 2 decimals (the generated suite's, as published), or ``exact``: every digit
    of the float (an augmented copy's, so that it scores as its source)."""
    if not np.all(np.isfinite(b)):
        return "NaN,NaN,NaN,NaN"
    if exact:
        return ",".join(repr(float(v)) for v in b)
    return ",".join(f"{v:.2f}".rstrip("0").rstrip(".") for v in b)


def write_annotations(root: Path, name: str, r: RenderedSequence) -> None:
    """Ground truth, attribute flags and true homographies of one sequence (UAV123 layout)."""
    anno = root / "anno" / "UAV123"
    (anno / "att").mkdir(parents=True, exist_ok=True)
    (anno / "homography").mkdir(parents=True, exist_ok=True)
    (anno / f"{name}.txt").write_text("\n".join(format_box(b) for b in r.groundtruth) + "\n")
    (anno / "att" / f"{name}.txt").write_text(",".join(str(f) for f in r.flags) + "\n")
    np.savetxt(anno / "homography" / f"{name}.txt", r.homographies.reshape(-1, 9), fmt="%.10g", delimiter=",")


def write_config_seqs(root: Path, names_and_lengths: list[tuple[str, int]]) -> None:
    """``anno/UAV123/configSeqs.m`` in the benchmark kit's syntax, one struct per sequence."""
    rows = [f"struct('name','{n}','path','D:\\data_seq\\UAV123\\{n}\\','startFrame',1,'endFrame',{m},"
            f"'nz',6,'ext','jpg','init_rect', [0,0,0,0])" for n, m in names_and_lengths]
    text = ("function seqs=configSeqs\n\n"
            "% synthetic UAV sequences written by mata-eval synth\n"
            "seqUAV123={" + ",...\n    ".join(rows) + "};\n\n"
            "seqs = seqUAV123;\n")
    path = root / "anno" / "UAV123" / "configSeqs.m"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)


def load_true_homographies(root: str | Path, seq: str) -> np.ndarray:
    """The true inter-frame homographies of a synthetic sequence, (N, 3, 3), ``H[k]`` mapping
    frame k-1 to frame k (``H[0]`` = identity)."""
    path = Path(root) / "anno" / "UAV123" / "homography" / f"{seq}.txt"
    if not path.is_file():
        raise FileNotFoundError(f"true homographies not found: {path} (written by `mata-eval synth`)")
    try:
        a = np.loadtxt(path, delimiter=",", ndmin=2)
    except ValueError as e:
        raise ValueError(f"{path}: expected one row of 9 comma-separated numbers per frame ({e})") from None
    if a.shape[1] != 9:
        raise ValueError(f"{path}: expected 9 numbers per row (row-major 3x3), got {a.shape[1]}")
    return a.reshape(-1, 3, 3)


def _write_frames(args: tuple[SequenceSpec, str, int]) -> RenderedSequence:
    spec, folder, quality = args
    cv2.setNumThreads(1)
    out = Path(folder)
    out.mkdir(parents=True, exist_ok=True)
    params = [cv2.IMWRITE_JPEG_QUALITY, int(quality)]

    def sink(k: int, img: np.ndarray) -> None:
        if not cv2.imwrite(str(out / f"{k + 1:06d}.jpg"), img, params):
            raise OSError(f"cannot write frame {out / f'{k + 1:06d}.jpg'}")

    return render(spec, sink)


SUITE_MARKER = "synth.json"


def write_suite(root: str | Path, n_sequences: int = 20, n_frames: int = 300, width: int = 1280,
                height: int = 720, seed: int = 0, *, motion: str = "uav123", jobs: int = 2,
                quality: int = 90, specs: list[SequenceSpec] | None = None, progress: bool = False,
                overwrite: bool = False) -> list[str]:
    """Generate a suite into ``root`` in the UAV123 layout, atomically: everything is written
    into a temporary sibling folder that is renamed to ``root`` when complete (``synth.json``,
    the generation parameters, inside). ``motion``: the camera model (``uav123``, the default,
    or ``legacy``, generator version 3's). A crash leaves no half suite at ``root``. Returns the
    sequence names. Raises FileExistsError when ``root`` already holds something (a suite, unless
    ``overwrite``; anything else, always), also when another process completed it meanwhile."""
    root = Path(root)
    suite = None
    if specs is None:
        specs = suite_specs(n_sequences, n_frames, width, height, seed, motion=motion)
        suite = {"n_sequences": n_sequences, "n_frames": n_frames, "width": width, "height": height,
                 "seed": seed, "motion": motion}
    names = [sp.name for sp in specs]
    if len(set(names)) != len(names):
        raise ValueError(f"sequence names must be unique, got {names}")
    if (root / SUITE_MARKER).exists() and not overwrite:
        raise FileExistsError(f"{root} already holds a synthetic suite ({SUITE_MARKER}); "
                              "choose another folder or overwrite it (--force)")
    if root.exists() and any(root.iterdir()) and not (root / SUITE_MARKER).exists():
        raise FileExistsError(f"{root} exists and is not empty (and is not a synthetic suite); refusing to replace it")
    root.parent.mkdir(parents=True, exist_ok=True)
    _remove_abandoned(root)
    tmp = root.parent / f".{root.name}.tmp-{socket.gethostname()}-{os.getpid()}-{time.time_ns()}"
    tmp.mkdir()
    try:
        tasks = [(sp, str(tmp / "data_seq" / "UAV123" / sp.name), quality) for sp in specs]
        results = _map(_write_frames, tasks, jobs, progress)
        for sp, r in zip(specs, results):
            write_annotations(tmp, sp.name, r)
        write_config_seqs(tmp, [(sp.name, sp.n_frames) for sp in specs])
        (tmp / SUITE_MARKER).write_text(json.dumps({
            "generator_version": GENERATOR_VERSION,
            "opencv": cv2.__version__,    # its warpPerspective's rounding shows in the frames
            "suite": suite,
            "sequences": [dataclasses.asdict(sp) for sp in specs],
            "attributes": {sp.name: sorted(r.attributes) for sp, r in zip(specs, results)},
        }, indent=1))
        if root.exists():
            if (root / SUITE_MARKER).exists() and not overwrite:
                raise FileExistsError(f"{root}: another process completed a suite meanwhile")
            if (root / SUITE_MARKER).exists() or not any(root.iterdir()):
                shutil.rmtree(root)
        try:
            os.replace(tmp, root)
        except OSError:
            raise FileExistsError(f"{root}: appeared while generating (another process?)") from None
    finally:
        if tmp.exists():
            shutil.rmtree(tmp, ignore_errors=True)
    return names


def _remove_abandoned(root: Path) -> None:
    """Delete the temporary folders of ``root`` left by a generating process of this machine
    that no longer exists (killed: ``kill -9`` skips the cleanup; each held 100+ MB of frames).
    Another machine's, in a shared cache, are left alone: its process ids are not ours."""
    mine = f".{root.name}.tmp-{socket.gethostname()}"
    for old in root.parent.glob(f"{glob.escape(mine)}-*-*"):
        prefix, pid, _ = old.name.rsplit("-", 2)
        if prefix != mine or not pid.isdigit():   # (host "a-b" is not host "a")
            continue
        try:
            os.kill(int(pid), 0)
        except ProcessLookupError:
            shutil.rmtree(old, ignore_errors=True)
        except PermissionError:   # alive, another user's
            pass


def read_suite_info(root: str | Path) -> dict | None:
    """The generation parameters of a complete suite at ``root`` (``synth.json``), or None."""
    path = Path(root) / SUITE_MARKER
    if not path.is_file():
        return None
    try:
        return json.loads(path.read_text())
    except json.JSONDecodeError as e:
        raise ValueError(f"{path}: not valid JSON ({e.msg} at line {e.lineno}); delete the folder to regenerate") from None


def _write_group(tasks: list) -> list[RenderedSequence]:
    return [_write_frames(t) for t in tasks]


def _map(fn, tasks: list, jobs: int, progress: bool) -> list:
    """Run tasks in a process pool of ``jobs`` (spawned workers), results in task order. Tasks
    sharing a ground texture go to the same worker, which generates that ground once."""
    from tqdm import tqdm

    groups: dict[int, list[int]] = {}
    for i, t in enumerate(tasks):
        groups.setdefault(t[0].texture_seed, []).append(i)
    out: list = [None] * len(tasks)
    import multiprocessing as mp

    if mp.current_process().daemon:  # a daemonic pool worker may not start processes
        jobs = 1
    with tqdm(total=len(tasks), desc="synthetic suite", unit="seq", disable=not progress) as bar:
        if jobs <= 1 or len(groups) == 1:
            for idx in groups.values():
                for i in idx:
                    out[i] = fn(tasks[i])
                    bar.update()
            return out
        from concurrent.futures import ProcessPoolExecutor, as_completed

        from ...core.processes import die_with_parent

        runner = _write_group if fn is _write_frames else functools.partial(_apply_all, fn)
        # the workers end with this process, even when it is killed (kill -9 left them rendering)
        with ProcessPoolExecutor(max_workers=jobs, mp_context=mp.get_context("spawn"),
                                 initializer=die_with_parent, initargs=(os.getpid(),)) as ex:
            futures = {ex.submit(runner, [tasks[i] for i in idx]): idx for idx in groups.values()}
            for fut in as_completed(futures):
                for i, r in zip(futures[fut], fut.result()):
                    out[i] = r
                bar.update(len(futures[fut]))
    return out


def _apply_all(fn, tasks: list) -> list:
    return [fn(t) for t in tasks]
