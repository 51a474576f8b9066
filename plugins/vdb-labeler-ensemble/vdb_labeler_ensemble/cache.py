"""A persistent SQLite cache of completed calls, so a rerun or a resumed run spends nothing twice.

The key hashes everything that can change an answer: the backend (kind, model, base URL, generation
parameters), the prompt version and digest, the CoT text and slots, and the ground-truth context. Each
reply is committed the moment it arrives, so an interrupted run loses at most the calls in flight.
Only what the model answered is stored — never a request header, so never an API key.
"""

from __future__ import annotations

import hashlib
import json
import os
import sqlite3
import sys
import threading
import time
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

from vladrivebench import ConfigError

from .backends import Reply

SCHEMA_VERSION = 1
CACHE_FILE = "ensemble-labels.sqlite"


def default_cache_path() -> Path:
    """``$VDB_CACHE_DIR``, else the user's cache directory (XDG on Linux), + ``vladrivebench/…sqlite``."""
    if os.environ.get("VDB_CACHE_DIR"):
        return Path(os.environ["VDB_CACHE_DIR"]).expanduser() / CACHE_FILE
    if sys.platform == "darwin":
        base = Path.home() / "Library" / "Caches"
    elif os.name == "nt":
        base = Path(os.environ.get("LOCALAPPDATA") or Path.home() / "AppData" / "Local")
    else:
        base = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")
    return base / "vladrivebench" / CACHE_FILE


def cache_key(identity: Mapping[str, Any], prompt_version: str, prompt_digest: str, text: str,
              slots: Mapping[str, str], context: Mapping[str, Any]) -> str:
    """The SHA-256 of the canonical JSON of everything that can change one backend's answer."""
    payload = {
        "backend": dict(identity),
        "prompt": {"version": prompt_version, "digest": prompt_digest},
        "text": text,
        "slots": [[name, value] for name, value in slots.items()],  # slot order is part of the CoT
        "context": context,
    }
    canonical = json.dumps(payload, sort_keys=True, separators=(",", ":"), default=str, allow_nan=True)
    return hashlib.sha256(canonical.encode("utf-8")).hexdigest()


class ResponseCache:
    """Completed replies by cache key. ``path=None`` keeps them in memory only (nothing persists)."""

    def __init__(self, path: str | Path | None):
        self.path = Path(path).expanduser() if path is not None else None
        self._lock = threading.Lock()
        self._db = self._open()

    def _open(self) -> sqlite3.Connection:
        target = ":memory:"
        if self.path is not None:
            try:
                self.path.parent.mkdir(parents=True, exist_ok=True)
            except OSError as exc:
                raise ConfigError(f"cache {self.path}: cannot create its folder ({exc.strerror}): "
                                  f"choose another with --labeler-opt cache=PATH") from None
            target = str(self.path)
        try:
            db = sqlite3.connect(target, check_same_thread=False, timeout=30.0)
            db.execute("PRAGMA journal_mode=WAL")
            # A commit then survives a killed process without an fsync each (only a power cut could lose
            # the last few replies, never corrupt the file).
            db.execute("PRAGMA synchronous=NORMAL")
            db.execute(
                "CREATE TABLE IF NOT EXISTS replies (key TEXT PRIMARY KEY, backend TEXT NOT NULL, "
                "model TEXT NOT NULL, prompt_version TEXT NOT NULL, created REAL NOT NULL, reply TEXT NOT NULL)"
            )
            db.execute("CREATE TABLE IF NOT EXISTS meta (name TEXT PRIMARY KEY, value TEXT NOT NULL)")
            db.execute("INSERT OR IGNORE INTO meta VALUES ('schema', ?)", (str(SCHEMA_VERSION),))
            db.commit()
            (schema,) = db.execute("SELECT value FROM meta WHERE name = 'schema'").fetchone()
        except sqlite3.DatabaseError as exc:
            raise ConfigError(f"cache {self.path}: not a usable SQLite cache ({exc}): delete it or choose "
                              f"another with --labeler-opt cache=PATH") from None
        if schema != str(SCHEMA_VERSION):
            raise ConfigError(f"cache {self.path}: written by another version (schema {schema}, expected "
                              f"{SCHEMA_VERSION}): choose another with --labeler-opt cache=PATH")
        return db

    def get_many(self, keys: Iterable[str]) -> dict[str, Reply]:
        """The cached replies among ``keys``."""
        found: dict[str, Reply] = {}
        unique = list(dict.fromkeys(keys))
        with self._lock:
            for start in range(0, len(unique), 500):
                chunk = unique[start:start + 500]
                marks = ",".join("?" * len(chunk))
                rows = self._db.execute(f"SELECT key, reply FROM replies WHERE key IN ({marks})", chunk)
                for key, reply in rows:
                    found[key] = Reply.from_json(json.loads(reply))
        return found

    def put(self, key: str, backend: str, model: str, prompt_version: str, reply: Reply) -> None:
        """Store one completed reply and commit at once."""
        row = (key, backend, model, prompt_version, time.time(), json.dumps(reply.to_json()))
        with self._lock:
            self._db.execute("INSERT OR REPLACE INTO replies VALUES (?, ?, ?, ?, ?, ?)", row)
            self._db.commit()

    def __len__(self) -> int:
        with self._lock:
            return self._db.execute("SELECT COUNT(*) FROM replies").fetchone()[0]

    def close(self) -> None:
        with self._lock:
            self._db.close()
