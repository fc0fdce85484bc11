"""The error the models raise on purpose.

A :class:`ParameterError` is a problem with what the caller asked of a model (an unknown variant,
a parameter out of its range, a policy file that is not one). The command lines print it as one
line and exit with status 2, as they do vdc's ``UserError``; any other exception is a bug and
keeps its traceback. It is a ``ValueError``, so code that catches those still catches it.
"""

from __future__ import annotations


class ParameterError(ValueError):
    """A bad model name, parameter or policy: printed as one line, exit status 2."""


class PluginError(ParameterError):
    """A model plug-in (the user's code) raised while it ran: one line naming the plug-in, the
    clip and the frame (when the caller knows them) and the plug-in's own error, never its
    traceback. ``offset``: the failing frame's index among the frames given to the call that
    failed (None: somewhere in them); a caller that knows those frames' numbers sets
    ``frame``, and ``clip``."""

    def __init__(self, ref: str, cause: BaseException, offset: int | None = None) -> None:
        detail = str(cause).splitlines()[0] if str(cause) else ""
        self.ref, self.offset = ref, offset
        self.cause = f"{type(cause).__name__}: {detail}" if detail else type(cause).__name__
        self.clip: str | None = None
        self.frame: int | None = None
        self.span: tuple[int, int] | None = None  # its frames, when the failing one is unknown
        super().__init__(str(self))

    def at(self, frames: object) -> PluginError:
        """Name the failing frame from the numbers of the frames given to the failed call."""
        try:
            if self.offset is not None and self.frame is None:
                self.frame = int(frames[self.offset])  # type: ignore[index]
            elif self.offset is None and self.span is None and len(frames):  # type: ignore[arg-type]
                self.span = (int(frames[0]), int(frames[-1]))  # type: ignore[index]
        except (IndexError, TypeError, ValueError):
            pass
        self.args = (str(self),)
        return self

    def on(self, clip: str) -> PluginError:
        """Name the clip (or recording) the plug-in failed on."""
        self.clip = clip
        self.args = (str(self),)
        return self

    def __str__(self) -> str:
        where = f" on {self.clip}" if self.clip else ""
        if self.frame is not None:
            where += f" at frame {self.frame}"
        elif self.span is not None:
            where += f" in frames {self.span[0]}-{self.span[1]}"
        return f"model plug-in {self.ref!r} failed{where}: {self.cause}"
