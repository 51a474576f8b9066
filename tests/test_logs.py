"""Episode logs: round trip, atomic publication, truncation and corruption, schema versions, PNG, and
Foxglove (message indexes, Foxglove channels valid against their schemas, @mcap/core's indexed reader)."""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import json
import os
import shutil
import subprocess
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
from vladrivebench._logs import foxglove
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
    assert record.ego == obs.ego and isinstance(record.ego, EgoState)
    assert record.ground_truth == obs.ground_truth  # actors as Actor tuples, route_ahead as tuples
    assert record.ground_truth.actors[1] == Actor("tl0", "traffic_light", 50.0, 3.0, state="red")
    assert record.cot == CoT(cot.text, slots={"decision": "Stop."}, spliced=False)
    assert record.trajectory == traj and record.trajectory.xy.dtype == np.float64
    assert record.control == control and record.control.next_state == EgoState(1.0, 2.0, 0.0, 6.4)
    assert record.extras == {"shadow": {"brake": False, "v": 1.5}}
    assert record.command == "straight" and record.image_png is None
    assert episode.steps[-1].ground_truth.terminal == "collision"


def test_records_still_answer_the_logged_keys_of_the_dict_era(tmp_path):
    """The deprecated key access: ``step.ego["x"]`` and ``.get`` give the logged JSON values."""
    record = read_episode(write_episode(tmp_path / "ep.mcap")).steps[2]
    assert record.ego["x"] == 2.0 and record.ego.get("nope", 7) == 7
    assert record.ground_truth["actors"][1] == {"actor_id": "tl0", "kind": "traffic_light", "x": 50.0, "y": 3.0,
                                                "yaw": 0.0, "length": 0.5, "width": 0.5, "height": 1.7,
                                                "speed": 0.0, "state": "red"}
    assert record.ground_truth.get("distance_to_critical") == 18.0
    assert record.trajectory["times"] == make_step(2)[2].to_json()["times"]
    assert record.control["next_state"]["speed"] == 6.4 and record.control.get("brake") == 0.0
    assert record.cot["text"] == "Stop for the pedestrian. "
    with pytest.raises(KeyError):
        record.ego["missing"]


@pytest.mark.parametrize(("topic", "message", "complaint"), [
    ("/ego", {"x": 1.0, "y": 0.0, "yaw": 0.0}, "ego lacks 'speed'"),
    ("/ego", {"x": "1", "y": 0.0, "yaw": 0.0, "speed": 1.0}, "ego.x is '1', expected a number"),
    ("/ego", [1, 2], "ego is list, expected a JSON object"),
    ("/ground_truth", {"step": 0}, "ground_truth lacks 'time'"),
    ("/ground_truth", {"step": 0, "time": 0.0, "actors": [{"kind": "car", "x": 1, "y": 2}]},
     "ground_truth.actors\\[0\\] lacks 'actor_id'"),
    ("/ground_truth", {"step": 0, "time": 0.0, "route_ahead": [[1.0]]}, "ground_truth.route_ahead has 1 coordinates, expected 2"),
    ("/trajectory", {"times": [0.1], "xy": [[1.0, "a"]]}, "trajectory.xy is 'a', expected a number"),
    ("/control", {"throttle": 0.0, "steer": 0.0, "brake": 0.0}, "control lacks 'v_des'"),
    ("/cot", {"text": "x", "slots": {"a": 3}}, "cot.slots.a is 3, expected a string"),
    ("/extras", [1], "extras is list"),
])
def test_a_message_of_the_wrong_shape_is_one_log_error_naming_step_and_field(tmp_path, monkeypatch, topic,
                                                                            message, complaint):
    original = logs.step_messages

    def with_bad_message(*args, **kwargs):
        return {**original(*args, **kwargs), topic: message}

    monkeypatch.setattr(logs, "step_messages", with_bad_message)
    monkeypatch.setattr(logs.foxglove, "step_messages", lambda *a, **k: {})
    path = tmp_path / "bad.mcap"
    with EpisodeWriter(path, META, foxglove=False) as writer:
        writer.write_step(*make_step(0))
        writer.finish({})
    with pytest.raises(LogError, match=f"bad.mcap: step 0: {complaint}"):
        read_episode(path)


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


# -- Foxglove: every message read by @mcap/core's indexed reader and valid against its schema ---------------

JS_DIR = Path(__file__).parent / "js"


def _mcap_records(path: Path):
    from mcap.stream_reader import StreamReader

    with open(path, "rb") as handle:
        yield from StreamReader(handle, validate_crcs=True).records


def test_every_message_is_valid_against_its_json_schema(tmp_path):
    from jsonschema import Draft202012Validator
    from mcap.records import Channel, Message, Schema

    path = write_episode(tmp_path / "ep.mcap", steps=6, log_images=True)
    schemas, channels, seen = {}, {}, {}
    for record in _mcap_records(path):
        if isinstance(record, Schema):
            schema = json.loads(record.data)
            Draft202012Validator.check_schema(schema)
            schemas[record.id] = (record.name, Draft202012Validator(schema))
        elif isinstance(record, Channel):
            channels[record.id] = (record.topic, *schemas[record.schema_id])
        elif isinstance(record, Message):
            topic, name, validator = channels[record.channel_id]
            errors = [e.message for e in validator.iter_errors(json.loads(record.data))]
            assert not errors, f"{topic} ({name}) step {record.sequence}: {errors[:3]}"
            seen[topic] = seen.get(topic, 0) + 1
    assert {channels[c][0]: channels[c][1] for c in channels}.items() >= {
        "/foxglove/tf": "foxglove.FrameTransforms", "/foxglove/scene": "foxglove.SceneUpdate",
        "/foxglove/trajectory": "foxglove.PosesInFrame", "/foxglove/cot": "foxglove.Log",
        "/camera": "foxglove.CompressedImage"}.items()
    assert set(seen.values()) == {6}


def test_message_indexes_are_written_for_every_channel(tmp_path):
    from mcap.reader import make_reader

    path = write_episode(tmp_path / "ep.mcap", steps=4)
    with open(path, "rb") as handle:
        summary = make_reader(handle).get_summary()
    indexed = {channel for index in summary.chunk_indexes for channel in index.message_index_offsets}
    assert indexed == set(summary.channels) and all(i.message_index_length > 0 for i in summary.chunk_indexes)
    assert summary.statistics.message_count == 4 * len(summary.channels)


def _record_offsets(data: bytes, opcode: int) -> list[int]:
    """Offsets of the top-level records with ``opcode`` (walking opcode + u64 length framing)."""
    offsets, position = [], 8
    while position + 9 <= len(data) - 8:
        length = int.from_bytes(data[position + 1:position + 9], "little")
        if data[position] == opcode:
            offsets.append(position)
        position += 9 + length
    return offsets


@pytest.mark.parametrize("inside", [9, 12, 20, 30])
def test_a_flip_inside_a_message_index_is_detected(tmp_path, inside):
    path = write_episode(tmp_path / "ep.mcap", steps=4)
    data = bytearray(path.read_bytes())
    indexes = _record_offsets(bytes(data), 0x07)
    assert indexes, "the log holds message index records"
    data[indexes[len(indexes) // 2] + inside] ^= 0x01
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(bytes(data))
    with pytest.raises(logs.LogError, match="bad.mcap"):
        read_episode(bad)


def test_scene_shows_road_ego_actors_and_the_light_colour():
    obs, cot, traj, control, _ = make_step(2)
    update = foxglove.scene_update(obs, 200_000_000)
    ids = [e["id"] for e in update["entities"]]
    assert ids == ["road", "ego", "actor/ped0", "actor/tl0"]
    light = update["entities"][3]["cubes"][0]["color"]
    assert (light["r"], light["g"], light["b"]) == (1.0, 0.0, 0.0)  # the red light drawn red
    assert update["deletions"][0]["type"] == 1  # everything of the previous step goes first
    road = update["entities"][0]["lines"][0]["points"]
    assert road[0]["x"] == pytest.approx(obs.ego.to_world_frame(1.0, 0.0)[0], abs=1e-3)
    poses = foxglove.poses_in_frame(traj, 0)["poses"]
    assert [p["position"]["x"] for p in poses] == [0.5, 1.0, 1.5]
    assert foxglove.cot_log(cot, 0)["message"] == "[decision] Stop."


def test_logs_without_foxglove_channels_and_of_schema_version_1_still_read(tmp_path, monkeypatch):
    monkeypatch.setattr(logs, "SCHEMA_VERSION", "1")
    path = write_episode(tmp_path / "old.mcap", foxglove=False)
    monkeypatch.setattr(logs, "SCHEMA_VERSION", "1.1")
    episode = read_episode(path)
    assert episode.meta["schema_version"] == "1" and len(episode.steps) == 5


def test_foxglove_channels_do_not_change_what_readers_see(tmp_path):
    plain = read_episode(write_episode(tmp_path / "a.mcap", foxglove=False))
    full = read_episode(write_episode(tmp_path / "b.mcap"))
    assert plain.steps == full.steps and plain.result == full.result


def test_layout_names_channels_the_writer_writes():
    from importlib.resources import files

    layout = json.loads(files("vladrivebench._logs").joinpath("foxglove_layout.json").read_text("utf-8"))
    text = json.dumps(layout)
    for topic in (*foxglove.FOXGLOVE_CHANNELS, foxglove.CAMERA_CHANNEL):
        assert f'"{topic}' in text, topic
    assert set(layout) >= {"configById", "layout"}


# -- @mcap/core under Node --------------------------------------------------------------------------
@pytest.fixture(scope="session")
def mcap_js(tmp_path_factory) -> Path:
    """tests/js installed with `npm ci` once per package-lock into a cache directory ($VDB_JS_CACHE or
    ~/.cache/vladrivebench); skipped only when Node.js or npm is not installed."""
    npm, node = shutil.which("npm"), shutil.which("node")
    if npm is None or node is None:
        pytest.skip("npm/node not installed: the @mcap/core reader test needs Node.js and npm")
    lock = (JS_DIR / "package-lock.json").read_bytes()
    root = Path(os.environ.get("VDB_JS_CACHE") or Path.home() / ".cache" / "vladrivebench")
    cache = root / f"js-{hashlib.sha256(lock).hexdigest()[:16]}"
    if not (cache / "node_modules" / ".ok").exists():
        staging = tmp_path_factory.mktemp("npm")
        for name in ("package.json", "package-lock.json", "read_indexed.mjs"):
            shutil.copy(JS_DIR / name, staging / name)
        done = subprocess.run([npm, "ci", "--no-audit", "--no-fund", "--loglevel=error"], cwd=staging,
                              capture_output=True, text=True, timeout=600)
        assert done.returncode == 0, f"npm ci in tests/js failed (network to the npm registry?): {done.stderr}"
        (staging / "node_modules" / ".ok").write_text("ok")
        cache.parent.mkdir(parents=True, exist_ok=True)
        shutil.rmtree(cache, ignore_errors=True)
        shutil.copytree(staging, cache)
    shutil.copy(JS_DIR / "read_indexed.mjs", cache / "read_indexed.mjs")
    return cache


def read_with_mcap_js(cache: Path, *paths: Path) -> list[dict]:
    done = subprocess.run([shutil.which("node"), str(cache / "read_indexed.mjs"), *map(str, paths)],
                          capture_output=True, text=True, timeout=300)
    return [json.loads(line) for line in done.stdout.splitlines() if line.strip()] or [{"fatal": done.stderr}]


def test_mcap_indexed_reader_reads_every_message_of_a_fresh_episode(mcap_js, tmp_path):
    paths = [write_episode(tmp_path / "plain.mcap", steps=12),
             write_episode(tmp_path / "images.mcap", steps=12, log_images=True)]
    for report, path in zip(read_with_mcap_js(mcap_js, *paths), paths, strict=True):
        assert "fatal" not in report, report
        assert report["errors"] == [], report["errors"]
        channels = len(logs.STEP_CHANNELS) + len(foxglove.FOXGLOVE_CHANNELS) + (path.name == "images.mcap")
        assert report["counts"] == {topic: 12 for topic in report["schemas"]} and len(report["counts"]) == channels
        assert sum(report["counts"].values()) == report["messageCount"]
        assert report["metadata"] == ["episode", "result"]


def test_mcap_indexed_reader_reads_a_run_of_the_real_simulator(mcap_js, tmp_path):
    from vladrivebench._cli.main import main

    out = tmp_path / "run"
    assert main(["run", "--model", "scripted", "--scenarios", "TL.1-red", "--seeds", "1", "--log-images",
                 "--out", str(out)]) in (0, None)
    paths = sorted(out.rglob("*.mcap"))
    reports = read_with_mcap_js(mcap_js, *paths)
    assert all("fatal" not in r and r["errors"] == [] for r in reports), reports
    scene_steps = reports[0]["counts"]["/foxglove/scene"]
    assert scene_steps == len(read_episode(paths[0]).steps) > 0


def test_writer_can_leave_the_foxglove_channels_out(tmp_path):
    with EpisodeWriter(tmp_path / "ep.mcap", META, foxglove=False) as writer:
        writer.write_step(*make_step(0, terminal="timeout"))
        writer.finish({})
    topics = {r.topic for r in _mcap_records(tmp_path / "ep.mcap") if type(r).__name__ == "Channel"}
    assert topics == set(logs.STEP_CHANNELS)


# -- typed reads: logged JSON → records ------------------------------------------------------------------
_finite = st.floats(-1e6, 1e6, allow_nan=False, allow_infinity=False)
_name = st.text(min_size=1, max_size=6)
_actors = st.builds(Actor, actor_id=_name, kind=st.sampled_from(["pedestrian", "car", "traffic_light"]),
                    x=_finite, y=_finite, yaw=_finite, length=_finite, width=_finite, height=_finite,
                    speed=_finite, state=st.none() | st.sampled_from(["red", "green"]))
_truths = st.builds(GroundTruth, step=st.integers(0, 10**6), time=_finite,
                    actors=st.lists(_actors, max_size=3).map(tuple),
                    critical_id=st.none() | _name, critical_kind=st.none() | _name,
                    distance_to_critical=st.none() | _finite, blocking=st.booleans(),
                    light_state=st.none() | st.sampled_from(["red", "yellow", "green"]),
                    lead_gap=st.none() | _finite, lead_speed=st.none() | _finite, route_progress=_finite,
                    route_length=_finite, collisions=st.lists(_name, max_size=2).map(tuple),
                    violations=st.lists(_name, max_size=2).map(tuple), terminal=st.none() | _name,
                    route_ahead=st.lists(st.tuples(_finite, _finite), max_size=4).map(tuple))
_egos = st.builds(EgoState, x=_finite, y=_finite, yaw=_finite, speed=_finite, steer=_finite, length=_finite,
                  width=_finite)


@settings(max_examples=80, deadline=None)
@given(truth=_truths, ego=_egos, next_state=st.none() | _egos, spliced=st.booleans(),
       slots=st.dictionaries(_name, st.text(max_size=8), max_size=3), text=st.text(max_size=20),
       times=st.lists(st.floats(0.01, 10), min_size=1, max_size=4))
def test_every_logged_record_reads_back_equal(truth, ego, next_state, spliced, slots, text, times):
    from vladrivebench._logs import decode

    obs = Observation(truth.step, truth.time, np.zeros((1, 1, 3), np.uint8), ego, "left", truth)
    cot = CoT(text, slots=slots, spliced=spliced)
    trajectory = Trajectory(np.array(times), np.array([[t, -t] for t in times]))
    control = Control(0.1, 0.2, 0.3, 0.4, next_state=next_state)
    logged = json.loads(json.dumps(logs.step_messages(obs, cot, trajectory, control), default=logs._json_default))
    assert decode.ego_from_json(logged["/ego"]) == ego
    assert decode.ground_truth_from_json(logged["/ground_truth"]) == truth
    assert decode.cot_from_json(logged["/cot"]) == cot
    assert decode.trajectory_from_json(logged["/trajectory"]) == trajectory
    assert decode.control_from_json(logged["/control"]) == control
    assert truth["actors"] == [dataclasses.asdict(a) for a in truth.actors]  # the deprecated key access
