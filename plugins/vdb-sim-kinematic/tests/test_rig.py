"""The kinematic simulator's camera rig: options, cameras and history in observations, pose history, route
text and bad rig options (on the command line too); ``--log-images`` is tested in the core's
tests/test_logs_rig.py."""

from __future__ import annotations

import numpy as np
import pytest
import vdb_model_scripted.plugin
from kinematic_driving import drive
from vdb_sim_kinematic import plugin
from vdb_sim_kinematic.simulator import KinematicSimulator
from vladrivebench import ConfigError
from vladrivebench.testing import Registry, core_plugin, isolated_registry, run_cli
from vladrivebench.world import load_suite


@pytest.fixture(scope="module")
def suite():
    return load_suite(Registry(plugins=[core_plugin()], entry_points=False))


def steps(sim, scenario, count):
    obs = sim.reset(scenario, 0)
    out = [obs]
    for _ in range(count):
        obs = sim.step(drive(obs))
        out.append(obs)
    return out


def test_the_default_observation_carries_the_front_camera_poses_and_route_text(suite):
    history = steps(KinematicSimulator(width=32, height=16), suite["TL.1-red"], 20)
    obs = history[-1]
    assert list(obs.cameras) == ["front"] and obs.cameras["front"].latest is obs.image
    assert obs.cameras["front"].times == (obs.time,) and obs.image.shape == (16, 32, 3)
    assert obs.pose_history.states == tuple(o.ego for o in history[-16:])
    assert obs.pose_history.times == tuple(o.time for o in history[-16:])
    assert obs.route_text.startswith("In ") and obs.route_text.endswith("go straight at the junction.")


def test_the_alpamayo_rig_at_its_own_resolution(suite):
    sim = plugin.make_simulator(rig="alpamayo", frames=4)
    obs = steps(sim, suite["C.1"], 4)[-1]
    assert list(obs.cameras) == ["front_wide", "front_tele", "cross_left", "cross_right"]
    for view in obs.cameras.values():
        assert len(view.frames) == 4 and view.times == pytest.approx((0.1, 0.2, 0.3, 0.4))
        assert all(frame.shape == (320, 576, 3) and frame.dtype == np.uint8 for frame in view.frames)
    assert obs.image is obs.cameras["front_wide"].latest


def test_a_slower_frame_rate_keeps_older_frames_and_a_camera_subset(suite):
    sim = plugin.make_simulator(rig="alpamayo", cameras="cross_left,front_tele", width=24, height=16, frames=3,
                                frame_rate_hz=2.5)
    history = steps(sim, suite["P.1"], 9)
    views = history[-1].cameras
    assert list(views) == ["cross_left", "front_tele"]
    assert views["front_tele"].times == pytest.approx((0.0, 0.4, 0.8))
    assert history[-1].image is views["cross_left"].latest
    assert history[-2].cameras["front_tele"].frames[-1] is views["front_tele"].frames[-1]  # step 8, reused


def test_render_false_gives_blank_frames_for_every_camera(suite):
    obs = KinematicSimulator(rig="alpamayo", width=16, height=8, render=False).reset(suite["C.1"], 0)
    assert all(view.latest.shape == (8, 16, 3) and not view.latest.any() for view in obs.cameras.values())


@pytest.mark.parametrize("options,needle", [
    ({"rig": "bogus"}, "option rig must be one of alpamayo, front, got 'bogus'"),
    ({"rig": "alpamayo", "cameras": "rear"}, "option cameras must be camera names of rig 'alpamayo'"),
    ({"frames": 0}, "option frames must be a whole number between 1 and 16"),
    ({"frame_rate_hz": 4}, "option frame_rate_hz must be 10 Hz divided by a whole number"),
    ({"poses": 500}, "option poses must be a whole number between 0 and 100"),
    ({"rig": "alpamayo", "width": 4}, "option width must be a whole number between 8 and 4096, got 4"),
])
def test_bad_rig_options_are_one_line_config_errors(options, needle):
    with pytest.raises(ConfigError) as info:
        plugin.make_simulator(**options)
    assert needle in str(info.value) and "\n" not in str(info.value)


PLUGINS = (core_plugin(), ("kinematic", plugin), ("scripted", vdb_model_scripted.plugin))


def test_vdb_run_with_an_unknown_rig_is_one_line_and_exit_2(tmp_path, capsys):
    with isolated_registry(*PLUGINS):
        code = run_cli(["run", "--model", "scripted", "--sim-opt", "rig=bogus", "--scenarios", "P.1",
                        "--seeds", "1", "--out", str(tmp_path / "run"), "--quiet"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1
    assert err[0] == "vdb: error: simulator 'kinematic': option rig must be one of alpamayo, front, got 'bogus'"
