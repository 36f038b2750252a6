"""The user error every layer may raise: the command line reports it in one line with exit status 2."""

from __future__ import annotations

__all__ = ["BadInput"]


class BadInput(ValueError):
    """A user error the command line reports in one line with exit status 2."""
