"""The black box: every message of a run, in SQLite.

Schema (an open format: any SQLite client reads it):

* ``messages(t REAL, channel TEXT, source TEXT, payload TEXT)``: one row per
  published message, in publication order; ``t`` is simulated seconds, the
  payload is JSON ``{"value": ...}`` (an enum's name, a boolean, a number in
  the channel's unit, a list, or null for "no value").
* ``channels(name, source, kind, domain, unit, period, record, description)``:
  what each channel carries (``domain`` is JSON: the enum's values, or the kind).
* ``metadata(key, value)``: run metadata as JSON values: the resolved scenario,
  seed, package versions, status (``running``, ``completed``, ``interrupted``,
  ``failed``).

Rows are committed in transactions after every simulated second (with
``recorded_until``, the simulated time they reach), so a killed run loses at
most its last second and what was committed stays readable.
"""

from __future__ import annotations

import json
import math
import os
import sqlite3
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from cellsim.channels import ChannelSpec

SCHEMA = """
CREATE TABLE messages (t REAL NOT NULL, channel TEXT NOT NULL, source TEXT NOT NULL, payload TEXT NOT NULL);
CREATE TABLE channels (
    name TEXT PRIMARY KEY, source TEXT NOT NULL, kind TEXT NOT NULL, domain TEXT NOT NULL,
    unit TEXT, period REAL NOT NULL, record TEXT NOT NULL, description TEXT NOT NULL);
CREATE TABLE metadata (key TEXT PRIMARY KEY, value TEXT NOT NULL);
"""


CHANNEL_KINDS = ("enum", "bool", "number", "vector")


class BlackBoxError(Exception):
    """A file that is not a readable cellsim black box."""


class BlackBoxWriter:
    """Writes one run's black box; rows are buffered until the next :meth:`commit`,
    so what is on disk always ends at the ``recorded_until`` written with it."""

    def __init__(self, path: str | os.PathLike):
        self.path = Path(path)
        if self.path.exists():
            raise FileExistsError(f"{self.path} already exists")
        self._rows: list[tuple] = []
        self._db = sqlite3.connect(self.path)
        try:
            self._db.executescript("PRAGMA journal_mode=WAL; PRAGMA synchronous=NORMAL;" + SCHEMA)
        except BaseException:  # (Ctrl-C as it opens, too): no connection is left open behind a writer never made
            self._db.close()
            raise
        self.rows_written = 0

    def set_metadata(self, **values) -> None:
        with self._db:
            self._db.executemany(
                "INSERT OR REPLACE INTO metadata VALUES (?, ?)", [(k, json.dumps(v)) for k, v in values.items()]
            )

    def add_channels(self, specs: list[ChannelSpec]) -> None:
        with self._db:
            self._db.executemany(
                "INSERT INTO channels VALUES (?, ?, ?, ?, ?, ?, ?, ?)",
                [
                    (s.name, s.module, s.type.kind, json.dumps(s.type.domain()), s.type.unit, s.sample_period, s.record, s.description)
                    for s in specs
                ],
            )

    def append(self, row: tuple) -> None:
        """Buffer one message row ``(t, channel, source, payload_json)``; :meth:`commit` writes it."""
        self._rows.append(row)

    def flush(self) -> None:
        if self._rows:
            with self._db:
                self._insert()

    def commit(self, recorded_until: float) -> None:
        """Write the buffered rows and ``recorded_until`` (simulated s) in one transaction.

        Everything published before ``recorded_until`` is then on disk: a reader
        of a run that was killed later takes the record as complete up to there.
        """
        with self._db:
            self._insert()
            self._db.execute(
                "INSERT OR REPLACE INTO metadata VALUES ('recorded_until', ?)", (json.dumps(round(recorded_until, 9)),)
            )

    def _insert(self) -> None:
        if self._rows:
            self._db.executemany("INSERT INTO messages VALUES (?, ?, ?, ?)", self._rows)
            self.rows_written += len(self._rows)
            self._rows.clear()

    def close(self, status: str) -> None:
        """Flush, record the final status, index, and leave a single self-contained file.

        While another process has the file open (someone reading the running record: ``cellsim check``,
        a dashboard, sqlite3), SQLite cannot leave WAL mode; the file then stays in it, complete and
        readable, everything checkpointed into it, rather than the run ending in an error."""
        self.flush()
        self.set_metadata(status=status)
        with self._db:
            self._db.execute("CREATE INDEX IF NOT EXISTS messages_by_channel ON messages(channel, t)")
        self._db.execute("PRAGMA wal_checkpoint(TRUNCATE)")
        try:
            self._db.execute("PRAGMA journal_mode=DELETE")
        except sqlite3.OperationalError:  # "database is locked": a reader has it open
            pass
        self._db.close()


@dataclass(frozen=True)
class Message:
    t: float
    channel: str
    source: str
    value: object


@dataclass(frozen=True)
class Series:
    """A channel's values over time: ``values[i]`` holds from ``times[i]`` on."""

    channel: str
    times: np.ndarray
    values: list

    def value_at(self, t: float):
        i = int(np.searchsorted(self.times, t, side="right")) - 1
        return None if i < 0 else self.values[i]

    def __len__(self) -> int:
        return len(self.values)


@dataclass(frozen=True)
class ChannelInfo:
    name: str
    source: str
    kind: str
    domain: object
    unit: str | None
    period: float
    record: str
    description: str


class BlackBox:
    """Reads a black box: metadata, channels, messages and per-channel time series."""

    def __init__(self, path: str | os.PathLike):
        self.path = Path(path)
        if not self.path.is_file():
            raise BlackBoxError(f"{self.path}: no such black box")
        try:
            self._db = sqlite3.connect(f"file:{self.path}?mode=ro", uri=True)
            tables = {r[0] for r in self._db.execute("SELECT name FROM sqlite_master WHERE type='table'")}
        except sqlite3.DatabaseError as e:
            raise BlackBoxError(f"{self.path}: not a SQLite database ({e})") from None
        missing = {"messages", "channels", "metadata"} - tables
        if missing:
            raise BlackBoxError(f"{self.path}: not a cellsim black box (missing tables: {', '.join(sorted(missing))})")
        self._channels: dict[str, ChannelInfo] | None = None

    def close(self) -> None:
        self._db.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def metadata(self) -> dict:
        data = {}
        for key, value in self._query("SELECT key, value FROM metadata"):
            try:
                data[key] = json.loads(value)
            except (json.JSONDecodeError, TypeError):
                raise self.corrupt(f"metadata '{key}' is not JSON") from None
        return data

    def channels(self) -> dict[str, ChannelInfo]:
        if self._channels is None:
            rows = self._query("SELECT name, source, kind, domain, unit, period, record, description FROM channels")
            self._channels = {r[0]: self._channel(*r) for r in rows}
        return self._channels

    def corrupt(self, problem: str) -> BlackBoxError:
        return BlackBoxError(f"{self.path}: corrupt black box: {problem}")

    def _query(self, sql: str, args=()) -> list:
        try:
            return self._db.execute(sql, args).fetchall()
        except sqlite3.DatabaseError as e:
            raise self.corrupt(str(e)) from None

    def _channel(self, name, source, kind, domain, unit, period, record, description) -> ChannelInfo:
        try:
            domain = json.loads(domain)
        except (json.JSONDecodeError, TypeError):
            raise self.corrupt(f"channel '{name}': its domain is not JSON") from None
        if kind not in CHANNEL_KINDS:
            raise self.corrupt(f"channel '{name}': unknown kind {kind!r} (expected one of: {', '.join(CHANNEL_KINDS)})")
        if kind == "enum" and not (isinstance(domain, list) and domain and all(isinstance(v, str) for v in domain)):
            raise self.corrupt(f"channel '{name}': an enum's domain must be a non-empty list of names, got {domain!r}")
        if isinstance(period, bool) or not isinstance(period, (int, float)) or not math.isfinite(period) or period <= 0:
            raise self.corrupt(f"channel '{name}': period {period!r} is not a positive number of seconds")
        return ChannelInfo(name, source, kind, domain, unit, float(period), record, description)

    def messages(self, channel: str | None = None) -> list[Message]:
        if channel is None:
            rows = self._db.execute("SELECT t, channel, source, payload FROM messages ORDER BY rowid")
        else:
            rows = self._db.execute(
                "SELECT t, channel, source, payload FROM messages WHERE channel = ? ORDER BY rowid", (channel,)
            )
        return [Message(t, c, s, self._value(c, t, p)) for t, c, s, p in rows]

    def _value(self, channel: str, t, payload):
        """A message's value from its JSON ``payload`` (BlackBoxError when it is no cellsim message)."""
        try:
            return json.loads(payload)["value"]
        except (json.JSONDecodeError, KeyError, TypeError) as e:
            raise self.corrupt(f"the payload of a '{channel}' message at t = {t} is not a cellsim message ({e})") from None

    def iter_values(self, channels: list[str]):
        """``(t, channel, value)`` of the messages of ``channels``, in time order (publication order within an
        instant). Rows are written as the recorder looks at them, a slow channel's value after a faster one's
        published later, so the file's order is not time order."""
        marks = ",".join("?" * len(channels))
        query = f"SELECT t, channel, payload FROM messages WHERE channel IN ({marks}) ORDER BY t, rowid"
        try:
            cursor = self._db.execute(query, list(channels))
            for t, channel, payload in cursor:  # row by row: memory stays flat however long the run
                yield t, channel, self._value(channel, t, payload)
        except sqlite3.DatabaseError as e:
            raise self.corrupt(str(e)) from None

    def check_vectors(self) -> None:
        """Every message of a vector channel is a JSON list of numbers (or nulls), of one length per channel;
        else a BlackBoxError naming the channel and time. Checked in SQLite (JSON1), not row by row in Python."""
        vectors = [name for name, info in self.channels().items() if info.kind == "vector"]
        if not vectors:
            return
        marks = ",".join("?" * len(vectors))
        bad = self._query(
            f"SELECT channel, t FROM messages WHERE channel IN ({marks}) AND (NOT json_valid(payload) "
            "OR json_type(payload, '$.value') IS NOT 'array' OR EXISTS (SELECT 1 FROM json_each(payload, '$.value') "
            "WHERE type NOT IN ('integer', 'real', 'null'))) ORDER BY rowid LIMIT 1", vectors)
        if bad:
            raise self.corrupt(f"'{bad[0][0]}' at t = {bad[0][1]} is not a vector of numbers")
        lengths = self._query(
            f"SELECT channel FROM messages WHERE channel IN ({marks}) GROUP BY channel "
            "HAVING count(DISTINCT json_array_length(payload, '$.value')) > 1 LIMIT 1", vectors)
        if lengths:
            raise self.corrupt(f"'{lengths[0][0]}' holds vectors of different lengths")

    def check_vector_sizes(self, sizes: dict[str, int]) -> None:
        """Each vector channel of ``sizes`` (channel -> the length the rebuilt cell's channel has) holds vectors of
        that length; else a BlackBoxError naming the channel (a record of another cell, or a corrupt one, would pose
        an arm or a body with the wrong number of values). Vectors of one length per channel: :meth:`check_vectors`."""
        recorded = self.channels()
        for name, size in sorted(sizes.items()):
            if name not in recorded or recorded[name].kind != "vector":
                continue
            found = self._query("SELECT t, json_array_length(payload, '$.value') FROM messages WHERE channel = ? "
                                "AND json_array_length(payload, '$.value') != ? ORDER BY rowid LIMIT 1", [name, size])
            if found:
                t, length = found[0]
                numbers = f"{length} number{'s' if length != 1 else ''}"
                raise self.corrupt(f"'{name}' at t = {t} holds {numbers} where the scenario's cell has {size}: a record "
                                   "of another cell, or a corrupt one")

    def recorded_seed(self, default: int) -> int:
        """The simulation seed the metadata names (``default`` where it names none); a BlackBoxError for one that is
        no non-negative integer."""
        seed = self.metadata().get("seed", default)
        if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
            raise self.corrupt(f"its metadata's seed is {json.dumps(seed)}, not a non-negative integer")
        return seed

    def check_channels(self) -> None:
        """Every message belongs to a channel the ``channels`` table lists; else a BlackBoxError naming one that does
        not (its messages would be read as nothing: a record lost without a word)."""
        stray = self._query("SELECT channel FROM messages WHERE channel NOT IN (SELECT name FROM channels) LIMIT 1")
        if stray:
            raise self.corrupt(f"messages of channel '{stray[0][0]}', which its channels table does not list")

    def rows(self) -> list[tuple]:
        """The raw ``messages`` rows in publication order (for comparing runs)."""
        return self._db.execute("SELECT t, channel, source, payload FROM messages ORDER BY rowid").fetchall()

    def series(self, channel: str) -> Series:
        """The time series of one channel (KeyError if the run has no such channel)."""
        if channel not in self.channels():
            raise KeyError(f"{self.path} has no channel '{channel}'")
        messages = self.messages(channel)
        return Series(channel, np.array([m.t for m in messages], float), [m.value for m in messages])

    def all_series(self) -> dict[str, Series]:
        grouped: dict[str, tuple[list, list]] = {name: ([], []) for name in self.channels()}
        for t, c, _, p in self._db.execute("SELECT t, channel, source, payload FROM messages ORDER BY rowid"):
            times, values = grouped.setdefault(c, ([], []))
            times.append(t)
            values.append(json.loads(p)["value"])
        return {c: Series(c, np.array(ts, float), vs) for c, (ts, vs) in grouped.items()}


def run_end(bb: BlackBox, metadata: dict, reach: float = 0.0) -> tuple[float, bool]:
    """Where a run's record ends (s), and whether the run completed.

    A completed run (or a live one stopped on request) ends at its duration; otherwise
    at the committed ``recorded_until``; without that, at ``reach`` (the latest message
    time plus its channel's period).
    """
    if "status" not in metadata:  # written when the run starts, whatever happens next
        raise BlackBoxError(f"{bb.path}: corrupt black box: its metadata has no status")
    complete = metadata.get("status") in ("completed", "stopped")
    end = _number(bb, metadata, "duration") if complete else None
    if end is None:
        complete = False
        end = _number(bb, metadata, "recorded_until") or reach
    return end, complete


def _number(bb: BlackBox, metadata: dict, key: str) -> float | None:
    """A positive finite number from the metadata, None when absent; corrupt otherwise."""
    value = metadata.get(key)
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not np.isfinite(value) or value < 0:
        raise BlackBoxError(f"{bb.path}: corrupt black box: metadata '{key}' is {value!r}, not a time in seconds")
    return float(value) if value > 0 else None
