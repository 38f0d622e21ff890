"""User-facing errors.

Anything the user can cause (a missing file, a bad config key, a malformed trajectory) raises
:class:`SlamInputError` with a message naming the file or key; the CLI turns it into a one-line message
and exit code 2 instead of a traceback.
"""


class SlamInputError(ValueError):
    """Bad user input: the message names the offending file, key or value."""


class SlamOutputError(SlamInputError):
    """An output could not be written (a full disk, no permission): the message names the file and says that what
    was written before is intact. A :class:`SlamInputError` so the CLI reports it as one line too."""


class SlamRunError(RuntimeError):
    """The run cannot go on for a reason outside its input (the mapping process died or failed): the message is one
    line, the outputs so far are written and the last checkpoint is kept, so ``lrslam run --resume`` goes on from it.
    ``detail``: more for a bug report (the failing process's traceback), written to ``metrics.json``, not the
    terminal. The CLI reports it as one line and exits 1."""

    def __init__(self, message: str, detail: str = ""):
        super().__init__(message)
        self.detail = detail


class MissingDependencyError(ImportError):
    """The SLAM client's dependencies (the ``slam`` extra) are not installed; the message is one line naming
    the missing packages and the install command (see :mod:`slam._deps`)."""

    def __init__(self, missing: list[str]):
        from slam._deps import missing_message

        self.missing = list(missing)
        super().__init__(missing_message(self.missing), name=self.missing[0] if self.missing else None)

    def __reduce__(self):  # ImportError pickles its message as the first argument; ours is the package list
        return type(self), (self.missing,)
