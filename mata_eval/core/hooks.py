"""pluggy hook specifications: one hook per plugin kind. A plugin module implements the hooks of
the kinds it provides and returns its plugin classes::

    from mata_eval.hooks import hookimpl

    @hookimpl
    def mata_eval_trackers():
        return [MyTracker]

and is named in its distribution's ``pyproject.toml``::

    [project.entry-points.mata_eval]
    mytracker = "mytracker_pkg.plugin"
"""

from __future__ import annotations

import pluggy

PROJECT = "mata_eval"
hookspec = pluggy.HookspecMarker(PROJECT)
hookimpl = pluggy.HookimplMarker(PROJECT)


class PluginSpecs:
    @hookspec
    def mata_eval_trackers(self) -> list[type]:
        """Tracker classes (block A): see :class:`mata_eval.core.interfaces.Tracker`."""

    @hookspec
    def mata_eval_egomotion(self) -> list[type]:
        """Ego-motion classes (block B): see :class:`mata_eval.core.interfaces.EgoMotion`."""

    @hookspec
    def mata_eval_estimators(self) -> list[type]:
        """Estimator classes (block C): see :class:`mata_eval.core.interfaces.Estimator`."""

    @hookspec
    def mata_eval_protocols(self) -> list[type]:
        """Evaluation protocol classes: presets of :mod:`mata_eval.run.scheduler`."""

    @hookspec
    def mata_eval_datasets(self) -> list[type]:
        """Dataset classes: see :class:`mata_eval.core.interfaces.Dataset`."""


KINDS = {
    "tracker": "mata_eval_trackers",
    "egomotion": "mata_eval_egomotion",
    "estimator": "mata_eval_estimators",
    "protocol": "mata_eval_protocols",
    "dataset": "mata_eval_datasets",
}
