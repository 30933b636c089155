"""The Python API: ``mata-eval run`` and ``mata-eval eval`` as two functions.

    import mata_eval as me
    runs = me.run("experiments/quickstart.yaml")        # one RunScores per run that ran
    for r in runs:
        print(r.name, r.overall.sr, r.overall.nt2f)      # fractions in [0, 1]
    s = me.evaluate("my_results/", dataset="uav123", root="/data/UAV123", profile="pysot-toolkit")

Both return :class:`mata_eval.score.evaluate.RunScores`, a frozen dataclass: ``name``, ``path``
(the results folder), ``overall`` (a :class:`~mata_eval.score.metrics.Summary`: ``sr``, ``msr``,
``pr``, ``precision20``, ``nt2f``, the mean curves and frame counts), ``sequences`` (per-sequence
:class:`~mata_eval.score.metrics.SequenceScores`), ``summary.attributes`` and
``summary.groups`` (per attribute and challenge group), ``failures`` (sequence -> reason),
``missing`` (sequences without results) and ``frequencies`` (block rates).

In a script, call ``run`` under ``if __name__ == "__main__":``: the synthetic suite is rendered in
spawned worker processes, which import the script, and without the guard each would start the
experiment again.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any, Sequence

from .score.evaluate import RunScores


class PreflightError(RuntimeError):
    """The experiment cannot run here (data, model file or backend missing): ``lines`` holds
    one line per problem; nothing has run."""

    def __init__(self, lines: Sequence[str]):
        self.lines = tuple(lines)
        super().__init__("\n".join(self.lines))


def run(experiment: str | Path, *, runs: Sequence[str] | None = None, sequences: Sequence[str] | None = None,
        jobs: int | None = None, force: bool = False, output: str | Path | None = None,
        progress: bool = True) -> list[RunScores]:
    """Run an experiment file like ``mata-eval run`` and score it.

    ``experiment``: a YAML path, or the name of a shipped experiment (``"quickstart"``);
    ``runs``: only these run names of its matrix; ``sequences``: only these sequences; ``jobs``: worker processes (default: the
    cores); ``force``: redo finished sequences; ``output``: results folder instead of the
    file's ``output``; ``progress``: progress bar and messages. Optional runs whose model file
    is missing are skipped (with a message). Raises :class:`PreflightError` when anything else
    is missing, before any sequence runs; :class:`~mata_eval.core.errors.ConfigError` for a bad
    experiment file. Returns one :class:`RunScores` per run that ran, in the file's order."""
    from .run.config import load_experiment
    from .run.preflight import plan, skipped_lines
    from .run.runner import run_experiment
    from .score.evaluate import evaluate_experiment

    if _imported_by_a_worker():
        raise RuntimeError("mata_eval.run() called while a worker process imports your script: put the call "
                           "under `if __name__ == \"__main__\":` (worker processes import the script)")
    exp = load_experiment(experiment)
    if output is not None:
        exp = dataclasses.replace(exp, output=Path(output).resolve())
    checked = plan(exp, runs, sequences)
    if checked.problems:
        raise PreflightError(checked.problems)
    log = print if progress else (lambda _msg: None)
    for line in skipped_lines(checked.skipped):
        log(line)
    for line in checked.warnings:
        log(f"warning: {line}")
    names = [r.name for r in checked.runs]
    run_experiment(exp, jobs=jobs, force=force, only=names, sequences=list(sequences or []) or None,
                   progress=progress, log=log)
    return evaluate_experiment(exp, only=names)


def _imported_by_a_worker() -> bool:
    """Whether this call comes from the top level of a script that a spawned worker process is
    importing (as ``__mp_main__``): a script without an ``if __name__ == "__main__":`` guard,
    which would run the experiment again in every worker, find the run folder locked and die,
    leaving the parent a broken process pool and no hint."""
    import sys

    frame = sys._getframe(1)
    while frame is not None:
        if frame.f_code.co_name == "<module>" and frame.f_globals.get("__name__") == "__mp_main__":
            return True
        frame = frame.f_back
    return False


def evaluate(folder: str | Path | Sequence[str | Path], dataset: str, root: str | Path | None = None, *,
             profile: str = "default", layout: str = "auto", **dataset_params: Any) -> RunScores | list[RunScores]:
    """Score a results folder (mata-eval run folder, pysot, got10k or pytracking layout; see
    ``mata-eval eval``) against a dataset's annotations; no file is written. A list of folders
    gives a list of RunScores, the annotations read once.

    ``dataset``: a dataset plugin name (``mata-eval list``; an unknown one is a ValueError
    naming those that exist); ``root``: its folder; more of its parameters as keywords
    (``sequences=[...]``, ``fps=30``; None: the default); ``profile``: the metric profile (``default``,
    ``pysot-toolkit``, ``got10k``, ...). As ``mata-eval eval``: without ``root``, a mata-eval
    run folder of this dataset (the first one given of it) is scored on the run's own dataset
    parameters, the keywords on top, and each run folder with its run's occlusion augmentation."""
    import warnings

    from .core.params import build_params
    from .core.registry import load_registry
    from .run.results import in_run_cwd
    from .score.evaluate import evaluate_results
    from .score.run_dataset import as_the_run_saw_them, defaults_for_none, run_dataset_values, run_manifest

    try:
        cls = load_registry().get("dataset", dataset).cls
    except KeyError as exc:
        raise ValueError(exc.args[0]) from None
    folders = [Path(folder)] if isinstance(folder, (str, Path)) else [Path(f) for f in folder]
    manifests = [run_manifest(f, dataset) for f in folders]
    values = {**dataset_params, **({} if root is None else {"root": str(root)})}
    first = next((m for m in manifests if m), {}) if root is None else {}   # the first run folder of this dataset
    if first:
        values = run_dataset_values(first, values)
    lost: list[str] = []
    with in_run_cwd(first or None):   # (the run's relative paths; frame 0 for its occlusion augmentation)
        sequences = cls(build_params(cls.Params, defaults_for_none(cls.Params, values), ("dataset",))).sequences()
        seen = [as_the_run_saw_them(sequences, m.get("config", {}), lambda line, f=f: lost.append(f"{f}: {line}"))
                for f, m in zip(folders, manifests)]
    for line in lost:
        warnings.warn(line, stacklevel=2)
    scores = [evaluate_results(f, s, profile=profile, layout=layout, dataset=dataset) for f, s in zip(folders, seen)]
    return scores[0] if isinstance(folder, (str, Path)) else scores
