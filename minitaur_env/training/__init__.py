"""Reusable pieces of the training and evaluation scripts (SB3 wiring, callbacks, videos)."""


class UsageError(Exception):
    """A mistake in what the user asked for; the scripts print it as one line."""
