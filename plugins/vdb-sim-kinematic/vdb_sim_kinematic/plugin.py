"""Registers the ``kinematic`` simulator. Importing this module is cheap: the simulator is built on use."""

from __future__ import annotations

import vladrivebench


def make_simulator(width: int = 160, height: int = 80, render: bool = True, hfov_deg: float = 90.0,
                   camera_height: float = 1.6, pitch_deg: float = 0.0, position_jitter: float = 0.2):
    """Build a :class:`~vdb_sim_kinematic.simulator.KinematicSimulator` (see its docstring for options)."""
    from .simulator import KinematicSimulator

    return KinematicSimulator(width=width, height=height, render=render, hfov_deg=hfov_deg,
                              camera_height=camera_height, pitch_deg=pitch_deg, position_jitter=position_jitter)


@vladrivebench.hookimpl
def register_simulators(register):
    register("kinematic", make_simulator,
             description="kinematic bicycle ego, scripted pedestrians/cars, numpy pinhole camera (10 Hz)")


@vladrivebench.hookimpl
def register_defaults(register):
    register("simulator", "kinematic", priority=10)
