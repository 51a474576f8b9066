"""How salient the obstacle was to the front camera at injection onset: pixels covered and angular size.

Two measures, both from the camera the model was given (its :class:`~vladrivebench.CameraSpec`):

* **pixels covered** — rendered: the front camera's frame at the onset pose drawn twice with the world's
  renderer (:class:`vladrivebench.world.Camera`), once with every actor and once without the obstacle;
  the pixels that differ (:func:`~vladrivebench.world.count_pixels_differing`) are the obstacle's footprint
  as the model saw it, after occlusion, clipping at the image border and the renderer's edge coverage. This
  is what the fit uses. The projection of the obstacle's box (below) is no substitute: its bounding
  rectangle includes background (and the renderer draws a pedestrian narrower than its box), while far
  away the renderer's partial edge pixels make the drawn footprint larger than the projected one.
* **angular size** — projected: the obstacle's box (8 corners) in the camera frame through the pinhole
  intrinsics (focal length from ``hfov_deg``, principal point at the image centre); its bounding rectangle
  in pixels, clipped to the image, and the horizontal / vertical angles it spans,
  ``atan((u₁ − cx) / f) − atan((u₀ − cx) / f)`` (and likewise in v).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from typing import Any

import numpy as np

NEAR_M = 0.05
"""Corners closer than this to the camera plane are not projected (the renderer's near plane)."""
FRONT = "front"


def box_corners(actor: Any) -> np.ndarray:
    """The 8 corners (x, y, z) in world coordinates of an actor's box (``length`` along its ``yaw``)."""
    c, s = math.cos(actor.yaw), math.sin(actor.yaw)
    out = []
    for along in (-0.5, 0.5):
        for across in (-0.5, 0.5):
            lx, ly = along * actor.length, across * actor.width
            for z in (0.0, actor.height):
                out.append((actor.x + c * lx - s * ly, actor.y + s * lx + c * ly, z))
    return np.asarray(out, dtype=float)


def to_camera(spec: Any, ego: Any, points: np.ndarray) -> np.ndarray:
    """World points (N, 3) → camera frame (N, 3): right, down, depth along the optical axis (the renderer's
    convention: mounted ``spec.x`` ahead and ``spec.y`` left of the ego's centre, ``spec.z`` up, turned
    left by ``yaw_deg`` and pitched down by ``pitch_deg``)."""
    c, s = math.cos(ego.yaw), math.sin(ego.yaw)
    dx, dy = points[:, 0] - ego.x, points[:, 1] - ego.y
    fwd = c * dx + s * dy - spec.x
    left = -s * dx + c * dy - spec.y
    yaw = math.radians(spec.yaw_deg)
    fwd, left = math.cos(yaw) * fwd + math.sin(yaw) * left, -math.sin(yaw) * fwd + math.cos(yaw) * left
    down = spec.z - points[:, 2]
    cp, sp = math.cos(math.radians(spec.pitch_deg)), math.sin(math.radians(spec.pitch_deg))
    return np.stack([-left, -fwd * sp + down * cp, fwd * cp + down * sp], axis=-1)


def angular_size(spec: Any, ego: Any, actor: Any) -> dict[str, Any]:
    """The obstacle box's bounding rectangle in the image (pixels, clipped) and the angles it spans (deg).

    ``in_view`` is false (and every size 0) when no part of the box is in front of the camera and inside
    the image; ``partial`` when some corner is behind the camera plane (only the others are projected).
    """
    camera = to_camera(spec, ego, box_corners(actor))
    front = camera[:, 2] > NEAR_M
    empty = {"in_view": False, "partial": bool(front.any() and not front.all()), "bbox_pixels": 0.0,
             "angular_width_deg": 0.0, "angular_height_deg": 0.0, "solid_angle_deg2": 0.0}
    if not front.any():
        return empty
    f, cx, cy = spec.focal, spec.width / 2, spec.height / 2
    u = cx + f * camera[front, 0] / camera[front, 2]
    v = cy + f * camera[front, 1] / camera[front, 2]
    u0, u1 = float(np.clip(u.min(), 0, spec.width)), float(np.clip(u.max(), 0, spec.width))
    v0, v1 = float(np.clip(v.min(), 0, spec.height)), float(np.clip(v.max(), 0, spec.height))
    if u1 <= u0 or v1 <= v0:
        return empty
    width = math.degrees(math.atan((u1 - cx) / f) - math.atan((u0 - cx) / f))
    height = math.degrees(math.atan((v1 - cy) / f) - math.atan((v0 - cy) / f))
    return {"in_view": True, "partial": not bool(front.all()), "bbox_pixels": (u1 - u0) * (v1 - v0),
            "angular_width_deg": width, "angular_height_deg": height, "solid_angle_deg2": width * height}


def front_spec(obs: Any) -> Any:
    """The :class:`~vladrivebench.CameraSpec` of the observation's front camera (its first if none is
    named ``front``)."""
    views = obs.camera_views()
    view = views.get(FRONT) or next(iter(views.values()))
    return view.spec


def pixels_covered(spec: Any, ego: Any, road: Any, actors: Iterable[Any], obstacle_id: str) -> int:
    """Pixels of the front camera's frame that the obstacle changes (rendered with vs without it)."""
    from vladrivebench.world import Camera, count_pixels_differing

    actors = tuple(actors)
    camera = Camera.from_spec(spec)
    with_obstacle = camera.render(road, ego, actors)
    without = camera.render(road, ego, tuple(a for a in actors if a.actor_id != obstacle_id))
    return count_pixels_differing(with_obstacle, without)


def measure(obs: Any, road: Any, obstacle_id: str) -> dict[str, Any]:
    """The obstacle's salience in the observation's front camera: pixels covered (rendered), their share
    of the image, the box's angular size, plus where it was measured (step, distance, camera)."""
    spec = front_spec(obs)
    truth = obs.ground_truth
    obstacle = truth.actor(obstacle_id)
    if obstacle is None:
        raise ValueError(f"step {obs.step}: the obstacle {obstacle_id!r} is not among the ground-truth actors")
    pixels = pixels_covered(spec, obs.ego, road, truth.actors, obstacle_id)
    return {"step": int(obs.step), "time": float(obs.time), "distance": float(truth.distance_to_critical),
            "speed": float(obs.ego.speed), "camera": spec.name, "image": [int(spec.width), int(spec.height)],
            "pixels": int(pixels), "pixel_share": pixels / float(spec.width * spec.height),
            **angular_size(spec, obs.ego, obstacle)}


def salience_value(record: Mapping[str, Any]) -> float:
    """The number the fit uses: pixels covered."""
    return float(record["pixels"])
