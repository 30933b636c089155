"""mata-eval: evaluate and run single-object visual trackers on UAVs the way they run on board.

Python API (:mod:`mata_eval.api`; ``import mata_eval`` itself loads nothing heavy)::

    import mata_eval as me
    runs = me.run("experiments/quickstart.yaml")    # list of RunScores
    print(runs[0].name, runs[0].overall.nt2f)
    scores = me.evaluate("results_folder/", dataset="dtb70", root="/data/DTB70", profile="pysot-toolkit")

One package per concept (``docs/architecture.md`` has the map): ``core`` (types, parameters,
hooks, registry, interfaces), ``data`` (datasets, synthetic suite, occlusion augmentation),
``run`` (experiment file, scheduler, runner, run folders), ``score`` (metrics, evaluation),
``report`` (tables, plots, paper tables), ``deploy`` (export, timing profiles) and ``cli``. The
core imports no plugin. Built-in plugins live in ``mata_eval_plugins`` and are discovered through
the ``mata_eval`` entry-point group.

The plugin API is :mod:`mata_eval.types`, :mod:`mata_eval.params` and :mod:`mata_eval.hooks`.
"""

from __future__ import annotations

import types as _types
from typing import Any

from . import run as _run_package  # the package only (its __init__ imports nothing)

__version__ = "0.1.0"


class _CallableRunPackage(_types.ModuleType):
    """``mata_eval.run`` is the package of the run machinery *and* the API function
    ``mata_eval.run(experiment, ...)``: Python binds a subpackage to its parent's attribute of
    the same name whenever it is imported, so a plain function ``run`` here would be replaced
    by the package; the package is made callable instead (see :func:`mata_eval.api.run`)."""

    def __call__(self, experiment: Any, *, runs: Any = None, sequences: Any = None, jobs: Any = None,
                 force: bool = False, output: Any = None, progress: bool = True) -> Any:
        """Run an experiment file like ``mata-eval run`` and score it; returns one RunScores per
        run that ran. ``experiment``: a YAML path or a shipped name (``"quickstart"``); ``runs``,
        ``sequences``: only these names; ``jobs``: worker processes (default: the cores);
        ``force``: redo finished sequences; ``output``: results folder instead of the file's;
        ``progress``: progress bar and messages. See :func:`mata_eval.api.run`."""
        from .api import run

        return run(experiment, runs=runs, sequences=sequences, jobs=jobs, force=force, output=output,
                   progress=progress)


_run_package.__class__ = _CallableRunPackage


def evaluate(folder: Any, dataset: str, root: Any = None, *, profile: str = "default", layout: str = "auto",
             **dataset_params: Any) -> Any:
    """Score a results folder (a mata-eval run folder, or pysot / got10k / pytracking layout)
    against a dataset's annotations, writing nothing; returns its RunScores. ``dataset``: a
    dataset plugin name, ``root``: its folder, other parameters of it as keywords
    (``sequences=[...]``, ``annotations=...``); ``profile``: the metric profile. See
    :func:`mata_eval.api.evaluate`."""
    from .api import evaluate as _evaluate

    return _evaluate(folder, dataset, root, profile=profile, layout=layout, **dataset_params)


def __getattr__(name: str) -> Any:
    """Lazy names: the result and error types of the API."""
    if name == "RunScores":
        from .score.evaluate import RunScores

        return RunScores
    if name == "PreflightError":
        from .api import PreflightError

        return PreflightError
    raise AttributeError(f"module 'mata_eval' has no attribute {name!r}")
