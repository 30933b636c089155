"""mata-eval: evaluate and run single-object visual trackers on UAVs the way they run on board.

The core (this package) holds the types, plugin registry, experiment files, scheduler, metrics,
datasets, results, reports and CLI; it imports no plugin. Built-in plugins live in
``mata_eval_plugins`` and are discovered through the ``mata_eval`` entry-point group.
"""

__version__ = "0.1.0"
