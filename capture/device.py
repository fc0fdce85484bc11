"""What every capture device delivers, simulated or real.

Like LeRobot's devices: a config plus one interface that the simulated and the real robot both
implement (``connect`` / ``read`` / ``disconnect``, and a context manager through
``DeviceContext``). ``read`` returns the next ``Batch`` of consecutive frames, or None at the
end; capture code does not care which it has.
"""

from __future__ import annotations

import dataclasses
from typing import Any, Protocol, Self

import numpy as np


@dataclasses.dataclass(frozen=True)
class Event:
    """Something that happened at one frame: a ring turn, an avoidance, a crash, a link error."""

    kind: str
    frame: int
    x_m: float
    y_m: float
    heading_rad: float
    text: str


@dataclasses.dataclass
class Batch:
    """Consecutive camera frames with everything known about them.

    frame (N,) int64 camera frame indices; t_s (N,) float64 seconds since the run started;
    images (N, H, W) uint8; poses (N, 3) float64 [x_m, y_m, heading_rad]; wall_tf_hz (N,);
    events in these frames (poses may be NaN where a real tracker lost the robot); overhead:
    (frame index, image) pairs; onboard: outputs of models that ran on the robot itself,
    ``{model name: {output: (N,)}}``.
    """

    frame: np.ndarray
    t_s: np.ndarray
    images: np.ndarray
    poses: np.ndarray | None  # None: a source with no pose (a video)
    wall_tf_hz: np.ndarray | None  # None: a source with no arena walls (a video)
    events: list[Event]
    overhead: list[tuple[int, np.ndarray]] = dataclasses.field(default_factory=list)
    onboard: dict[str, dict[str, np.ndarray]] = dataclasses.field(default_factory=dict)
    # real robots: the frames ``images`` belong to (a decimating link sends fewer images than
    # frames; None = one image per frame), host receive times (int64 ns since the epoch), and
    # the link's running counts
    image_frame: np.ndarray | None = None
    capture_time_ns: np.ndarray | None = None
    link_stats: dict[str, int] | None = None
    # real cameras (video): the frames that repeat the previous one, and how many frames the
    # timestamps say are missing just before each frame (None: a source with neither)
    repeat: np.ndarray | None = None
    dropped_before: np.ndarray | None = None
    # sources with native frames: (N, len(NATIVE_METRICS)) float64, the standard metrics on
    # each frame's native luma (vdc.frame_metrics; NaN where undefined)
    native_metrics: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.frame)


class CaptureDevice(Protocol):
    """What the capture loop needs from a robot, simulated or real."""

    def connect(self) -> None: ...

    def read(self) -> Batch | None: ...

    def disconnect(self) -> None: ...


class DescribedDevice(Protocol):
    """A device that says what it is: what a recording of it shows in the viewer."""

    def properties(self) -> dict[str, dict[str, Any]]:
        """The recording's property sections that describe the device (``vdc.recording``'s
        ``PROPERTY_SECTIONS``: ``run``, ``camera``, ``wall``...)."""
        ...

    def description(self) -> str:
        """What a recording of it holds, in a sentence (the description's **What**)."""
        ...


class DeviceContext:
    """The context manager every device is: ``with device:`` connects on entry and
    disconnects on exit (whatever happened)."""

    def connect(self) -> None:
        raise NotImplementedError

    def disconnect(self) -> None:
        raise NotImplementedError

    def __enter__(self) -> Self:
        self.connect()
        return self

    def __exit__(self, *exc: object) -> None:
        self.disconnect()
