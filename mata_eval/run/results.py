"""Run folders (docs/architecture.md, "Run folder"): every file written atomically; the
prediction file ``<seq>.txt`` is written last, so its presence marks a finished sequence."""

from __future__ import annotations

import contextlib
import functools
import hashlib
import io
import json
import os
import platform
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import TYPE_CHECKING, Any, Iterable, Iterator

import numpy as np

from ..core.errors import UserError

if TYPE_CHECKING:
    from ..core.sequence import Sequence

MANIFEST = "manifest.json"
_UMASK = os.umask(0)
os.umask(_UMASK)


def atomic_write_text(path: Path, text: str) -> None:
    """Write via a temporary file in the same folder and ``os.replace`` (atomic on POSIX)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "w", newline="", encoding="utf-8") as f:
            f.write(text)
        os.chmod(tmp, 0o666 & ~_UMASK)  # mkstemp makes 0600 files; results are shared files
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def write_json(path: Path, data: Any) -> None:
    atomic_write_text(path, json.dumps(data, indent=2, sort_keys=True, default=_json_default) + "\n")


def _json_default(obj: Any) -> Any:
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, Path):
        return str(obj)
    raise TypeError(f"not JSON serialisable: {type(obj).__name__}")


class UnsafeName(UserError, ValueError):
    """A run or sequence name that would put a file outside its folder."""


def is_file_name(name: str) -> bool:
    """One file or folder name: not empty, not ``.`` or ``..``, no separator."""
    return name not in ("", ".", "..") and not any(c in name for c in "/\\\0")


def inside(folder: Path, name: str, suffix: str = "") -> Path:
    """``folder / (name + suffix)``, refusing a name that is not one file name (a run or
    sequence name like ``../../x`` or ``/abs`` would write outside the output folder)."""
    if not is_file_name(name):
        raise UnsafeName(f"{name!r} is not a single file name; refusing to write outside {folder}")
    return Path(folder) / f"{name}{suffix}"


def predictions_path(run_dir: Path, seq: str) -> Path:
    return inside(run_dir, seq, ".txt")


def is_finished(run_dir: Path, seq: str) -> bool:
    return predictions_path(run_dir, seq).is_file()


def format_predictions(boxes: np.ndarray) -> str:
    """pysot-toolkit layout: one ``x,y,w,h`` line per frame, comma separated floats."""
    return "".join(",".join(f"{v:.4f}" for v in row) + "\n" for row in np.asarray(boxes, dtype=float))


def read_predictions(path: Path) -> np.ndarray:
    """Read a prediction file written by :func:`format_predictions` (or any comma/tab/space
    separated ``x,y,w,h`` file); raises ValueError naming the file and line.

    numpy's parser reads the file (it rounds like ``float()``); a file it rejects is read again
    line by line to name the first bad line."""
    text = Path(path).read_text(encoding="utf-8-sig")   # (a BOM, as the ground truth allows)
    if not text.strip():
        return np.empty((0, 4))
    try:
        boxes = np.loadtxt(io.StringIO(text.replace(",", " ")), dtype=float, comments=None, ndmin=2)
        if boxes.shape[1] == 4:
            return boxes
    except ValueError:
        pass
    for i, line in enumerate(text.splitlines(), start=1):
        parts = line.replace(",", " ").split()
        if parts and not _are_numbers(parts, 4):
            vot = (" (a line of one 0, 1 or 2 is the VOT toolkit's reset-based output: 1 initialised, 2 failed, "
                   "0 skipped; mata-eval scores one-pass results only, no EAO: docs/decisions/protocols.md)"
                   if parts[0] in ("0", "1", "2") and len(parts) == 1 else "")
            raise ValueError(f"{path}:{i}: expected 4 numbers x,y,w,h, got {line!r}{vot}")
    raise ValueError(f"{path}: expected 4 numbers x,y,w,h per line")  # not reached: a line is bad


def _are_numbers(parts: list[str], n: int) -> bool:
    try:
        [float(p) for p in parts]
    except ValueError:
        return False
    return len(parts) == n


SCORES = "scores.json"  # the run's scores (mata_eval.score.evaluate), stale once a sequence changes
#: the files a sequence leaves in its run folder (predictions, sidecars, failure, skipped frames)
SEQUENCE_FILES = (".txt", ".frames.csv", ".trace.csv", ".failed.json", ".bad_frames.json")


#: the longest file name a file system takes (bytes; ext4, xfs, btrfs, APFS, NTFS in characters)
NAME_MAX = 255
#: what atomic_write_text adds to a file's name for its temporary file (".", ".", 8 random, ".tmp")
_TMP_EXTRA = 14


def sequence_name_problem(seq: str) -> str | None:
    """Why ``seq`` cannot name its files in a run folder (not one file name, or too long for
    the longest of them and its temporary file), or None."""
    if not is_file_name(seq):
        return f"{seq!r} is not a single file name"
    longest = max(len(f"{seq}{suffix}".encode()) for suffix in SEQUENCE_FILES) + _TMP_EXTRA
    if longest > NAME_MAX:
        return (f"sequence name {seq[:40]!r}... is too long for its result files ({longest} bytes with "
                f"{max(SEQUENCE_FILES, key=len)!r} and the temporary file's extra characters; at most {NAME_MAX})")
    return None


def invalidate_scores(run_dir: Path) -> None:
    """Remove the run's scores.json: a sequence of it is being rewritten, so the scores no longer
    describe the predictions (a report then scores the run again instead of showing old numbers)."""
    (Path(run_dir) / SCORES).unlink(missing_ok=True)


def write_sequence(run_dir: Path, seq: str, boxes: np.ndarray, frames_csv: str, trace_csv: str) -> None:
    """Write one finished sequence: sidecars first, predictions last (the completion mark)."""
    invalidate_scores(run_dir)
    atomic_write_text(inside(run_dir, seq, ".frames.csv"), frames_csv)
    atomic_write_text(inside(run_dir, seq, ".trace.csv"), trace_csv)
    inside(run_dir, seq, ".failed.json").unlink(missing_ok=True)
    atomic_write_text(predictions_path(run_dir, seq), format_predictions(boxes))


def write_failure(run_dir: Path, seq: str, reason: str, tb: str) -> None:
    """Record a failed sequence; a result of an earlier attempt (``--force`` redoes finished
    sequences in place) goes, so that the failure is what the folder says."""
    invalidate_scores(run_dir)
    for suffix in SEQUENCE_FILES:
        if suffix != ".failed.json":
            inside(run_dir, seq, suffix).unlink(missing_ok=True)
    write_json(inside(run_dir, seq, ".failed.json"), {"sequence": seq, "reason": reason, "traceback": tb})


def write_bad_frames(run_dir: Path, seq: str, bad: dict[int, str]) -> None:
    """``<seq>.bad_frames.json``: the frames excluded from scoring (``on_bad_frame: skip``)."""
    write_json(inside(run_dir, seq, ".bad_frames.json"),
               {"sequence": seq, "frames": {str(k): why for k, why in sorted(bad.items())}})


class CorruptFile(UserError, ValueError):
    """A file of a run folder that cannot be read; names it and says what to do."""


def read_json(path: Path) -> Any:
    try:
        return json.loads(Path(path).read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise CorruptFile(f"{path}: not valid JSON ({exc}); delete it (or rerun with --force)") from None


def read_bad_frames(run_dir: Path) -> dict[str, int]:
    """Sequence -> how many of its frames were skipped as unreadable and not scored
    (``<seq>.bad_frames.json``, ``on_bad_frame: skip``)."""
    out = {}
    for p in sorted(Path(run_dir).glob("*.bad_frames.json")):
        data = read_json(p)
        if not isinstance(data, dict) or not isinstance(data.get("frames"), dict):
            raise CorruptFile(f"{p}: expected {{\"sequence\": ..., \"frames\": {{...}}}}; delete it (or rerun with --force)")
        out[str(data.get("sequence", p.name[:-len(".bad_frames.json")]))] = len(data["frames"])
    return out


def read_failures(run_dir: Path) -> dict[str, str]:
    out = {}
    for p in sorted(Path(run_dir).glob("*.failed.json")):
        data = read_json(p)
        if not isinstance(data, dict) or not isinstance(data.get("sequence"), str):
            raise CorruptFile(f"{p}: expected {{\"sequence\": ..., \"reason\": ...}}; delete it (or rerun with --force)")
        out[data["sequence"]] = str(data.get("reason", ""))
    return out


def holds_results(run_dir: Path) -> bool:
    """Whether the folder holds a file of some sequence (or the run's scores)."""
    d = Path(run_dir)
    return (d / SCORES).exists() or any(next(d.glob(f"*{suffix}"), None) for suffix in SEQUENCE_FILES)


def clear_run(run_dir: Path) -> None:
    """Remove every sequence's results and the scores of a run folder (its results are of
    another configuration, which must not be mixed with the new one's)."""
    invalidate_scores(run_dir)
    for suffix in SEQUENCE_FILES:
        for p in Path(run_dir).glob(f"*{suffix}"):
            p.unlink(missing_ok=True)


@contextlib.contextmanager
def in_run_cwd(manifest: dict | None) -> Iterator[None]:
    """Relative paths of a run's configuration (a dataset ``root``, an annotation folder) are
    the folder ``mata-eval run`` ran in, which its manifest records (``cwd``): while a run is
    rebuilt from its manifest (``report`` scoring it, ``play``, ``eval``), that folder is the
    working folder. Without the record (older manifests) or the folder, nothing changes. Callers
    make their own paths absolute first."""
    cwd = (manifest or {}).get("cwd")
    if not cwd or not os.path.isdir(cwd) or os.path.realpath(cwd) == os.path.realpath(os.getcwd()):
        yield
        return
    before = os.getcwd()
    os.chdir(cwd)
    try:
        yield
    finally:
        os.chdir(before)


def file_sha256(path: str | Path) -> str:
    """sha256 of a file's bytes, computed once per process for a file of a given size and
    modification time (a run reads its model files in the driver and every worker)."""
    st = os.stat(path)
    return _sha256(str(path), st.st_size, st.st_mtime_ns)


@functools.lru_cache(maxsize=32)
def _sha256(path: str, size: int, mtime_ns: int) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            digest.update(chunk)
    return digest.hexdigest()


def results_sha256(run_dir: str | Path, seq: str) -> str:
    """sha256 of what scoring reads of a sequence's results: ``<seq>.txt`` and, when present,
    ``<seq>.frames.csv`` (its scored column)."""
    digest = hashlib.sha256(Path(inside(run_dir, seq, ".txt")).read_bytes())
    frames = Path(inside(run_dir, seq, ".frames.csv"))
    if frames.is_file():
        digest.update(b"frames" + frames.read_bytes())
    return digest.hexdigest()


def groundtruth_sha256(seq: Sequence) -> str:
    """sha256 of a sequence's annotations as scoring reads them: every ground-truth box as
    float64, the ``annotated`` mask and the ``init`` box when it has them."""
    digest = hashlib.sha256(np.ascontiguousarray(seq.groundtruth, dtype=np.float64).tobytes())
    if seq.annotated is not None:
        digest.update(b"annotated" + np.ascontiguousarray(seq.annotated, dtype=bool).tobytes())
    if seq.init is not None:
        digest.update(b"init" + np.array([seq.init.x, seq.init.y, seq.init.w, seq.init.h], np.float64).tobytes())
    return digest.hexdigest()


def run_input_sha256(seq: Sequence, occluded: bool) -> str:
    """sha256 of what a run reads of a sequence's annotations: the box its tracker starts from,
    and with the occlusion augmentation (``occluded``), which places its occluders from every
    box, all of them (:func:`groundtruth_sha256`). A box edited later in a run without occlusion
    changes the scores, not the results."""
    if occluded:
        return groundtruth_sha256(seq)
    b = seq.init_box
    return hashlib.sha256(b"start" + np.array([b.x, b.y, b.w, b.h], np.float64).tobytes()).hexdigest()


def changed_groundtruth(recorded: Any, sequences: Iterable[Sequence]) -> list[str]:
    """The sequences whose :func:`groundtruth_sha256` differs from ``recorded`` (sequence ->
    digest, as a scores.json keeps it); a sequence without a record (older mata-eval) is not
    compared."""
    recorded = recorded if isinstance(recorded, dict) else {}
    return [s.name for s in sequences if s.name in recorded and recorded[s.name] != groundtruth_sha256(s)]


def changed_run_inputs(recorded: Any, sequences: Iterable[Sequence], occluded: bool) -> list[str]:
    """:func:`changed_groundtruth` of a manifest's ``groundtruth`` record (:func:`run_input_sha256`).
    A record of every box (:func:`groundtruth_sha256`, as a development version wrote it also
    without occlusion) that still matches counts as unchanged."""
    recorded = recorded if isinstance(recorded, dict) else {}
    return [s.name for s in sequences if s.name in recorded
            and recorded[s.name] not in (run_input_sha256(s, occluded), groundtruth_sha256(s))]


def package_versions() -> dict[str, str]:
    """Versions of the packages that decide the numbers (recorded in every manifest)."""
    from importlib import metadata

    out = {"python": platform.python_version()}
    for dist in ("mata-eval", "numpy", "opencv-python-headless", "opencv-python", "onnxruntime",
                 "torch", "numba", "pluggy", "PyYAML"):
        try:
            out[dist] = metadata.version(dist)
        except metadata.PackageNotFoundError:
            pass
    return out


#: what tells two setups apart: what a manifest records of the process that ran, the command
#: line aside (runner._setup)
SETUP_KEYS = ("versions", "environment", "git_commit", "machine")


def setup_identity(record: dict) -> dict[str, Any]:
    """The setup a manifest records at its top level (the last run's): its SETUP_KEYS, without
    the command line (``machine.argv``), as JSON has them."""
    machine = record.get("machine")
    if isinstance(machine, dict):
        machine = {k: v for k, v in machine.items() if k != "argv"}
    return json.loads(json.dumps({**{k: record.get(k) for k in SETUP_KEYS}, "machine": machine}, default=str))


def setup_record(manifest: dict) -> tuple[list[dict], dict[str, int]]:
    """A run folder manifest's ``setups`` (the distinct :func:`setup_identity` of the runs that
    made its results) and ``made_by`` (sequence -> index into them), checked: a record edited
    into another shape reads as none, an entry that is no index into ``setups`` is dropped."""
    setups, made_by = manifest.get("setups"), manifest.get("made_by")
    if not (isinstance(setups, list) and all(isinstance(s, dict) for s in setups) and isinstance(made_by, dict)):
        return [], {}
    return setups, {k: v for k, v in made_by.items()
                    if isinstance(v, int) and not isinstance(v, bool) and 0 <= v < len(setups)}


def record_made_by(run_dir: Path, seq: str, made: bool) -> None:
    """Credit the result of ``seq`` just written (``made``; a failure leaves none) to the setup
    of the run writing it, the one its manifest names (:func:`setup_identity`)."""
    try:
        manifest = read_manifest(run_dir)
    except CorruptFile:   # edited during the run: the record goes, not the run (the next run says so)
        return
    if manifest is None:   # the folder was emptied during the run: the next write says so (runner.write_result)
        return
    setups, made_by = setup_record(manifest)
    made_by.pop(seq, None)
    if made:
        here = setup_identity(manifest)
        setups = setups if here in setups else setups + [here]
        made_by[seq] = setups.index(here)
    used = sorted(set(made_by.values()))   # a setup whose results were all redone goes
    write_manifest(run_dir, {**manifest, "setups": [setups[i] for i in used],
                             "made_by": {k: used.index(v) for k, v in sorted(made_by.items())}})


def comparable_versions(versions: dict[str, str]) -> dict[str, str]:
    """Package versions as two setups are compared: Python by its minor version (a patch release
    does not change the numbers)."""
    return {k: ".".join(str(v).split(".")[:2]) if k == "python" else v for k, v in versions.items()}


def setups_of(manifest: dict, names: Iterable[str]) -> list[dict]:
    """The setups that made the results of the sequences ``names`` (:func:`setup_record`), in
    the order they first ran."""
    setups, made_by = setup_record(manifest)
    return [setups[i] for i in sorted({made_by[n] for n in names if n in made_by})]


def mixed_versions(manifest: dict, names: Iterable[str]) -> dict[str, list[str]]:
    """Package -> the versions that made the results of the sequences ``names`` of a run folder
    (:func:`setups_of`; Python by its minor version), for the packages whose version differs
    among them (a run resumed after an upgrade); empty when one setup made them all or there is
    no record (an older mata-eval, a setup without versions)."""
    versions = [comparable_versions(s["versions"]) for s in setups_of(manifest, names) if isinstance(s.get("versions"), dict)]
    packages = sorted({k for v in versions for k in v})
    seen = {k: list(dict.fromkeys(str(v.get(k, "absent")) for v in versions)) for k in packages}
    return {k: v for k, v in seen.items() if len(v) > 1}


def versions_line(mixed: dict[str, list[str]]) -> str:
    """``numpy 1.26.4, 2.1.0; opencv ...``: :func:`mixed_versions` for people."""
    return "; ".join(f"{k} {', '.join(v)}" for k, v in mixed.items())


def git_commit(path: Path | None = None) -> str | None:
    """The commit of the mata-eval checkout (with ``+dirty`` when it has local changes); None for
    an installed package, also one in a virtual environment inside the user's own repository
    (whose commit it recorded): the package must sit at the top of the repository."""
    where = Path(path or Path(__file__).resolve().parents[1])   # the package folder, mata_eval/
    try:
        top = subprocess.run(["git", "-C", str(where), "rev-parse", "--show-toplevel"], capture_output=True,
                             text=True, timeout=5)
        if top.returncode != 0 or Path(top.stdout.strip()).resolve() != where.resolve().parent:
            return None
        head = subprocess.run(["git", "-C", str(where), "rev-parse", "HEAD"], capture_output=True,
                              text=True, timeout=5)
        if head.returncode != 0:
            return None
        dirty = subprocess.run(["git", "-C", str(where), "status", "--porcelain", "--untracked-files=no"],
                               capture_output=True, text=True, timeout=5).stdout.strip()
        return head.stdout.strip() + ("+dirty" if dirty else "")
    except (OSError, subprocess.TimeoutExpired):
        return None


def machine() -> dict[str, Any]:
    return {"platform": platform.platform(), "processor": platform.processor() or platform.machine(),
            "cpu_count": os.cpu_count(), "argv": sys.argv}


def write_manifest(run_dir: Path, manifest: dict) -> None:
    write_json(Path(run_dir) / MANIFEST, manifest)


def read_manifest(run_dir: Path) -> dict | None:
    p = Path(run_dir) / MANIFEST
    if not p.is_file():
        return None
    data = read_json(p)
    if not isinstance(data, dict):
        raise CorruptFile(f"{p}: expected a JSON object; delete it (or rerun with --force)")
    return data
