"""Episode logs: one MCAP file per episode, the single source of truth for every analysis.

Layout of a log (schema version ``"1.1"``, every message JSON-encoded, one message per channel per step,
``log_time`` = simulated time in nanoseconds, ``sequence`` = step number):

==================  ===========================================================================
``/ego``            the ego state (fields of :class:`~vladrivebench.records.EgoState`)
``/ground_truth``   ``dataclasses.asdict(GroundTruth)`` (actors as dicts, tuples as lists)
``/cot``            ``{"text", "slots", "spliced"}``
``/trajectory``     ``{"times", "xy"}`` (ego frame at the moment of prediction)
``/control``        ``{"throttle", "steer", "brake", "v_des", "next_state"}``
``/extras``         whatever the step policy returned as extras (``{}`` by default)
``/command``        ``{"command"}``: the navigation command the model was given
``/camera``         optional (``log_images``): ``{"timestamp", "frame_id", "format": "png", "data"}``
                    with base64 PNG data (foxglove ``CompressedImage`` layout): the observation's
                    ``image`` (the rig's main camera), every step
``/camera/<name>``  optional (``log_images``, rigs of two or more cameras): the same layout for each
                    camera of ``Observation.cameras``, its newest frame, on the steps it is taken
                    (``timestamp`` = the frame's time; ``frame_id`` = the camera's name)
``/foxglove/*``     for players (``foxglove=True``, the default): frames, the scene, the trajectory
                    and the CoT as Foxglove messages (see :mod:`vladrivebench._logs.foxglove`)
==================  ===========================================================================

Reading gives typed steps: :class:`StepRecord` holds the public records of :mod:`vladrivebench.records`.

Indexes: the summary holds every MCAP index (chunk, message, metadata, statistics), so indexed readers
such as Foxglove's ``McapIndexedReader`` play a log. Damage is detected without trusting any index: chunk
CRCs, the data-section CRC (which covers the message indexes, the only records without a CRC of their
own) and the summary CRC; the reader reads the data section in order.

Metadata records: ``episode`` (written first: ``{"schema_version", "json"}`` where ``json`` holds the
episode description — ids, components and their options, scenario spec, seed, run configuration,
versions) and ``result`` (written last: ``{"json"}`` with terminal, steps, collisions, violations, route
completion, mean speed, duration). No wall-clock time is written, so the same run gives the same bytes.

Crash safety: a writer fills ``NAME.mcap.<pid>.partial`` beside the final path, fsyncs it and renames it
with :func:`os.replace`, so ``NAME.mcap`` is complete or absent.
"""

from __future__ import annotations

import base64
import dataclasses
import io
import json
import os
import struct
import zlib
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from vladrivebench._logs import decode, foxglove
from vladrivebench.errors import LogError
from vladrivebench.records import Control, CoT, EgoState, GroundTruth, Observation, Trajectory

SCHEMA_VERSION = "1.1"
"""Major.minor: readers accept every minor version of their major (1.1 added the message indexes and the
Foxglove channels, which a 1.0 reader ignores)."""
PARTIAL_SUFFIX = ".partial"
STEP_CHANNELS = ("/ego", "/ground_truth", "/cot", "/trajectory", "/control", "/extras", "/command")
CAMERA_CHANNEL = foxglove.CAMERA_CHANNEL
PROFILE = "vladrivebench"
_NS = 1_000_000_000
_MAGIC = b"\x89MCAP0\r\n"

_FIELD_OF_CHANNEL = {
    "/ego": "ego",
    "/ground_truth": "ground_truth",
    "/cot": "cot",
    "/trajectory": "trajectory",
    "/control": "control",
    "/extras": "extras",
}

_SCHEMAS: dict[str, dict[str, Any]] = {
    "/ego": {
        "title": "vdb.EgoState",
        "type": "object",
        "properties": {k: {"type": "number"} for k in ("x", "y", "yaw", "speed", "steer", "length", "width")},
    },
    "/ground_truth": {
        "title": "vdb.GroundTruth",
        "type": "object",
        "properties": {
            "step": {"type": "integer"},
            "time": {"type": "number"},
            "actors": {"type": "array", "items": {"type": "object"}},
            "critical_id": {"type": ["string", "null"]},
            "critical_kind": {"type": ["string", "null"]},
            "distance_to_critical": {"type": ["number", "null"]},
            "blocking": {"type": "boolean"},
            "light_state": {"type": ["string", "null"]},
            "collisions": {"type": "array", "items": {"type": "string"}},
            "violations": {"type": "array", "items": {"type": "string"}},
            "terminal": {"type": ["string", "null"]},
        },
    },
    "/cot": {
        "title": "vdb.CoT",
        "type": "object",
        "properties": {
            "text": {"type": "string"},
            "slots": {"type": "object", "additionalProperties": {"type": "string"}},
            "spliced": {"type": "boolean"},
        },
    },
    "/trajectory": {
        "title": "vdb.Trajectory",
        "type": "object",
        "properties": {
            "times": {"type": "array", "items": {"type": "number"}},
            "xy": {"type": "array", "items": {"type": "array", "items": {"type": "number"}}},
        },
    },
    "/control": {
        "title": "vdb.Control",
        "type": "object",
        "properties": {
            "throttle": {"type": "number"},
            "steer": {"type": "number"},
            "brake": {"type": "number"},
            "v_des": {"type": "number"},
            "next_state": {"type": ["object", "null"]},
        },
    },
    "/extras": {"title": "vdb.Extras", "type": "object"},
    "/command": {"title": "vdb.Command", "type": "object", "properties": {"command": {"type": "string"}}},
}


# -- records ----------------------------------------------------------------------------------------
@dataclass(frozen=True)
class StepRecord:
    """One logged step, as the records it was written from.

    ``ego``, ``ground_truth`` (actors as :class:`~vladrivebench.records.Actor` tuples), ``cot`` (text, slots,
    spliced; no model state), ``trajectory`` (float arrays) and ``control`` are the public records of
    :mod:`vladrivebench.records`; ``extras`` is the free-form JSON the step policy returned; ``command`` the
    navigation command; ``image_png`` the logged ``/camera`` PNG and ``camera_pngs`` the rig cameras' frames
    taken at this step, by camera name (``None`` / empty unless the run logged images).
    """

    step: int
    time: float
    ego: EgoState
    ground_truth: GroundTruth
    cot: CoT
    trajectory: Trajectory
    control: Control
    extras: dict
    command: str = ""
    image_png: bytes | None = None
    camera_pngs: dict[str, bytes] = dataclasses.field(default_factory=dict)


@dataclass(frozen=True)
class Episode:
    """A read episode log. ``complete`` is False for a truncated log read with ``recover=True``."""

    path: Path
    meta: dict
    steps: list[StepRecord]
    result: dict | None
    complete: bool

    @property
    def episode_id(self) -> str:
        return str(self.meta["episode_id"])

    @property
    def model(self) -> str:
        return str(self.meta["model"]["name"])

    @property
    def scenario_id(self) -> str:
        return str(self.meta["scenario"]["id"])

    @property
    def seed(self) -> int:
        return int(self.meta["seed"])


# -- JSON encoding -----------------------------------------------------------------------------------
def to_jsonable(value: Any) -> Any:
    """Plain JSON types for records, numpy scalars/arrays, tuples and mappings (NaN is refused)."""
    return json.loads(_dumps(value))


def _json_default(value: Any) -> Any:
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return _shallow_fields(value)
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, Mapping):
        return dict(value)
    if isinstance(value, (set, frozenset)):
        return sorted(value)
    if isinstance(value, bytes):
        return base64.b64encode(value).decode("ascii")
    raise TypeError(f"cannot log a value of type {type(value).__name__}")


def _shallow_fields(record: Any) -> dict[str, Any]:
    return {f.name: getattr(record, f.name) for f in dataclasses.fields(record)}


_ENCODER = json.JSONEncoder(separators=(",", ":"), allow_nan=False, default=_json_default)
"""What ``json.dumps`` with these options builds on every call, built once (it keeps no state between calls)."""


def _dumps(value: Any) -> bytes:
    try:
        text = _ENCODER.encode(value)
    except ValueError as exc:  # NaN or infinity somewhere
        raise ValueError(f"cannot log a non-finite number ({exc})") from None
    return text.encode("utf-8")


def encode_png(image: np.ndarray) -> bytes:
    """A deterministic PNG (8-bit RGB or grey, no filtering, zlib level 6) of a uint8 image."""
    array = np.ascontiguousarray(np.asarray(image))
    if array.dtype != np.uint8 or array.ndim not in (2, 3) or (array.ndim == 3 and array.shape[2] != 3):
        raise ValueError(f"expected a uint8 (H, W) or (H, W, 3) image, got {array.dtype} {array.shape}")
    height, width = array.shape[:2]
    colour_type = 2 if array.ndim == 3 else 0
    rows = array.reshape(height, -1)
    raw = np.hstack([np.zeros((height, 1), np.uint8), rows]).tobytes()

    def chunk(tag: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + tag + data + struct.pack(">I", zlib.crc32(tag + data))

    header = struct.pack(">IIBBBBB", width, height, 8, colour_type, 0, 0, 0)
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header) + chunk(b"IDAT", zlib.compress(raw, 6)) + chunk(b"IEND", b"")


def step_messages(obs: Observation, cot: CoT, trajectory: Trajectory, control: Control,
                  extras: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """The JSON-ready message of every step channel for one step."""
    return {
        "/ego": _shallow_fields(obs.ego),
        "/ground_truth": _shallow_fields(obs.ground_truth),
        "/cot": {"text": cot.text, "slots": dict(cot.slots), "spliced": bool(cot.spliced)},
        "/trajectory": trajectory.to_json(),
        "/control": {
            "throttle": control.throttle,
            "steer": control.steer,
            "brake": control.brake,
            "v_des": control.v_des,
            "next_state": _shallow_fields(control.next_state) if control.next_state else None,
        },
        "/extras": dict(extras or {}),
        "/command": {"command": obs.command},
    }


# -- writing -----------------------------------------------------------------------------------------
class EpisodeWriter:
    """Writes one episode log atomically.

    ``foxglove`` adds the Foxglove channels (:mod:`vladrivebench._logs.foxglove`); ``message_indexes=False``
    leaves the message-index records out (a smaller file that Foxglove's indexed reader cannot play; for
    measuring their cost). Use as a context manager: ``write_step`` once per step, then ``finish(result)``, which writes the
    ``result`` record, fsyncs and renames the partial file to ``path``. Leaving the block without
    ``finish`` (an exception) removes the partial file: the episode log then does not exist.

    Example::

        with EpisodeWriter(out / "ep.mcap", meta) as writer:
            writer.write_step(obs, cot, trajectory, control, extras)
            writer.finish({"terminal": "route_complete", "steps": 1})
    """

    def __init__(self, path: Path | str, meta: Mapping[str, Any], *, log_images: bool = False,
                 foxglove: bool = True, message_indexes: bool = True, chunk_size: int = 64 * 1024):
        self.path = Path(path)
        self.meta = dict(meta)
        self.log_images = log_images
        self.foxglove = foxglove
        self.message_indexes = message_indexes
        self.chunk_size = chunk_size
        self.partial_path = self.path.with_name(f"{self.path.name}.{os.getpid()}{PARTIAL_SUFFIX}")
        self._file = None
        self._writer = None
        self._channels: dict[str, int] = {}
        self.steps_written = 0
        self.finished = False

    def __enter__(self) -> EpisodeWriter:
        from mcap.writer import CompressionType, IndexType, Writer

        from vladrivebench import __version__

        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._file = open(self.partial_path, "wb")  # noqa: SIM115 - closed in finish/__exit__
        _lock(self._file)  # held until closed: tells a resumed sweep this partial is still being written
        # Every index, message indexes included: players (Foxglove's indexed reader) need them. Message
        # indexes carry no CRC of their own; the data-section CRC in the DataEnd record covers them.
        index_types = IndexType.ALL if self.message_indexes else IndexType.ALL & ~IndexType.MESSAGE
        self._writer = Writer(self._file, chunk_size=self.chunk_size, compression=CompressionType.ZSTD,
                              enable_data_crcs=True, index_types=index_types)
        self._writer.start(profile=PROFILE, library=f"vladrivebench/{__version__}")
        topics = STEP_CHANNELS + ((CAMERA_CHANNEL,) if self.log_images else ())
        topics += foxglove.FOXGLOVE_CHANNELS if self.foxglove else ()
        for topic in topics:
            schema = _SCHEMAS.get(topic) or foxglove.SCHEMAS[topic]
            schema_id = self._writer.register_schema(
                name=schema["title"], encoding="jsonschema", data=json.dumps(schema).encode("utf-8")
            )
            self._channels[topic] = self._writer.register_channel(
                topic=topic, message_encoding="json", schema_id=schema_id
            )
        meta = {"schema_version": SCHEMA_VERSION, **self.meta}
        self._writer.add_metadata("episode", {"schema_version": SCHEMA_VERSION, "json": _dumps(meta).decode()})
        return self

    def write_step(self, obs: Observation, cot: CoT, trajectory: Trajectory, control: Control,
                   extras: Mapping[str, Any] | None = None) -> None:
        """Log one step: the observation's ego and ground truth, the CoT, trajectory, control and extras."""
        messages = {topic: _dumps(msg) for topic, msg in step_messages(obs, cot, trajectory, control,
                                                                       extras).items()}
        time_ns = int(round(obs.time * _NS))
        if self.log_images:
            for topic, frame_id, time, image in camera_images(obs):
                messages[topic] = _dumps(_camera_message(time, frame_id, image))
        if self.foxglove:
            messages.update((topic, _dumps(msg)) for topic, msg in
                            foxglove.step_messages(obs, cot, trajectory, time_ns).items())
        for topic, data in messages.items():
            self._writer.add_message(self._channel(topic), log_time=time_ns, data=data,
                                     publish_time=time_ns, sequence=obs.step)
        self.steps_written += 1

    def _channel(self, topic: str) -> int:
        """The channel id of ``topic``; a rig camera's channel is registered on its first message."""
        if topic not in self._channels:
            schema = _SCHEMAS.get(CAMERA_CHANNEL) or foxglove.SCHEMAS[CAMERA_CHANNEL]
            schema_id = self._writer.register_schema(
                name=schema["title"], encoding="jsonschema", data=json.dumps(schema).encode("utf-8")
            )
            self._channels[topic] = self._writer.register_channel(
                topic=topic, message_encoding="json", schema_id=schema_id
            )
        return self._channels[topic]

    def finish(self, result: Mapping[str, Any]) -> Path:
        """Write the result record and atomically publish the log at ``path``."""
        self._writer.add_metadata("result", {"json": _dumps(result).decode()})
        self._writer.finish()
        self._file.flush()
        os.fsync(self._file.fileno())
        self._file.close()
        os.replace(self.partial_path, self.path)
        _fsync_directory(self.path.parent)
        self.finished = True
        return self.path

    def __exit__(self, exc_type, exc, tb) -> None:
        if self.finished:
            return
        if self._file is not None and not self._file.closed:
            self._file.close()
        self.partial_path.unlink(missing_ok=True)


def camera_images(obs: Observation) -> list[tuple[str, str, float, np.ndarray]]:
    """``(topic, frame_id, time, image)`` of every camera image to log for ``obs``: ``obs.image`` on
    ``/camera``, and for a rig of two or more cameras each camera's newest frame on ``/camera/<name>`` on
    the step it was taken (a rig below the step rate reuses frames; they are logged once)."""
    images = [(CAMERA_CHANNEL, foxglove.CAMERA_FRAME, obs.time, obs.image)]
    if len(obs.cameras) > 1:
        images += [(f"{CAMERA_CHANNEL}/{name}", name, view.times[-1], view.latest)
                   for name, view in obs.cameras.items() if view.times and view.times[-1] == obs.time]
    return images


def _camera_message(time: float, frame_id: str, image: np.ndarray) -> dict[str, Any]:
    return {
        "timestamp": foxglove.stamp(int(round(time * _NS))),
        "frame_id": frame_id,
        "format": "png",
        "data": base64.b64encode(encode_png(image)).decode("ascii"),
    }


def _lock(handle: Any) -> None:
    try:
        import fcntl
    except ImportError:  # not POSIX: partial_in_use falls back to the writer's pid
        return
    fcntl.flock(handle.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)


def partial_in_use(path: Path | str) -> bool:
    """Whether a live :class:`EpisodeWriter` is still writing the partial log ``path``.

    The writer holds an exclusive ``flock`` on it; the kernel releases it when the writer's process
    dies, however it dies — so a partial nobody holds is left over from a killed run.
    """
    try:
        import fcntl
    except ImportError:
        return _pid_alive(Path(path).name[: -len(PARTIAL_SUFFIX)].rsplit(".", 1)[-1])
    try:
        with open(path, "rb") as handle:
            try:
                fcntl.flock(handle.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                return True
            fcntl.flock(handle.fileno(), fcntl.LOCK_UN)
            return False
    except FileNotFoundError:
        return False


def _pid_alive(pid: str) -> bool:
    if not pid.isdigit():
        return False
    try:
        os.kill(int(pid), 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def _fsync_directory(directory: Path) -> None:
    try:
        fd = os.open(directory, os.O_RDONLY)
    except OSError:  # not supported on this platform
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


# -- reading -----------------------------------------------------------------------------------------
def read_episode(path: Path | str, *, recover: bool = False) -> Episode:
    """Read an episode log.

    A corrupt, truncated or incompatible file raises :class:`LogError` naming the file. With
    ``recover=True`` a truncated file (e.g. a ``.partial`` left by a killed run) yields its complete
    steps, ``result=None`` and ``complete=False``.
    """
    from mcap.records import Channel, DataEnd, Footer, Message, Metadata
    from mcap.stream_reader import StreamReader

    path = Path(path)
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        raise LogError(f"episode log {path}: no such file") from None
    except OSError as exc:
        raise LogError(f"episode log {path}: cannot read ({exc.strerror})") from None
    topics: dict[int, str] = {}
    by_step: dict[int, dict[str, Any]] = {}
    meta: dict | None = None
    result: dict | None = None
    complete = data_end = False
    try:
        for record in StreamReader(io.BytesIO(data), validate_crcs=True).records:
            if isinstance(record, Channel):
                topics[record.id] = record.topic
            elif isinstance(record, Message):
                _collect_message(by_step, topics, record)
            elif isinstance(record, Metadata):
                if record.name == "episode":
                    meta = _episode_meta(path, record.metadata)
                elif record.name == "result":
                    result = json.loads(record.metadata["json"])
            elif isinstance(record, DataEnd):
                data_end = True
            elif isinstance(record, Footer):
                if not data_end:  # a damaged DataEnd opcode reads as an unknown record and would be skipped
                    raise ValueError("no data-end record before the footer")
                _check_summary_crc(data, record)
        complete = True
    except LogError:
        raise
    except Exception as exc:  # mcap raises many types for damaged bytes: one line for all of them
        if not recover or meta is None:
            raise LogError(f"episode log {path}: {_damage(exc)} ({_describe(exc)}); "
                           f"re-run the episode, or read it with recover=True") from None
    if meta is None:
        raise LogError(f"episode log {path}: not a VLADriveBench episode log (no 'episode' metadata)")
    if complete and result is None:
        complete = False
        if not recover:
            raise LogError(f"episode log {path}: incomplete (no 'result' record); re-run the episode")
    return Episode(path, meta, _assemble_steps(path, by_step), result if complete else None, complete)


def _check_summary_crc(data: bytes, footer: Any) -> None:
    """The summary section (indexes, repeated schemas) is covered by the footer's CRC: check it."""
    if footer.summary_crc == 0:
        return
    end = len(data) - len(_MAGIC) - 4  # the CRC covers everything up to the CRC field itself
    start = footer.summary_start or end - 25  # no summary: only the footer's own fields
    if zlib.crc32(data[start:end]) != footer.summary_crc:
        raise ValueError("summary section CRC mismatch")


def _collect_message(by_step: dict[int, dict[str, Any]], topics: dict[int, str], message: Any) -> None:
    topic = topics.get(message.channel_id)
    if topic is None:
        raise LogError("message on an unknown channel")
    entry = by_step.setdefault(message.sequence, {"time": message.log_time / _NS})
    if topic == CAMERA_CHANNEL:
        entry["image_png"] = base64.b64decode(json.loads(message.data)["data"])
    elif topic.startswith(CAMERA_CHANNEL + "/"):
        name = topic[len(CAMERA_CHANNEL) + 1:]
        entry.setdefault("camera_pngs", {})[name] = base64.b64decode(json.loads(message.data)["data"])
    elif topic == "/command":
        entry["command"] = str(json.loads(message.data).get("command", ""))
    elif topic in _FIELD_OF_CHANNEL:
        entry[_FIELD_OF_CHANNEL[topic]] = json.loads(message.data)


_DECODERS = {
    "ego": decode.ego_from_json,
    "ground_truth": decode.ground_truth_from_json,
    "cot": decode.cot_from_json,
    "trajectory": decode.trajectory_from_json,
    "control": decode.control_from_json,
}


def _assemble_steps(path: Path, by_step: dict[int, dict[str, Any]]) -> list[StepRecord]:
    steps = []
    for step in sorted(by_step):
        entry = by_step[step]
        if not all(field in entry for field in _FIELD_OF_CHANNEL.values()):
            continue  # a step cut short by truncation
        steps.append(_step_record(path, step, entry))
    return steps


def _step_record(path: Path, step: int, entry: dict[str, Any]) -> StepRecord:
    try:
        records = {field: decoder(entry[field], field) for field, decoder in _DECODERS.items()}
        extras = entry["extras"]
        if not isinstance(extras, dict):
            raise ValueError(f"extras is {type(extras).__name__}, expected a JSON object")
    except ValueError as exc:
        raise LogError(f"episode log {path}: step {step}: {exc}; expected the layout of log schema "
                       f"version {SCHEMA_VERSION}") from None
    return StepRecord(step=step, time=float(records["ground_truth"].time), command=entry.get("command", ""),
                      image_png=entry.get("image_png"), camera_pngs=entry.get("camera_pngs", {}), extras=extras,
                      **records)


def _episode_meta(path: Path, metadata: Mapping[str, str]) -> dict:
    version = metadata.get("schema_version", "?")
    if version.split(".")[0] != SCHEMA_VERSION.split(".")[0]:
        raise LogError(f"episode log {path}: written with log schema version {version}, this VLADriveBench "
                       f"reads version {SCHEMA_VERSION}; re-run it or use a matching vladrivebench")
    try:
        return json.loads(metadata["json"])
    except (KeyError, ValueError):
        raise LogError(f"episode log {path}: unreadable 'episode' metadata") from None


def _damage(exc: BaseException) -> str:
    """``corrupt (CRC mismatch)`` when a checksum failed, ``truncated`` when the bytes ran out early."""
    text = f"{type(exc).__name__} {exc}".lower()
    if "crc" in text:
        return "corrupt (CRC mismatch)"
    if isinstance(exc, EOFError) or any(w in text for w in ("endoffile", "eof", "end of", "truncat", "not enough",
                                                            "requires a buffer")):
        return "truncated"
    return "corrupt or truncated"


def read_result(path: Path | str) -> dict | None:
    """The ``result`` record of a complete log, read from the summary without reading the steps.

    ``None`` when the file is not a complete, readable episode log (missing, truncated, corrupt).
    """
    from mcap.reader import SeekingReader

    try:
        with open(path, "rb") as handle:
            handle.seek(-8, os.SEEK_END)
            if handle.read(8) != _MAGIC:
                return None
            handle.seek(0)
            reader = SeekingReader(handle)
            if reader.get_summary() is None:
                return None
            for record in reader.iter_metadata():
                if record.name == "result":
                    return json.loads(record.metadata["json"])
    except Exception:  # any damage means "not complete": the caller re-runs the episode
        return None
    return None


def find_episodes(directory: Path | str) -> list[Path]:
    """Every episode log (``*.mcap``) under ``directory``, recursively, sorted; LogError if none."""
    directory = Path(directory)
    if not directory.is_dir():
        raise LogError(f"episode directory {directory}: no such directory")
    paths = sorted(p for p in directory.rglob("*.mcap") if p.is_file())
    if not paths:
        raise LogError(f"episode directory {directory}: no episode logs (*.mcap) found; "
                       f"run `vdb run --out {directory}` first")
    return paths


def load_episodes(directory: Path | str, *, recover: bool = False) -> list[Episode]:
    """Read every episode log under ``directory`` (see :func:`find_episodes`)."""
    return [read_episode(path, recover=recover) for path in find_episodes(directory)]


def _describe(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return f"{type(exc).__name__}: {text[0]}" if text else type(exc).__name__
