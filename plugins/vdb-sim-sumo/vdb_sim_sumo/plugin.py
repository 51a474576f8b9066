"""Registers the ``sumo`` simulator. Importing this module is cheap: libsumo is imported by the factory."""

from __future__ import annotations

import vladrivebench


def make_simulator(width: int | None = None, height: int | None = None, render: bool = True,
                   hfov_deg: float = 90.0, camera_height: float = 1.6, pitch_deg: float = 0.0,
                   position_jitter: float = 0.2, background_vehicles_per_hour: float = 0.0,
                   background_pedestrians_per_hour: float = 0.0, background_warmup_s: float = 30.0,
                   pedestrians: str = "scripted", net_file: str | None = None, route: str | None = None,
                   depart_pos: float = 0.0, cache_dir: str | None = None, rig: str = "front",
                   cameras: str | None = None, frames: int = 1, frame_rate_hz: float = 10.0, poses: int = 16):
    """Build a :class:`~vdb_sim_sumo.simulator.SumoSimulator` (see its docstring for the options)."""
    from .simulator import SumoSimulator

    return SumoSimulator(
        width=width, height=height, render=render, hfov_deg=hfov_deg, camera_height=camera_height,
        pitch_deg=pitch_deg, position_jitter=position_jitter,
        background_vehicles_per_hour=background_vehicles_per_hour,
        background_pedestrians_per_hour=background_pedestrians_per_hour,
        background_warmup_s=background_warmup_s, pedestrians=pedestrians, net_file=net_file, route=route,
        depart_pos=depart_pos, cache_dir=cache_dir, rig=rig, cameras=cameras, frames=frames,
        frame_rate_hz=frame_rate_hz, poses=poses,
    )


@vladrivebench.hookimpl
def register_simulators(register):
    register("sumo", make_simulator,
             description="SUMO via libsumo: netconvert networks, persons, frozen lights, background traffic (10 Hz)")
