"""Plugin parameters: the ``param()`` field helper and the validation of experiment blocks.

Public plugin API: plugins import from here. The code lives in :mod:`mata_eval.core.params`;
this module re-exports it so that ``from mata_eval.params import ...`` stays stable."""

from .core.params import ParamInfo, build_params, describe, param, parse_key_values

__all__ = ["ParamInfo", "build_params", "describe", "param", "parse_key_values"]
