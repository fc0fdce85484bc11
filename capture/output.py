"""One writer per recording path: an exclusive claim, a partial file, publication at the end.

A capture never writes its final path directly. It holds an exclusive ``flock`` on
``.<name>.lock`` in the target folder for its whole life, writes ``<stem>.partial.rrd`` beside the
target, and only when the recording is closed takes the final name:

* without ``force`` by a hard link, which fails if the name exists, so of two writers one wins
  and the other is told in one line; with ``force`` by ``os.replace``, so an old recording is
  replaced only when the new one is complete (a reader sees the old file or the new one);
* the lock is a kernel ``flock``: a writer killed by any signal, SIGKILL included, releases it;
* a capture killed by SIGKILL (or a power cut) leaves ``<stem>.partial.rrd``: a readable
  recording without a footer. It is never deleted by a later capture without ``--force``.
"""

from __future__ import annotations

import errno
import fcntl
import os
from pathlib import Path
from typing import Any

from vdc.errors import UserError
from vdc.recording import PARTIAL_SUFFIX, lock_path, partial_path

__all__ = ["OutputClaim", "claim_output", "lock_path", "partial_path"]


def _check_name(path: Path) -> None:
    if path.suffix != ".rrd":
        raise UserError(f"output {str(path)!r} must end in .rrd.")
    if path.name.endswith(PARTIAL_SUFFIX):
        raise UserError(
            f"output {str(path)!r} ends in {PARTIAL_SUFFIX}, the name of captures in progress; "
            "choose another --out."
        )
    if path.is_dir():
        raise UserError(f"output {str(path)!r} is a directory; give a file name ending in .rrd.")


class OutputClaim:
    """The exclusive right to write one recording path; see the module docstring.

    Use :func:`claim_output`, write to :attr:`partial`, then :meth:`finish`."""

    def __init__(self, path: Path, force: bool, fd: int) -> None:
        self.path = path
        self.partial = partial_path(path)
        self.force = force
        self._fd: int | None = fd

    def finish(self, keep: bool) -> None:
        """Publish the partial file under the final name (``keep``) or remove it (nothing of
        value was written), then release the claim. Raises ValueError when the final name was
        taken meanwhile by something that does not respect the lock; the partial file stays."""
        try:
            if not keep:
                self.partial.unlink(missing_ok=True)
            elif self.partial.exists():
                if self.force:
                    os.replace(self.partial, self.path)
                else:
                    try:
                        os.link(self.partial, self.path)  # exclusive: fails if the name exists
                    except FileExistsError:
                        raise UserError(
                            f"{str(self.path)!r} appeared while recording; the recording is kept "
                            f"as {str(self.partial)!r}."
                        ) from None
                    self.partial.unlink()
        finally:
            self.release()

    def release(self) -> None:
        """Drop the lock (idempotent). The lock file is removed while still held, so a waiting
        writer never locks a file that is no longer the one at the path."""
        if self._fd is None:
            return
        try:
            lock_path(self.path).unlink(missing_ok=True)
        finally:
            os.close(self._fd)
            self._fd = None

    def __enter__(self) -> OutputClaim:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.release()


def claim_output(path: Path, force: bool) -> OutputClaim:
    """Take the exclusive claim on ``path`` before anything is rendered or written.

    Raises ValueError with one line saying what to do when the name is wrong, the folder cannot
    be written (tested by creating the lock file there, not guessed from permission bits, so
    ``/proc`` or a read-only mount is caught), another capture holds the claim, the output
    exists (without ``force``), or a capture killed earlier left its partial file."""
    path = Path(path)
    _check_name(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise UserError(f"cannot create the folder {str(path.parent)!r}: {exc.strerror}") from None
    lock = lock_path(path)
    for _ in range(20):  # the lock file can be replaced between open and flock: retry
        try:
            fd = os.open(lock, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o644)
        except OSError as exc:
            raise UserError(
                f"cannot write in the folder {str(path.parent)!r}: {exc.strerror}"
            ) from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as exc:
            os.close(fd)
            if exc.errno in (errno.EWOULDBLOCK, errno.EAGAIN):
                raise UserError(
                    f"another capture is writing {str(path)!r} right now; wait for it or "
                    "choose another --out."
                ) from None
            raise UserError(f"cannot lock {str(lock)!r}: {exc.strerror}") from None
        try:
            same = os.fstat(fd).st_ino == os.stat(lock).st_ino
        except FileNotFoundError:
            same = False
        if same:
            break
        os.close(fd)
    else:  # pragma: no cover - needs 20 lost races in a row
        raise UserError(f"could not lock {str(lock)!r}; try again.")
    claim = OutputClaim(path, force, fd)
    try:
        # a probe write: a folder that accepts a lock file but no data (a full disk) fails here
        os.ftruncate(fd, 0)  # the pid names the live writer (vdc.recording.capture_writing)
        os.write(fd, f"{os.getpid()}\n".encode())
        if not force and path.exists():
            raise UserError(
                f"{str(path)!r} already exists (same configuration recorded before?): "
                "pass --force to record it again, or choose --out."
            )
        if not force and claim.partial.exists():
            raise UserError(
                f"{str(claim.partial)!r} holds a capture that was cut short (killed?); analyse it "
                "as it is, rename or remove it, or pass --force to replace it."
            )
    except OSError as exc:
        claim.release()
        raise UserError(
            f"cannot write in the folder {str(path.parent)!r}: {exc.strerror}"
        ) from None
    except BaseException:
        claim.release()
        raise
    return claim
