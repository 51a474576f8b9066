"""``--log-images`` with a camera rig: every camera of a multi-camera rig on its own ``/camera/<name>``
channel on the steps its frames are taken, the main image on ``/camera`` as before, the default rig
unchanged."""

from __future__ import annotations

import numpy as np
import vdb_model_scripted.plugin
from vdb_sim_kinematic import plugin
from vladrivebench import CameraSpec, CameraView, EgoState, GroundTruth, Observation
from vladrivebench._engine.runner import decode_png
from vladrivebench._logs.episodes import EpisodeWriter, camera_images, read_episode
from vladrivebench.records import Control, CoT, Trajectory
from vladrivebench.testing import core_plugin, isolated_registry, run_cli

PLUGINS = (core_plugin(), ("kinematic", plugin), ("scripted", vdb_model_scripted.plugin))


def rig_observation(step: int) -> Observation:
    def view(name, shade, times):
        frames = tuple(np.full((4, 6, 3), shade + i, np.uint8) for i in range(len(times)))
        return CameraView(CameraSpec(name, 6, 4), frames, times)

    time = round(step * 0.1, 10)
    taken = (time,) if step % 2 == 0 else (round(time - 0.1, 10),)
    cameras = {"wide": view("wide", 10 * step, taken), "left": view("left", 100 + 10 * step, taken)}
    return Observation(step, time, cameras["wide"].latest, EgoState(step, 0.0, 0.0, 1.0), "follow_lane",
                       GroundTruth(step, time), cameras=cameras)


def test_camera_images_lists_the_main_image_and_each_new_rig_frame():
    obs = rig_observation(2)
    assert [(t, f, time) for t, f, time, _ in camera_images(obs)] == [
        ("/camera", "front_camera", 0.2), ("/camera/wide", "wide", 0.2), ("/camera/left", "left", 0.2)]
    assert [t for t, *_ in camera_images(rig_observation(3))] == ["/camera"]  # frames of step 2, reused


def test_the_writer_logs_each_camera_on_its_channel_and_reads_them_back(tmp_path):
    trajectory = Trajectory(np.array([0.1]), np.array([[0.1, 0.0]]))
    with EpisodeWriter(tmp_path / "ep.mcap", {"episode_id": "e"}, log_images=True) as writer:
        for step in range(4):
            writer.write_step(rig_observation(step), CoT(""), trajectory, Control(0, 0, 0, 0))
        writer.finish({"steps": 4})
    episode = read_episode(tmp_path / "ep.mcap")
    assert [sorted(s.camera_pngs) for s in episode.steps] == [["left", "wide"], [], ["left", "wide"], []]
    assert np.array_equal(decode_png(episode.steps[2].camera_pngs["left"]), rig_observation(2).cameras["left"].latest)
    assert all(s.image_png is not None for s in episode.steps)


def test_log_images_writes_every_camera_of_the_rig(tmp_path):
    with isolated_registry(*PLUGINS):
        code = run_cli(["run", "--model", "scripted", "--scenarios", "C.1", "--seeds", "1", "--out",
                        str(tmp_path), "--quiet", "--log-images", "--sim-opt", "rig=alpamayo", "--sim-opt",
                        "width=24", "--sim-opt", "height=16", "--sim-opt", "frame_rate_hz=5"])
    assert code == 0
    episode = read_episode(tmp_path / "episodes" / "scripted__C.1__s0.mcap")
    names = {"front_wide", "front_tele", "cross_left", "cross_right"}
    assert all(s.image_png is not None for s in episode.steps)
    assert all(set(s.camera_pngs) == (names if s.step % 2 == 0 else set()) for s in episode.steps)
    first = episode.steps[0]
    assert first.camera_pngs["front_wide"] == first.image_png  # the main camera is also on /camera
    assert len(set(first.camera_pngs.values())) == 4


def test_log_images_of_the_default_rig_has_only_the_camera_channel(tmp_path):
    with isolated_registry(*PLUGINS):
        assert run_cli(["run", "--model", "scripted", "--scenarios", "P.1", "--seeds", "1", "--out", str(tmp_path),
                        "--quiet", "--log-images", "--sim-opt", "width=16", "--sim-opt", "height=8"]) == 0
    episode = read_episode(tmp_path / "episodes" / "scripted__P.1__s0.mcap")
    assert all(s.image_png is not None and s.camera_pngs == {} for s in episode.steps)
