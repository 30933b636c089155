"""mata-eval: evaluate and run single-object visual trackers on UAVs the way they run on board.

One package per concept (``docs/architecture.md`` has the map): ``core`` (types, parameters,
hooks, registry, interfaces), ``data`` (datasets, synthetic suite, occlusion augmentation),
``run`` (experiment file, scheduler, runner, run folders), ``score`` (metrics, evaluation),
``report`` (tables, plots, paper tables), ``deploy`` (export, timing profiles) and ``cli``. The
core imports no plugin. Built-in plugins live in ``mata_eval_plugins`` and are discovered through
the ``mata_eval`` entry-point group.

The plugin API is :mod:`mata_eval.types`, :mod:`mata_eval.params` and :mod:`mata_eval.hooks`.
"""

__version__ = "0.1.0"

