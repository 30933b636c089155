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


class ConfigErrors(ConfigError):
    """Several independent problems of one experiment file (each plugin block is checked, and
    each run of a matrix), one :class:`ConfigError` per line; reads as the first one
    (``location``, ``keypath``, ``message``)."""

    def __init__(self, errors: "list[ConfigError]"):
        self.errors = tuple(errors)
        first = self.errors[0]
        super().__init__(first.location, first.keypath, first.message)
        self.args = ("\n".join(str(e) for e in self.errors),)

    def __str__(self) -> str:
        return self.args[0]


def raise_all(errors: "list[ConfigError]") -> None:
    """Raise the problems collected, if any: one as it is, several as :class:`ConfigErrors`
    (the same problem found in several runs of a matrix once)."""
    unique = list({str(e): e for e in errors}.values())
    if len(unique) == 1:
        raise unique[0]
    if unique:
        raise ConfigErrors(unique)


class Interrupted(BaseException):
    """SIGINT or SIGTERM reached the driver of a run (a BaseException, like KeyboardInterrupt,
    so that no ``except Exception`` records it as a failure). ``exit_status``: 128 + signal."""

    def __init__(self, signum: int):
        super().__init__(signal.Signals(signum).name)
        self.signum = signum
        self.exit_status = 128 + signum
        self.outcomes: list = []
