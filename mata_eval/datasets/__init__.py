"""Built-in dataset plugins, registered through the ``mata_eval`` entry-point group."""

from __future__ import annotations

from ..hooks import hookimpl


@hookimpl
def mata_eval_datasets() -> list[type]:
    return []
