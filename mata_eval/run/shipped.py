"""The experiment files shipped with mata-eval and the files they name."""

from __future__ import annotations

from pathlib import Path

#: where the experiments shipped with mata-eval are: the wheel's ``mata_eval/experiments`` or,
#: in a source checkout, ``experiments/`` beside the package
SHIPPED = (Path(__file__).resolve().parents[1] / "experiments", Path(__file__).resolve().parents[2] / "experiments")


def shipped_file(path: str | Path) -> Path:
    """``path``, or for ``experiments/...`` not found from the current folder the file shipped
    with mata-eval (a shipped experiment's timing profiles, read from any folder and in a wheel
    install). The experiment keeps the path as written: its configuration hash is the same
    wherever mata-eval is installed."""
    path = Path(path)
    if path.exists() or path.is_absolute() or path.parts[:1] != ("experiments",):
        return path
    return next((f.parent / path for f in SHIPPED if (f.parent / path).exists()), path)
