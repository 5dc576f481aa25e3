"""Exceptions that the command line turns into a one-line message and exit code 1."""


class FaceAnalysisError(Exception):
    """A failure caused by the user's input or environment, not by a bug.

    The command line prints ``faceanalysis: error: <message>`` for it and exits
    with status 1; the Python API lets it propagate. Input errors raised as
    :class:`ValueError` or :class:`FileNotFoundError` are treated the same way.
    """
