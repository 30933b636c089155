"""Errors a user sees."""

from __future__ import annotations


class ConfigError(ValueError):
    """Bad input in an experiment file: says where (``file:line``), which key path, and what was
    expected."""

    def __init__(self, location: str, keypath: tuple = (), message: str = ""):
        self.location = location
        self.keypath = tuple(keypath)
        self.message = message
        key = ".".join(str(k) for k in self.keypath)
        head = ": ".join(p for p in (location, key) if p)
        super().__init__(f"{head}: {message}" if head else message)
