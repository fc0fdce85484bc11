"""A toy plug-in detector with a constructed complexity boundary (used by the tests as a user
would use a plug-in: ``--detector tests.toy_detector:BlindAbove``).

It sees a looming object perfectly: the share of very dark pixels (the rendered object is
level 20, the textured backgrounds never below 70) above ``dark_share`` is an alert. But it is
blind, by construction, whenever the scene is too busy: once the running mean of the AVDM's
response (``avdm-natural``, the model ``vdc-analyse complexity`` profiles clips with) over the
frames so far exceeds ``blind_above_dps``, it never alerts. So its success falls from 100 % to
0 % at ``blind_above_dps``: the truth its measured boundary is tested against.
"""

from __future__ import annotations

import numpy as np

from avdm.registry import make_model


class BlindAbove:
    outputs = (("dark_share", "1"), ("busy_dps", "deg/s"), ("alert", "1"))

    def __init__(
        self,
        blind_above_dps: float = 20.0,
        # 0.002 of a 160x120 frame is a disc of 3.5 px radius: tests/footage_clips.py's object
        # (radius 60 px / frames to collision) covers it 17 frames (0.68 s) before impact, inside
        # the 1 s alert window and earlier than boundary's default --min-ttc-s (0.5 s), so it
        # sees the object in time (0.02 was 0.2 s before: a miss since too-late alerts count)
        dark_share: float = 0.002,
        profile_model: str = "avdm-natural",
        **camera: float,
    ) -> None:
        self.blind_above_dps, self.dark_share = blind_above_dps, dark_share
        self.avdm = make_model(profile_model, **camera)  # the camera vdc passes in
        self.reset()

    def reset(self) -> None:
        self.avdm.reset()
        self.total, self.seen = 0.0, 0

    def step(self, frame: np.ndarray) -> dict[str, float]:
        self.total += self.avdm.step(frame)["omega_dps"]
        self.seen += 1
        busy = self.total / self.seen
        dark = (
            float((frame < 45).mean()) if frame.dtype == np.uint8 else float((frame < 0.18).mean())
        )
        alert = dark > self.dark_share and busy <= self.blind_above_dps
        return {"dark_share": dark, "busy_dps": busy, "alert": float(alert)}


def broken(**_camera: float) -> BlindAbove:
    """A factory that raises, as a user's broken plug-in would."""
    raise RuntimeError("no camera calibration found for this detector")


class NoAlert:
    """A plug-in without an 'alert' output: it cannot drive the robot."""

    outputs = (("brightness", "1"),)

    def __init__(self, gain: float = 1.0) -> None:
        self.gain = gain

    def step(self, frame):
        return {"brightness": self.gain * float(frame.mean())}
