"""Zenoh transport: key expressions and message codecs (the client is `replanner.client`)."""

from .keys import Keys

__all__ = ["Keys"]
