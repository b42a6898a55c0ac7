"""User-facing errors: the CLI prints ``CurvsliceError`` as one line and exits non-zero."""


class CurvsliceError(Exception):
    """A problem with the user's input or settings, with an actionable message."""
