"""The errors vdc raises on purpose.

A :class:`UserError` is a problem with the user's input (an unknown model, a file that is not a
video, a range beyond what the camera can show): the command lines print it as one line and exit
with status 2. Any other exception is a bug and keeps its traceback.
"""

from __future__ import annotations


class UserError(ValueError):
    """A problem with the user's input: printed as one line, exit status 2."""
