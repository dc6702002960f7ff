"""Errors that mean "the user gave something wrong" (shown as one line, exit code 2)."""


class DynoplanError(Exception):
    """A user-facing error: bad argument, malformed file, unknown name.

    The command line prints ``dynoplan: error: <message>`` and exits non-zero, with no
    traceback. Library code raises it for mistakes a caller can fix; bugs stay ordinary
    exceptions.
    """


class DynoplanWarning(UserWarning):
    """Something the user should know that does not stop the run (for example an option
    never demonstrated, or one admissible almost nowhere). The command line prints it as
    one line, ``dynoplan: warning: <message>``."""
