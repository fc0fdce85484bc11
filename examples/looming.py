"""A looming detector in a few lines of OpenCV, as a vdc model plug-in.

    vdc-capture video clip.mp4 --fov-deg 60 --model examples.looming:Looming
    vdc-analyse boundary --labels clips/labels.csv --fov-deg 60 \
        --detector examples.looming:Looming --param threshold --values 0.05,0.1

Like the locust's LGMD at its crudest: excitation is the share of the view whose brightness
changed since the last frame; an object on a collision course excites more and more of it, so
an alert is excitation above ``threshold`` for ``frames`` frames in a row. A busy, moving
background excites it too: where that happens is what `vdc-analyse boundary` measures.
"""

import cv2
import numpy as np


class Looming:
    outputs = (("excitation", "1"), ("alert", "1"))  # (name, unit) of each output

    def __init__(self, threshold: float = 0.1, frames: int = 2, levels: int = 12) -> None:
        self.threshold, self.frames, self.levels = threshold, frames, levels
        self.reset()

    def reset(self) -> None:
        self.previous, self.run_length = None, 0

    def step(self, frame: np.ndarray) -> dict[str, float]:
        grey = frame if frame.dtype == np.uint8 else (frame * 255).astype(np.uint8)
        smooth = cv2.GaussianBlur(grey, (5, 5), 0)
        if self.previous is None:
            self.previous = smooth
        excitation = float((cv2.absdiff(smooth, self.previous) > self.levels).mean())
        self.previous = smooth
        self.run_length = self.run_length + 1 if excitation > self.threshold else 0
        return {"excitation": excitation, "alert": float(self.run_length >= self.frames)}
