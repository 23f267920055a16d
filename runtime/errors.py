"""Errors a person sees: one line naming the thing and what was expected; the CLI exits 2."""


class InputError(ValueError):
    """Bad input from a person (file, argument, JSON).  ``str()`` is the whole one-line message."""
