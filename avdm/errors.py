"""The error the models raise on purpose.

A :class:`ParameterError` is a problem with what the caller asked of a model (an unknown variant,
a parameter out of its range, a policy file that is not one). The command lines print it as one
line and exit with status 2, as they do vdc's ``UserError``; any other exception is a bug and
keeps its traceback. It is a ``ValueError``, so code that catches those still catches it.
"""

from __future__ import annotations


class ParameterError(ValueError):
    """A bad model name, parameter or policy: printed as one line, exit status 2."""
