"""vdc.sources: how vdc opens a video when the user has turned on PyAV's Python logging."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from tests.helpers import write_pan

ROOT = Path(__file__).resolve().parents[2]

# The child turns PyAV's Python log callback on, as Rerun's own video example does, then
# reads a clip through vdc and lets the garbage collector free what it left.
CHILD = """
import gc, sys
import av
from vdc.sources import open_reader, open_video

getattr(av.logging, "set_level")(av.logging.VERBOSE)  # the user's choice, not vdc's
container, stream = open_video(sys.argv[1])
print(stream.thread_type.name, stream.codec_context.thread_count)
container.close()
reader = open_reader(sys.argv[1])
n = sum(1 for _ in reader.frames())
reader.close()
del reader
gc.collect()
print(n)
"""


def test_with_pyavs_python_logging_on_ffmpeg_decodes_on_one_thread(tmp_path) -> None:
    """FFmpeg's frame threads wait for the GIL to log through PyAV's callback while a
    container being freed holds the GIL and waits for them: the deadlock that once held CI
    for 90 minutes. With the callback on, vdc opens the stream with no frame threads."""
    clip = write_pan(tmp_path / "pan.mp4", 160, 120, 30)
    proc = subprocess.run(
        [sys.executable, "-c", CHILD, str(clip)],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=120,  # a hang guard: the child ends in about a second
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    threads, count, frames = proc.stdout.split()
    assert (threads, count) == ("NONE", "1")  # AUTO 0 before: FFmpeg's frame threads
    assert int(frames) == 30
