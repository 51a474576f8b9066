"""Episode logs: round trip, atomic publication, truncation and corruption, schema versions, PNG."""

from __future__ import annotations

import functools
import json
import os
import sys
import tempfile
import zlib
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp
from vladrivebench._engine.runner import decode_png, observation_from_step
from vladrivebench._logs import episodes as logs
from vladrivebench._logs.episodes import (
    EpisodeWriter,
    find_episodes,
    load_episodes,
    read_episode,
    read_result,
)
from vladrivebench.errors import LogError
from vladrivebench.records import Actor, Control, CoT, EgoState, GroundTruth, Observation, Trajectory

META = {"episode_id": "m__P.1__s3", "model": {"name": "m", "options": {"alpha": 0.5}},
        "scenario": {"id": "P.1", "family": "pedestrian", "group": "Pedestrian (in-lane)"}, "seed": 3}


def make_step(step: int, *, terminal: str | None = None) -> tuple:
    gt = GroundTruth(step=step, time=step * 0.1,
                     actors=(Actor("ped0", "pedestrian", 20.0, 1.0, state=None),
                             Actor("tl0", "traffic_light", 50.0, 3.0, state="red")),
                     critical_id="ped0", critical_kind="pedestrian", distance_to_critical=20.0 - step,
                     blocking=True, light_state="red", lead_gap=None, route_progress=float(step),
                     route_length=100.0, collisions=("ped0",) if terminal == "collision" else (),
                     terminal=terminal, route_ahead=((1.0, 0.0), (2.0, 0.01)))
    image = np.arange(4 * 6 * 3, dtype=np.uint8).reshape(4, 6, 3) + step
    obs = Observation(step, step * 0.1, image, EgoState(float(step), 0.5, 0.1, 6.5), "straight", gt, "P.1")
    cot = CoT("Stop for the pedestrian. ", slots={"decision": "Stop."}, spliced=step % 2 == 1)
    traj = Trajectory(np.arange(1, 4) * 0.1, np.array([[0.5, 0.0], [1.0, 0.0], [1.5, 0.01]]))
    control = Control(0.2, -0.01, 0.0, 6.4, next_state=EgoState(1.0, 2.0, 0.0, 6.4) if step == 2 else None)
    return obs, cot, traj, control, {"shadow": {"brake": step % 3 == 0, "v": np.float32(1.5)}}


def write_episode(path: Path, steps: int = 5, **kw) -> Path:
    with EpisodeWriter(path, META, **kw) as writer:
        for step in range(steps):
            writer.write_step(*make_step(step, terminal="collision" if step == steps - 1 else None))
        writer.finish({"terminal": "collision", "steps": steps})
    return path


def test_round_trip_keeps_every_field(tmp_path):
    path = write_episode(tmp_path / "ep.mcap")
    episode = read_episode(path)
    assert episode.complete and episode.result == {"terminal": "collision", "steps": 5}
    assert (episode.episode_id, episode.model, episode.scenario_id, episode.seed) == ("m__P.1__s3", "m", "P.1", 3)
    assert episode.meta["schema_version"] == logs.SCHEMA_VERSION
    assert episode.meta["scenario"]["group"] == "Pedestrian (in-lane)"
    assert [s.step for s in episode.steps] == list(range(5))
    obs, cot, traj, control, extras = make_step(2)
    record = episode.steps[2]
    assert record.time == pytest.approx(0.2)
    assert record.ego == {"x": 2.0, "y": 0.5, "yaw": 0.1, "speed": 6.5, "steer": 0.0, "length": 4.7, "width": 1.9}
    assert record.ground_truth["actors"][1] == {"actor_id": "tl0", "kind": "traffic_light", "x": 50.0, "y": 3.0,
                                                "yaw": 0.0, "length": 0.5, "width": 0.5, "height": 1.7,
                                                "speed": 0.0, "state": "red"}
    assert set(record.ground_truth) == set(GroundTruth.__dataclass_fields__)
    assert record.cot == {"text": cot.text, "slots": {"decision": "Stop."}, "spliced": False}
    assert record.trajectory == traj.to_json()
    assert record.control["next_state"]["speed"] == 6.4 and record.control["v_des"] == 6.4
    assert record.extras == {"shadow": {"brake": False, "v": 1.5}}
    assert record.command == "straight" and record.image_png is None
    assert episode.steps[-1].ground_truth["terminal"] == "collision"


def test_observation_rebuilt_from_a_logged_step_equals_the_original(tmp_path):
    path = write_episode(tmp_path / "ep.mcap", log_images=True)
    record = read_episode(path).steps[3]
    original = make_step(3)[0]
    rebuilt = observation_from_step(record, scenario_id="P.1")
    assert rebuilt == original  # images are not compared by Observation equality
    assert np.array_equal(rebuilt.image, original.image)


def test_camera_channel_only_when_asked(tmp_path):
    without = read_episode(write_episode(tmp_path / "a.mcap"))
    with_images = read_episode(write_episode(tmp_path / "b.mcap", log_images=True))
    assert all(s.image_png is None for s in without.steps)
    assert all(s.image_png.startswith(b"\x89PNG") for s in with_images.steps)
    assert (tmp_path / "b.mcap").stat().st_size > (tmp_path / "a.mcap").stat().st_size


@settings(max_examples=40, deadline=None)
@given(hnp.arrays(np.uint8, st.tuples(st.integers(1, 12), st.integers(1, 12), st.sampled_from([1, 3]))))
def test_png_round_trip(image):
    image = image[:, :, 0] if image.shape[2] == 1 else image
    data = logs.encode_png(image)
    assert np.array_equal(decode_png(data), image)
    # a real PNG: every chunk's CRC is right
    pos = 8
    while pos < len(data):
        length = int.from_bytes(data[pos:pos + 4], "big")
        body = data[pos + 4:pos + 8 + length]
        assert int.from_bytes(data[pos + 8 + length:pos + 12 + length], "big") == zlib.crc32(body)
        pos += 12 + length


def test_same_content_same_bytes(tmp_path):
    a = write_episode(tmp_path / "a.mcap", log_images=True).read_bytes()
    b = write_episode(tmp_path / "b.mcap", log_images=True).read_bytes()
    assert a == b


def test_writer_is_atomic_and_cleans_up_after_an_error(tmp_path):
    path = tmp_path / "ep.mcap"
    with pytest.raises(RuntimeError):
        with EpisodeWriter(path, META) as writer:
            writer.write_step(*make_step(0))
            assert not path.exists() and writer.partial_path.exists()
            raise RuntimeError("model crashed")
    assert list(tmp_path.iterdir()) == []


def test_unfinished_writer_leaves_only_a_partial_file(tmp_path):
    path = tmp_path / "ep.mcap"
    writer = EpisodeWriter(path, META).__enter__()
    for step in range(3):
        writer.write_step(*make_step(step))
    writer._file.flush()
    assert not path.exists()
    assert writer.partial_path.name == f"ep.mcap.{os.getpid()}.partial"
    with pytest.raises(LogError, match="truncated"):
        read_episode(writer.partial_path)
    writer.__exit__(None, None, None)


@settings(max_examples=30, deadline=None)
@given(st.floats(0.0, 1.0, exclude_max=True))
def test_truncated_logs_fail_in_one_line_or_recover_their_complete_steps(tmp_path_factory, fraction):
    tmp_path = tmp_path_factory.mktemp("trunc")
    data = reference_log(40, True)
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: int(len(data) * fraction)])
    with pytest.raises(LogError) as info:
        read_episode(cut)
    message = str(info.value)
    assert "\n" not in message and str(cut) in message
    assert read_result(cut) is None
    try:
        recovered = read_episode(cut, recover=True)
    except LogError:
        return  # cut before the episode record: nothing to recover, and said so
    assert not recovered.complete and recovered.result is None
    full = read_episode(write_episode(tmp_path / "ep.mcap", steps=40, log_images=True)).steps
    assert recovered.steps == full[: len(recovered.steps)]


@functools.cache
def reference_log(steps: int, log_images: bool) -> bytes:
    with tempfile.TemporaryDirectory() as directory:
        return write_episode(Path(directory) / "ep.mcap", steps=steps, log_images=log_images).read_bytes()


@settings(max_examples=150, deadline=None)
@given(st.floats(0.0, 1.0, exclude_max=True), st.integers(1, 255))
def test_any_corrupted_byte_is_detected(tmp_path_factory, where, flip):
    tmp_path = tmp_path_factory.mktemp("flip")
    data = bytearray(reference_log(20, False))
    data[int(where * len(data))] ^= flip
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(bytes(data))
    with pytest.raises(LogError, match="bad.mcap"):
        read_episode(bad)


def test_not_an_mcap_file(tmp_path):
    path = tmp_path / "notes.mcap"
    path.write_text("hello")
    with pytest.raises(LogError, match="truncated"):
        read_episode(path)
    with pytest.raises(LogError, match="no such file"):
        read_episode(tmp_path / "missing.mcap")


def test_mcap_without_episode_record_is_refused(tmp_path):
    from mcap.writer import Writer

    path = tmp_path / "other.mcap"
    with open(path, "wb") as handle:
        writer = Writer(handle)
        writer.start()
        writer.finish()
    with pytest.raises(LogError, match="not a VLADriveBench episode log"):
        read_episode(path)


def test_other_schema_major_version_names_both_versions(tmp_path, monkeypatch):
    monkeypatch.setattr(logs, "SCHEMA_VERSION", "2")
    path = write_episode(tmp_path / "ep.mcap")
    monkeypatch.setattr(logs, "SCHEMA_VERSION", "1")
    with pytest.raises(LogError, match=r"schema version 2.*reads version 1"):
        read_episode(path)


def test_missing_result_record(tmp_path):
    from mcap.writer import Writer

    path = tmp_path / "ep.mcap"
    with open(path, "wb") as handle:
        writer = Writer(handle)
        writer.start()
        writer.add_metadata("episode", {"schema_version": "1", "json": json.dumps(META)})
        writer.finish()
    with pytest.raises(LogError, match="incomplete"):
        read_episode(path)
    assert read_episode(path, recover=True).complete is False


def test_non_finite_values_are_refused_when_logging(tmp_path):
    obs, cot, traj, control, _ = make_step(0)
    with pytest.raises(ValueError, match="non-finite"):
        with EpisodeWriter(tmp_path / "ep.mcap", META) as writer:
            writer.write_step(obs, cot, traj, control, {"x": float("nan")})
    assert not (tmp_path / "ep.mcap").exists()


def test_find_and_load_episodes(tmp_path):
    with pytest.raises(LogError, match="no such directory"):
        find_episodes(tmp_path / "nope")
    with pytest.raises(LogError, match="no episode logs"):
        find_episodes(tmp_path)
    write_episode(tmp_path / "episodes" / "b.mcap")
    write_episode(tmp_path / "episodes" / "a.mcap")
    (tmp_path / "episodes" / "c.mcap.123.partial").write_bytes(b"junk")
    assert [p.name for p in find_episodes(tmp_path)] == ["a.mcap", "b.mcap"]
    assert [e.path.name for e in load_episodes(tmp_path)] == ["a.mcap", "b.mcap"]


@settings(max_examples=40, deadline=None)
@given(st.recursive(st.none() | st.booleans() | st.integers(-10**6, 10**6) | st.floats(allow_nan=False,
                    allow_infinity=False) | st.text(max_size=8),
                    lambda inner: st.lists(inner, max_size=3) | st.dictionaries(st.text(max_size=5), inner,
                                                                                 max_size=3),
                    max_leaves=10))
def test_extras_round_trip_any_json(tmp_path_factory, extras):
    path = tmp_path_factory.mktemp("extras") / "ep.mcap"
    obs, cot, traj, control, _ = make_step(0, terminal="timeout")
    with EpisodeWriter(path, META) as writer:
        writer.write_step(obs, cot, traj, control, {"value": extras})
        writer.finish({})
    assert read_episode(path).steps[0].extras == {"value": extras}


def test_reader_does_not_import_heavy_libraries():
    import subprocess

    code = "import vladrivebench._logs.episodes, sys; print('torch' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "False"
