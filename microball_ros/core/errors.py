"""The project's one error hierarchy: what a user can fix, as opposed to a bug.

Every error a user can cause (a malformed file, a wrong unit, an unusable bag, data a fit cannot
describe) is a ``MicroballError``; its message is one line in the user's terms. The CLI maps
exactly these to exit status 2 and prints the message; anything else escaping a command is a bug
and gets a traceback and exit status 1. The subclasses also derive from ``ValueError`` so code
that validated with ``except ValueError`` keeps working.
"""


class MicroballError(Exception):
    """Base of every error a user can cause and fix; the message is one line for the user."""


class InputError(MicroballError, ValueError):
    """Bad input: a file, option, parameter or record that cannot be used as given."""


class BagError(InputError):
    """A bag (directory or .mcap) that cannot be read or used."""


class FitError(MicroballError, ValueError):
    """A fit that failed on the data given (no convergence, a parameter leaving its domain)."""
