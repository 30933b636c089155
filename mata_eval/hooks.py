"""The plugin hooks: ``hookimpl`` for plugin modules, the hook specs and the plugin kinds.

Public plugin API: plugins import from here. The code lives in :mod:`mata_eval.core.hooks`;
this module re-exports it so that ``from mata_eval.hooks import ...`` stays stable."""

from .core.hooks import KINDS, PROJECT, PluginSpecs, hookimpl, hookspec

__all__ = ["KINDS", "PROJECT", "PluginSpecs", "hookimpl", "hookspec"]
