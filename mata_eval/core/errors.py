"""Errors a user sees: each says in one line what is wrong, where, and what to do. The command
line prints them without a traceback (``--debug`` shows it)."""

from __future__ import annotations

import signal


class UserError(Exception):
    """A mistake the user can fix (bad input, a busy or conflicting output folder)."""


class ConfigError(UserError, ValueError):
    """Bad input in an experiment file: says where (``file:line``), which key path, and what was
    expected."""

    def __init__(self, location: str, keypath: tuple = (), message: str = ""):
        self.location = location
        self.keypath = tuple(keypath)
        self.message = message
        key = ".".join(str(k) for k in self.keypath)
        head = ": ".join(p for p in (location, key) if p)
        super().__init__(f"{head}: {message}" if head else message)


class Interrupted(BaseException):
    """SIGINT or SIGTERM reached the driver of a run (a BaseException, like KeyboardInterrupt,
    so that no ``except Exception`` records it as a failure). ``exit_status``: 128 + signal."""

    def __init__(self, signum: int):
        super().__init__(signal.Signals(signum).name)
        self.signum = signum
        self.exit_status = 128 + signum
        self.outcomes: list = []
