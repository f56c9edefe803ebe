"""The project's root error: every error aider-exo reports to its user as one line derives from
:class:`AiderError` (the command line prints it without a traceback)."""

from __future__ import annotations


class AiderError(Exception):
    """Base class of the errors aider-exo reports to its user."""
