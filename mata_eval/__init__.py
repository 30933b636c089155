"""mata-eval: evaluate and run single-object visual trackers on UAVs the way they run on board.

The core (this package) holds the types, plugin registry, experiment files, scheduler, metrics,
datasets, results, reports and CLI; it imports no plugin. Built-in plugins live in
``mata_eval_plugins`` and are discovered through the ``mata_eval`` entry-point group.
"""

__version__ = "0.1.0"

# Transitional while the move commit lands: the public plugin API modules now live in core/.
import sys as _sys  # noqa: E402

from .core import hooks as _hooks, params as _params, types as _types  # noqa: E402

_sys.modules.update({"mata_eval.hooks": _hooks, "mata_eval.params": _params, "mata_eval.types": _types})
