"""A fixed, varied set of rendered camera images and their SHA-256 hashes: the renderer's pixel contract.

The neural models are trained on these images, so an optimisation of the renderer (``world/_camera.py``,
``world/_rig.py``) must keep every pixel of every camera. ``tests/test_render_hashes.py`` renders every
scene below and compares its hash with ``tests/data/render_hashes.json``, written by this script from
the renderer as it was when the contract was set:

    python tests/render_scenes.py --write      # (re)write tests/data/render_hashes.json
    python tests/render_scenes.py              # check, print the scenes that differ

Rewrite the file only for an intended change of the images (and retrain the models on the new ones).

The scenes: every scenario of the suite on the kinematic simulator with its default front camera, the
ego driven along its route by teleporting controls (``Control.next_state``) with a small weave, hashed
at several steps; the same with the scenery removed or swapped; the ``alpamayo`` rig (four cameras, a
frame history at 2 Hz); odd image sizes, fields of view, pitch and mounting height; direct renders of
random actors of every kind around random ego poses (near-plane clipping, sub-pixel faces, lamps); and,
when ``libsumo`` is installed, three scenarios on the SUMO simulator.
"""

from __future__ import annotations

import argparse
import dataclasses
import hashlib
import json
import math
import sys
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np

HASHES = Path(__file__).resolve().parent / "data" / "render_hashes.json"
SPEED = 6.0
"""Metres per second the ego advances along its route in the driven scenes."""


def image_hash(image: np.ndarray) -> str:
    """SHA-256 of an image's shape, dtype and pixels."""
    array = np.ascontiguousarray(image)
    header = f"{array.shape}|{array.dtype}|".encode()
    return hashlib.sha256(header + array.tobytes()).hexdigest()


def suite() -> dict:
    from vladrivebench._engine.registry import get_registry
    from vladrivebench._scenarios.spec import load_suite

    return dict(load_suite(get_registry()))


def with_scenery(scenario, scenery: str):
    return dataclasses.replace(scenario, road=dataclasses.replace(scenario.road, scenery=scenery))


def driven_pose(route, step: int, speed: float):
    """The ego's pose at ``step``: ``speed`` m/s along the route, weaving ±0.4 m and ±0.06 rad."""
    from vladrivebench.records import EgoState

    s = speed * 0.1 * step
    x, y = (float(v) for v in route.to_world(s, 0.4 * math.sin(0.3 * step)))
    yaw = float(route.heading(s)) + 0.06 * math.sin(0.23 * step)
    return EgoState(x, y, yaw, speed, 0.0)


def drive(simulator, scenario, seed: int, steps: tuple[int, ...]) -> Iterator[tuple[int, dict]]:
    """(step, {camera: image}) of ``scenario`` at each of ``steps`` (until the episode ends)."""
    from vladrivebench.records import Control

    obs = simulator.reset(scenario, seed)
    last = max(steps)
    for step in range(last + 1):
        if step in steps:
            yield step, {name: view.latest for name, view in obs.cameras.items()}
        if obs.ground_truth.terminal or step == last:
            return
        pose = driven_pose(simulator.road.route, step + 1, SPEED)
        obs = simulator.step(Control(0.0, 0.0, 0.0, SPEED, next_state=pose))


def kinematic_scenes(make_simulator: Callable, label: str, scenarios: dict, steps: tuple[int, ...],
                     seed: int = 1) -> Iterator[tuple[str, np.ndarray]]:
    simulator = make_simulator()
    try:
        for name, scenario in scenarios.items():
            for step, images in drive(simulator, scenario, seed, steps):
                for camera, image in images.items():
                    yield f"{label}/{name}/step{step}/{camera}", image
    finally:
        simulator.close()


def direct_scenes(count: int = 40) -> Iterator[tuple[str, np.ndarray]]:
    """Actors of every kind at random places around random ego poses, rendered by cameras directly."""
    from vladrivebench.records import Actor, EgoState
    from vladrivebench.world._camera import Camera
    from vladrivebench.world._roads import build_road

    rng = np.random.default_rng(20261202)
    scenarios = suite()
    roads = {name: build_road(scenarios[name]) for name in ("P.1", "S.3", "TL.1-red", "E.2")}
    cameras = [Camera(160, 80), Camera(64, 48, 120.0, mount_height=1.2, pitch_deg=5.0),
               Camera(101, 37, 45.0, mount_left=0.6, yaw_deg=30.0)]
    kinds = ("pedestrian", "car", "animal", "traffic_light", "stop_sign", "cone")
    for i in range(count):
        name = list(roads)[i % len(roads)]
        road = roads[name]
        s = float(rng.uniform(0.0, road.route.length))
        x, y = (float(v) for v in road.route.to_world(s, rng.uniform(-1.5, 1.5)))
        ego = EgoState(x, y, float(road.route.heading(s)) + float(rng.normal(0.0, 0.3)), 5.0)
        actors = []
        for k in range(int(rng.integers(1, 9))):
            kind = kinds[int(rng.integers(len(kinds)))]
            distance = float(rng.choice([rng.uniform(0.3, 4.0), rng.uniform(4.0, 40.0), rng.uniform(40.0, 160.0)]))
            bearing = float(rng.uniform(-1.2, 1.2)) + ego.yaw
            state = str(rng.choice(["red", "yellow", "green"])) if kind == "traffic_light" else None
            actors.append(Actor(f"a{k}", kind, ego.x + distance * math.cos(bearing),
                                ego.y + distance * math.sin(bearing), float(rng.uniform(-math.pi, math.pi)),
                                float(rng.uniform(0.3, 5.0)), float(rng.uniform(0.3, 2.5)),
                                float(rng.uniform(0.5, 4.5)), state=state))
        camera = cameras[i % len(cameras)]
        yield f"direct/{i:02d}-{name}/{camera.width}x{camera.height}", camera.render(road, ego, actors)


def scenes() -> Iterator[tuple[str, np.ndarray]]:
    """Every (scene name, image) of the contract, in a fixed order."""
    from vdb_sim_kinematic.simulator import KinematicSimulator

    everything = suite()
    yield from kinematic_scenes(KinematicSimulator, "kinematic", everything, (0, 9, 24, 45))
    picked = {name: everything[name] for name in ("P.2", "S.1", "TL.3-green", "SAFE.car")}
    for scenery in ("plain", "suburban", "urban"):
        variants = {name: with_scenery(s, scenery) for name, s in picked.items() if s.road.scenery != scenery}
        yield from kinematic_scenes(KinematicSimulator, f"kinematic-{scenery}", variants, (0, 30))
    rig = {name: everything[name] for name in ("P.1", "S.2", "TL.2-red", "E.1", "C.2")}
    yield from kinematic_scenes(lambda: KinematicSimulator(rig="alpamayo", frames=2, frame_rate_hz=2.0),
                                "alpamayo", rig, (0, 10, 20), seed=2)
    odd = {name: everything[name] for name in ("C.1", "S.3", "TL.1-green")}
    for label, options in (("97x41-hfov60", dict(width=97, height=41, hfov_deg=60.0)),
                           ("33x17-hfov150-pitch8", dict(width=33, height=17, hfov_deg=150.0, pitch_deg=8.0)),
                           ("240x64-high", dict(width=240, height=64, camera_height=2.3)),
                           ("alpamayo-odd", dict(rig="alpamayo", cameras="cross_right,front_tele", width=75,
                                                 height=29))):
        yield from kinematic_scenes(lambda options=options: KinematicSimulator(**options), label, odd, (0, 20))
    yield from direct_scenes()
    yield from sumo_scenes(everything)


def sumo_scenes(everything: dict) -> Iterator[tuple[str, np.ndarray]]:
    try:
        import libsumo  # noqa: F401
        from vdb_sim_sumo.simulator import SumoSimulator
    except ImportError:
        return
    chosen = {name: everything[name] for name in ("P.3", "S.1", "TL.3-red")}
    yield from kinematic_scenes(SumoSimulator, "sumo", chosen, (0, 8, 15))


def compute() -> dict[str, str]:
    """{scene name: image hash} for every scene."""
    hashes: dict[str, str] = {}
    for name, image in scenes():
        if name in hashes:
            raise RuntimeError(f"scene {name!r} appears twice")
        hashes[name] = image_hash(image)
    return hashes


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--write", action="store_true", help=f"write {HASHES.name} from the current renderer")
    args = parser.parse_args()
    hashes = compute()
    if args.write:
        HASHES.write_text(json.dumps(hashes, indent=0, sort_keys=True) + "\n")
        print(f"wrote {len(hashes)} scene hashes to {HASHES}")
        return 0
    expected = json.loads(HASHES.read_text())
    bad = sorted(name for name in expected.keys() | hashes.keys() if expected.get(name) != hashes.get(name))
    for name in bad:
        print(f"differs: {name}")
    print(f"{len(hashes) - len(bad)} of {len(expected)} scenes identical")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
