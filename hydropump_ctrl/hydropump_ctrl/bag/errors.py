"""The errors of bags, under one root.

:class:`BagError` is a :class:`~hydropump_sim.errors.HydropumpError` (one line, shown after
``error:``). Its kinds say which way the bag failed, and keep the built-in base a caller
catches: a bag that cannot be read as asked is a :class:`BagReadError` (``ValueError``: bad
input); one that cannot be written is a :class:`BagOutputError` (``OSError``), of which a
folder that exists already is a :class:`BagExistsError` and a write that failed on the way
(disk full, a file-size limit) a :class:`BagWriteError`.
"""

from __future__ import annotations

from pathlib import Path

from hydropump_sim.errors import HydropumpError


class BagError(HydropumpError):
    """A bag that cannot be read or written as asked."""


class BagReadError(BagError, ValueError):
    """A bag or saved recording that cannot be read as asked."""


class BagOutputError(BagError, OSError):
    """A bag that cannot be written as asked."""


class BagExistsError(BagOutputError):
    """The bag folder exists already (a bag is never overwritten)."""


class BagWriteError(BagOutputError):
    """Writing failed (disk full, file too large, I/O error); the bag is closed with the
    messages written before (:attr:`messages` of them)."""

    def __init__(self, text: str, path: Path, reason: str, messages: int):
        super().__init__(text)
        self.path, self.reason, self.messages = path, reason, messages
