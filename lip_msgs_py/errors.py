"""The one error type of the message layer."""

from __future__ import annotations

__all__ = ["MalformedMessageError"]


class MalformedMessageError(ValueError):
    """A message, or the arrays to build one from, violates its layout or contract.

    Raised by every reader and writer of ``lip_msgs_py`` with the reason in the text.
    """
