"""User-facing errors.

Anything the user can cause (a missing file, a bad config key, a malformed trajectory) raises
:class:`SlamInputError` with a message naming the file or key; the CLI turns it into a one-line message
and exit code 2 instead of a traceback.
"""


class SlamInputError(ValueError):
    """Bad user input: the message names the offending file, key or value."""
