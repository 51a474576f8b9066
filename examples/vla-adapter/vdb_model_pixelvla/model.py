"""A toy camera-only VLA showing every part of the VLAModel protocol.

"Vision": the share of strongly red pixels (a lit red lamp, a stop sign) and of pixels in the lower
middle of the image that look like neither road, grass nor sidewalk (an obstacle in the lane).
"Language": one sentence stating the decision. "Action head": a speed profile whose target comes from
the CoT's stated intent, mixed with the vision estimate by ``coupling`` (1 = the CoT alone decides).
The CoT's model state is just the intent parsed from its text, so splicing the model's own text
reproduces the generated state exactly (selfsplice) by construction.
"""

from __future__ import annotations

import hashlib
import json

import numpy as np
from vladrivebench import CoT, CoTFormat, Observation, Trajectory, TrajectorySpec

STOP_WORDS = ("stop", "brake", "slow", "yield")
GO_WORDS = ("accelerate", "speed up", "maintain", "keep", "continue", "proceed")


def read_intent(text: str) -> str:
    """The longitudinal intent a sentence states: ``stop``, ``go`` or ``none``."""
    lowered = text.lower()
    if any(word in lowered for word in STOP_WORDS):
        return "stop"
    if any(word in lowered for word in GO_WORDS):
        return "go"
    return "none"


def ego_lane_clutter(rgb: np.ndarray) -> float:
    """Share of pixels in the ego lane's wedge below the horizon that are not grey road or marking."""
    height, width = rgb.shape[:2]
    rows, cols = np.mgrid[0:height, 0:width]
    horizon, centre = height // 2, width / 2
    wedge = (rows > horizon) & (np.abs(cols - centre) < (rows - horizon) * 1.0)
    grey = np.abs(rgb[..., 0] - rgb[..., 2]) < 12
    yellow = (rgb[..., 0] > 180) & (rgb[..., 1] > 140) & (rgb[..., 2] < 110)
    return float((wedge & ~(grey | yellow)).sum() / max(wedge.sum(), 1))


class PixelVLA:
    """Implements ``vladrivebench.protocols.VLAModel``."""

    cot_format = CoTFormat(kind="sentence", max_tokens=64)
    trajectory_spec = TrajectorySpec(horizon_s=3.0, rate_hz=10.0)

    def __init__(self, cruise_speed: float, red_threshold: float, obstacle_threshold: float, coupling: float):
        if not 0.0 <= coupling <= 1.0:
            from vladrivebench import ConfigError

            raise ConfigError(f"model 'pixel-vla': option 'coupling' must be in [0, 1], got {coupling}")
        self.cruise_speed, self.coupling = cruise_speed, coupling
        self.red_threshold, self.obstacle_threshold = red_threshold, obstacle_threshold

    def reset(self, seed: int) -> None:
        """No memory across steps."""

    def _vision(self, image: np.ndarray) -> str:
        rgb = image.astype(np.int16)
        red = (rgb[..., 0] > 200) & (rgb[..., 1] < 90) & (rgb[..., 2] < 90)
        if red.mean() > self.red_threshold:
            return "Stop for the red light ahead."
        if ego_lane_clutter(rgb) > self.obstacle_threshold:
            return "Stop for the obstacle in the lane because it is blocking the lane."
        return "Keep lane and maintain speed since the road ahead is clear."

    def generate_cot(self, obs: Observation, rng: np.random.Generator) -> CoT:
        text = self._vision(obs.image)
        return CoT(text=text, state={"intent": read_intent(text)})

    def splice_cot(self, obs: Observation, text, rng: np.random.Generator) -> CoT:
        if not isinstance(text, str):
            text = " ".join(text.values())
        return CoT(text=text, state={"intent": read_intent(text)}, spliced=True)

    def decode_action(self, obs: Observation, cot: CoT, rng: np.random.Generator) -> Trajectory:
        cot_target = 0.0 if cot.state["intent"] == "stop" else self.cruise_speed
        vision_target = 0.0 if read_intent(self._vision(obs.image)) == "stop" else self.cruise_speed
        target = self.coupling * cot_target + (1 - self.coupling) * vision_target
        times = np.arange(1, 31) / 10.0
        speed, xs, x = float(obs.ego.speed), [], 0.0
        for _ in times:
            speed += float(np.clip(target - speed, -0.6, 0.3)) + float(rng.normal(0.0, 0.01))
            speed = max(speed, 0.0)
            x += speed * 0.1
            xs.append(x)
        return Trajectory(times=times, xy=np.column_stack([xs, np.zeros_like(times)]))

    def state_digest(self, cot: CoT) -> str:
        return hashlib.sha256(json.dumps(cot.state, sort_keys=True).encode()).hexdigest()
