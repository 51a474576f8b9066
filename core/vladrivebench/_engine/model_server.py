"""A model server: models live in one spawned process, their callers (the harness) in this one.

The ``pipelined`` executor runs several lockstep batch jobs on threads of the driver; each job's model is a
:class:`RemoteModel` whose calls go to the server over its own pipe. A thread waiting for the server holds
no lock, so while the server computes one job's batched step the driver's other threads render, control,
log and step their lanes: on two cores the model never waits for the harness, and the harness no longer
sits on the model's critical path (as a simulator beside a model server on a GPU machine).

Each pipe has its own model instance on the server, built from the job's registry and component spec, and
its calls are served in the order that job makes them, so a job's results do not depend on what the other
jobs do: the logs are byte-identical to a sequential run. What crosses the pipe is plain pickle (never
shared tensors); a CoT's opaque ``state`` stays on the server and travels as a :class:`StateHandle`.
The RNGs a call draws from are sent with it and their final states sent back, so a caller sees its
generators advance exactly as a local call would advance them.
"""

from __future__ import annotations

import dataclasses
import itertools
import pickle
import threading
import time
import traceback
from collections import OrderedDict
from collections.abc import Callable, Sequence
from multiprocessing.connection import wait
from typing import Any

import numpy as np

HELD_STATES = 4096
"""CoT states a server keeps per model (oldest dropped first): many batches' worth of CoTs."""

_MAX_ATTRIBUTE_BYTES = 65536
_RUN_POLICY = "<run policy>"  # not a method name: a request to run a policy function beside the model
_INSTANCE_NUMBERS = itertools.count(1)  # the server process's model instances


@dataclasses.dataclass(frozen=True)
class StateHandle:
    """Where a CoT's state is on the server: a number, unique per model instance."""

    number: int


class RemoteCallError(Exception):
    """The server could not send back what a model call raised (its text and traceback are kept)."""


class RemoteTraceback(Exception):
    """The traceback of an exception raised on the model server (the ``__cause__`` of the local copy)."""


# -- the driver's side --------------------------------------------------------------------------------
class ModelServer:
    """A spawned process serving models on ``pipes`` pipes (one per caller thread); ``stop()`` ends it."""

    def __init__(self, pipes: int, start_method: str = "spawn"):
        import multiprocessing

        context = multiprocessing.get_context(start_method)
        ends = [context.Pipe() for _ in range(pipes)]
        self.process = context.Process(target=_serve, args=([child for _, child in ends],), daemon=True)
        self.process.start()
        for _, child in ends:
            child.close()
        self.pipes = [parent for parent, _ in ends]
        # One caller thread's harness at a time, and one thread's whole model step (see run_lockstep).
        self.harness_turn, self.model_turn = threading.Lock(), threading.Lock()

    def model(self, pipe: int, registry_spec: Any, component_spec: Any) -> RemoteModel:
        """A proxy of a new instance of the model ``component_spec``, built on the server, called over pipe
        ``pipe`` (only ever used by one thread at a time)."""
        conn = self.pipes[pipe]
        described = _request(conn, ("build", registry_spec, component_spec))
        return _proxy_class(described["methods"])(conn, described["instance"], described["attributes"],
                                                   described["type"])

    def stats(self) -> dict[str, float]:
        """What the server measured over all pipes (for the benchmark): ``model_seconds`` in the models'
        methods (and policies run beside them), and ``first_call`` / ``last_call`` (``time.perf_counter`` of this machine) when its first model call started and
        its last one ended. Ask only while no caller thread has a call in flight."""
        return dict(_request(self.pipes[0], ("stats",)))

    def stop(self) -> None:
        from vladrivebench._engine.executors import stop_process

        for conn in self.pipes:
            try:
                conn.send_bytes(pickle.dumps(None))
            except (OSError, ValueError):
                pass
        stop_process(self.process)
        for conn in self.pipes:
            conn.close()


class RemoteModel:
    """A model on the model server. Its class has exactly the public methods of the remote model's class
    (so protocol checks such as ``isinstance(model, BatchedModel)`` answer as for the model itself) and its
    picklable public attributes (``cot_format``, ``trajectory_spec``, …) as copies."""

    def __init__(self, conn: Any, instance: int, attributes: dict[str, Any], remote_type: str):
        self._conn, self._instance = conn, instance
        self._remote_type = remote_type
        for name, value in attributes.items():
            setattr(self, name, value)

    def __repr__(self) -> str:
        return f"<RemoteModel {self._remote_type}>"

    def close_remote(self) -> None:
        """Close the model on the server (if it can be closed) and drop it there. Safe to call twice."""
        if self._instance is not None:
            instance, self._instance = self._instance, None
            try:
                _request(self._conn, ("drop", instance))
            except (EOFError, OSError):  # the server is gone already
                pass

    def run_policy(self, policy: Callable[..., Any], *args: Any) -> Any:
        """``policy(model, *args)`` run on the server beside the model, in one round trip (``policy`` must
        pickle by reference: a module-level function such as ``own_cot_batch_policy``)."""
        return self._call(_RUN_POLICY, (policy, *args), {})

    def _call(self, method: str, args: tuple, kwargs: dict) -> Any:
        generators = _generators((args, kwargs))
        result, states = _request(self._conn, ("call", self._instance, method, args, kwargs))
        for generator, state in zip(generators, states, strict=True):
            generator.bit_generator.state = state
        return result


def _proxy_class(methods: Sequence[str]) -> type:
    def forward(name: str) -> Callable[..., Any]:
        def method(self: RemoteModel, *args: Any, **kwargs: Any) -> Any:
            return self._call(name, args, kwargs)
        method.__name__ = name
        return method

    namespace = {name: forward(name) for name in methods}
    namespace["close"] = RemoteModel.close_remote  # the instance is dropped on the server too
    return type("RemoteModel", (RemoteModel,), namespace)


def _request(conn: Any, message: tuple) -> Any:
    conn.send_bytes(pickle.dumps(message, protocol=pickle.HIGHEST_PROTOCOL))
    status, payload = pickle.loads(conn.recv_bytes())
    if status == "ok":
        return payload
    exc, text, remote_traceback = payload
    error = exc if isinstance(exc, BaseException) else RemoteCallError(text)
    raise error from RemoteTraceback(remote_traceback)


def _map_nested(value: Any, leaf: Callable[[Any], Any]) -> Any:
    """``value`` with ``leaf`` applied to everything inside its nested lists, tuples and dict values, in
    order (what crosses the pipe: arguments, results)."""
    if isinstance(value, list):
        return [_map_nested(item, leaf) for item in value]
    if isinstance(value, tuple):
        return tuple(_map_nested(item, leaf) for item in value)
    if isinstance(value, dict):
        return {key: _map_nested(item, leaf) for key, item in value.items()}
    return leaf(value)


def _generators(value: Any) -> list[np.random.Generator]:
    """The numpy Generators in ``value`` (nested tuples, lists and dict values), in a fixed order."""
    found: list[np.random.Generator] = []
    _map_nested(value, lambda leaf: found.append(leaf) if isinstance(leaf, np.random.Generator) else None)
    return found


# -- the server's side --------------------------------------------------------------------------------
class _Hosted:
    """One pipe's model and the CoT states it handed out."""

    def __init__(self, model: Any):
        self.model = model
        self.states: OrderedDict[int, Any] = OrderedDict()
        self.next_number = 0

    def outgoing(self, value: Any) -> Any:
        """``value`` with every CoT's state replaced by a handle (the state kept here)."""
        return _map_nested(value, self._handle)

    def incoming(self, value: Any) -> Any:
        """``value`` with every CoT's handle replaced by the state it stands for."""
        return _map_nested(value, self._resolve)

    def _handle(self, value: Any) -> Any:
        from vladrivebench.records import CoT

        if not isinstance(value, CoT) or value.state is None or isinstance(value.state, StateHandle):
            return value
        self.next_number += 1
        self.states[self.next_number] = value.state
        while len(self.states) > HELD_STATES:
            self.states.popitem(last=False)
        return dataclasses.replace(value, state=StateHandle(self.next_number))

    def _resolve(self, value: Any) -> Any:
        from vladrivebench.records import CoT

        if not isinstance(value, CoT) or not isinstance(value.state, StateHandle):
            return value
        state = self.states.get(value.state.number)
        if state is None:
            raise RemoteCallError(f"the model server no longer holds this CoT's state (it keeps the last "
                                  f"{HELD_STATES} CoTs of each model)")
        return dataclasses.replace(value, state=state)


def _serve(conns: list[Any]) -> None:
    """The server process: answer every pipe's requests until all say stop or the driver goes away."""
    import signal

    from vladrivebench._engine.executors import _die_with_parent

    _die_with_parent()
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    hosted: dict[int, _Hosted] = {}  # instance number (never reused) → its model
    stats = {"model_seconds": 0.0, "first_call": 0.0, "last_call": 0.0}
    open_conns = list(conns)
    while open_conns:
        for conn in wait(open_conns):
            try:
                message = pickle.loads(conn.recv_bytes())
            except (EOFError, OSError):
                message = None
            if message is None:
                open_conns.remove(conn)
                continue
            reply = _answer(message, hosted, stats)
            try:
                data = pickle.dumps(reply, protocol=pickle.HIGHEST_PROTOCOL)
            except Exception as exc:  # an unpicklable result: the caller gets the reason instead
                data = pickle.dumps(_error(exc), protocol=pickle.HIGHEST_PROTOCOL)
            conn.send_bytes(data)


def _answer(message: tuple, hosted: dict[int, _Hosted], stats: dict[str, float]) -> tuple[str, Any]:
    try:
        if message[0] == "build":
            return "ok", _build(message[1], message[2], hosted)
        if message[0] == "stats":
            return "ok", dict(stats)
        if message[0] == "drop":
            _drop(hosted.pop(message[1], None))
            return "ok", None
        _, instance, method, args, kwargs = message
        host = hosted[instance]
        args, kwargs = host.incoming(args), host.incoming(kwargs)
        started = time.perf_counter()
        try:
            if method == _RUN_POLICY:
                result = args[0](host.model, *args[1:], **kwargs)
            else:
                result = getattr(host.model, method)(*args, **kwargs)
        finally:
            stats["last_call"] = time.perf_counter()
            stats["first_call"] = stats["first_call"] or started
            stats["model_seconds"] += stats["last_call"] - started
        states = [g.bit_generator.state for g in _generators((args, kwargs))]
        return "ok", (host.outgoing(result), states)
    except Exception as exc:
        return _error(exc)


def _build(registry_spec: Any, component_spec: Any, hosted: dict[int, _Hosted]) -> dict[str, Any]:
    from vladrivebench._engine.sweep import _registry_for

    model = _registry_for(registry_spec).create(component_spec.kind, component_spec.name, component_spec.options)
    instance = next(_INSTANCE_NUMBERS)
    hosted[instance] = _Hosted(model)
    methods = [name for name in dir(type(model)) if not name.startswith("_") and callable(getattr(model, name))]
    return {"instance": instance, "methods": methods, "attributes": _attributes(model),
            "type": type(model).__qualname__}


def _drop(host: _Hosted | None) -> None:
    close = getattr(host.model, "close", None) if host else None
    if callable(close):
        close()


def _attributes(model: Any) -> dict[str, Any]:
    """The model's public non-callable attributes that pickle small (copied to the proxy)."""
    found = {}
    for name in dir(model):
        if name.startswith("_"):
            continue
        try:
            value = getattr(model, name)
        except Exception:
            continue
        if callable(value):
            continue
        try:
            if len(pickle.dumps(value)) <= _MAX_ATTRIBUTE_BYTES:
                found[name] = value
        except Exception:
            continue
    return found


def _error(exc: BaseException) -> tuple[str, Any]:
    text = f"{type(exc).__name__}: {' '.join(str(exc).split())}"
    details = "".join(traceback.format_exception(type(exc), exc, exc.__traceback__))
    try:
        exc.__traceback__ = None
        exc.__cause__ = exc.__context__ = None
        pickle.loads(pickle.dumps(exc))
        sendable: Any = exc
    except Exception:
        sendable = None
    return "error", (sendable, text, details)
