"""ModeTable: validated pushing modes, reused across similar obstacles (Section III-C, Remark 4).

A mode is what the hybrid search tries on a movable: a body-frame push direction (binned), a team
size, a speed and a yaw rate. The contact points themselves are re-derived on the actual obstacle
(``push.face_contacts``) so that a mode learnt on one obstacle transfers to a similar one whose size
differs by less than the signature's rounding.

Key: the obstacle's *shape signature* (:func:`shape_signature`: its shape kind and sizes rounded to
``resolution``; without shape metadata, the number of pieces and the body-frame bounding extents and
area, rounded) and the mode (:class:`ModeKey`). Value: how often the mode was simulated (``trials``)
and validated (``success``: the rollout was valid and the body followed at least half of the
commanded displacement), plus the last validated body-frame contacts, for inspection.

The table is a plain dict; ``save`` / ``load`` write / read JSON::

    {"format": "jaxplan.pusharound.modetable", "version": 1, "resolution": 0.1, "angle_bins": 16,
     "entries": {"rectangle|height=0.4|width=0.6": [{"bin": 4, "n_robots": 2, "speed": 0.3,
                  "omega": 0.0, "success": 3, "trials": 4, "contacts": [[..], [..]]}, ...]}}
"""
from __future__ import annotations

import json
import math
from pathlib import Path
from typing import NamedTuple

import numpy as np
import shapely

from jaxplan.core import read_text

__all__ = ["ModeKey", "ModeRecord", "ModeTable", "shape_signature"]

_FORMAT = "jaxplan.pusharound.modetable"


def shape_signature(movable, resolution: float = 0.1) -> str:
    """A string naming the obstacle's shape up to ``resolution`` [m] (mass is not part of it).

    With shape metadata (``movable.shape = {"kind": ..., sizes...}``): the kind and every numeric
    size rounded to ``resolution`` (integer parameters such as polygon sides kept). Without it: the
    number of pieces, the body-frame bounding extents (sorted, so that a quarter turn gives the same
    key) and the area, rounded.
    """
    if not resolution > 0:
        raise ValueError(f"resolution: must be > 0 m; got {resolution!r}.")

    def rnd(v):
        return f"{round(float(v) / resolution) * resolution:.3f}"

    shape = getattr(movable, "shape", None)
    if isinstance(shape, dict) and shape.get("kind"):
        parts = [str(shape["kind"])]
        for k in sorted(shape):
            if k == "kind":
                continue
            v = shape[k]
            if isinstance(v, (bool, np.bool_)):
                parts.append(f"{k}={bool(v)}")
            elif isinstance(v, (int, np.integer)):
                parts.append(f"{k}={int(v)}")
            elif isinstance(v, (float, np.floating)):
                parts.append(f"{k}={rnd(v)}")
        return "|".join(parts)
    body = shapely.union_all(list(movable.pieces))
    x0, y0, x1, y1 = body.bounds
    ext = sorted([x1 - x0, y1 - y0])
    return f"polygon{len(movable.pieces)}|ext={rnd(ext[0])},{rnd(ext[1])}|area={rnd(body.area / max(ext[1], 1e-9))}"


class ModeKey(NamedTuple):
    """bin: body-frame push direction bin (0..angle_bins-1, bin k centred on 2 pi k / angle_bins);
    n_robots: team size; speed [m/s] and omega [rad/s], rounded to 0.05 m/s and 0.05 rad/s."""

    bin: int
    n_robots: int
    speed: float
    omega: float


class ModeRecord(NamedTuple):
    """A stored mode: its key, success / trial counts and the last validated body-frame contacts
    f[n, 2] (None before the first success)."""

    key: ModeKey
    success: int
    trials: int
    contacts: list | None

    @property
    def rate(self) -> float:
        """Laplace-smoothed success rate (success + 1) / (trials + 2)."""
        return (self.success + 1.0) / (self.trials + 2.0)


class ModeTable:
    """Validated pushing modes per shape signature (module docstring).

    resolution: size rounding of the signature [m]; angle_bins: body-frame direction bins.
    ``len(table)`` is the number of validated modes (success > 0) over all signatures.
    """

    def __init__(self, resolution: float = 0.1, angle_bins: int = 16):
        if not resolution > 0:
            raise ValueError(f"resolution: must be > 0 m; got {resolution!r}.")
        if not isinstance(angle_bins, (int, np.integer)) or angle_bins < 4:
            raise ValueError(f"angle_bins: must be an int >= 4; got {angle_bins!r}.")
        self.resolution = float(resolution)
        self.angle_bins = int(angle_bins)
        self.entries: dict[str, dict[ModeKey, ModeRecord]] = {}

    # ------------------------------------------------------------------ keys
    def signature(self, movable) -> str:
        return shape_signature(movable, self.resolution)

    def angle_bin(self, body_angle: float) -> int:
        """The bin of a body-frame direction angle [rad]."""
        step = 2 * math.pi / self.angle_bins
        return int(round(float(body_angle) / step)) % self.angle_bins

    def bin_angle(self, b: int) -> float:
        """The centre angle [rad] of bin ``b``."""
        return 2 * math.pi * (int(b) % self.angle_bins) / self.angle_bins

    def key(self, body_angle: float, n_robots: int, speed: float, omega: float) -> ModeKey:
        return ModeKey(self.angle_bin(body_angle), int(n_robots), round(round(float(speed) / 0.05) * 0.05, 3),
                       round(round(float(omega) / 0.05) * 0.05, 3))

    # ------------------------------------------------------------------ queries
    def lookup(self, movable, body_angle: float | None = None, n_robots: int | None = None,
               validated: bool = True, window: int = 0) -> list:
        """Stored :class:`ModeRecord` for the obstacle's signature, best rate first.

        body_angle: only modes whose bin is within ``window`` bins of this body-frame angle [rad];
        n_robots: only that team size; validated: only modes with at least one success.
        """
        recs = self.entries.get(self.signature(movable), {})
        out = []
        b0 = None if body_angle is None else self.angle_bin(body_angle)
        for k, r in recs.items():
            if validated and r.success <= 0:
                continue
            if n_robots is not None and k.n_robots != int(n_robots):
                continue
            if b0 is not None:
                d = (k.bin - b0) % self.angle_bins
                if min(d, self.angle_bins - d) > window:
                    continue
            out.append(r)
        out.sort(key=lambda r: (-r.rate, -r.success, r.key))
        return out

    def prior(self, movable, key: ModeKey) -> ModeRecord | None:
        """The record of exactly this mode on this obstacle's signature, or None."""
        return self.entries.get(self.signature(movable), {}).get(key)

    def record(self, movable, key: ModeKey, success: bool, contacts=None) -> ModeRecord:
        """Count one simulated trial of ``key`` on ``movable`` (validated when ``success``)."""
        if not isinstance(key, ModeKey):
            raise ValueError(f"key: expected a ModeKey (ModeTable.key(...)); got {type(key).__name__}.")
        recs = self.entries.setdefault(self.signature(movable), {})
        old = recs.get(key, ModeRecord(key, 0, 0, None))
        c = old.contacts
        if success and contacts is not None:
            c = np.asarray(contacts, np.float64).round(6).tolist()
        rec = ModeRecord(key, old.success + int(bool(success)), old.trials + 1, c)
        recs[key] = rec
        return rec

    def __len__(self) -> int:
        return sum(1 for recs in self.entries.values() for r in recs.values() if r.success > 0)

    def __repr__(self) -> str:
        return (f"ModeTable({len(self)} validated modes over {len(self.entries)} signatures, "
                f"resolution={self.resolution}, angle_bins={self.angle_bins})")

    # ------------------------------------------------------------------ persistence
    def to_dict(self) -> dict:
        return {"format": _FORMAT, "version": 1, "resolution": self.resolution, "angle_bins": self.angle_bins,
                "entries": {sig: [{"bin": r.key.bin, "n_robots": r.key.n_robots, "speed": r.key.speed,
                                   "omega": r.key.omega, "success": r.success, "trials": r.trials,
                                   "contacts": r.contacts} for r in sorted(recs.values(), key=lambda r: r.key)]
                            for sig, recs in sorted(self.entries.items())}}

    @classmethod
    def from_dict(cls, data: dict) -> ModeTable:
        """Parse a table dict (the JSON of :meth:`to_dict`); ValueError naming the bad field."""
        if not isinstance(data, dict) or data.get("format") != _FORMAT:
            raise ValueError(f"format: not a ModeTable file (expected format {_FORMAT!r}).")
        if type(data.get("version")) is not int or data["version"] != 1:
            raise ValueError(f"version: unsupported ModeTable version {data.get('version')!r} (expected 1).")
        unknown = [k for k in data if k not in _TABLE_KEYS]
        if unknown:
            raise ValueError(f"unknown key(s) {', '.join(map(repr, unknown))}; a ModeTable file has the keys "
                             f"{', '.join(_TABLE_KEYS)}.")
        resolution = data.get("resolution", 0.1)
        if not _is_number(resolution) or not math.isfinite(resolution):
            raise ValueError(f"resolution: must be a finite number > 0 (m); got {resolution!r}.")
        angle_bins = data.get("angle_bins", 16)
        if type(angle_bins) is not int:
            raise ValueError(f"angle_bins: must be an int >= 4; got {angle_bins!r}.")
        table = cls(resolution, angle_bins)
        entries = data.get("entries", {})
        if not isinstance(entries, dict):
            raise ValueError(f"entries: expected an object mapping shape signatures to lists of mode "
                             f"records; got {type(entries).__name__}.")
        for sig, recs in entries.items():
            if not isinstance(recs, list):
                raise ValueError(f"entries[{sig!r}]: expected a list of mode records; got {type(recs).__name__}.")
            for i, r in enumerate(recs):
                rec = _record(r, f"entries[{sig!r}][{i}]", table.angle_bins)
                table.entries.setdefault(str(sig), {})[rec.key] = rec
        return table

    def save(self, path) -> Path:
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(self.to_dict(), indent=1))
        return path

    @classmethod
    def load(cls, path) -> ModeTable:
        """Read a table written by :meth:`save`. Every problem -- missing, a directory, unreadable,
        empty, not UTF-8 JSON, malformed records -- raises one ``ValueError("ModeTable file <path>:
        ...")``."""
        path = Path(path)
        try:
            return cls.from_dict(json.loads(read_text(path, "a ModeTable .json file (ModeTable.save)")))
        except json.JSONDecodeError as exc:
            raise ValueError(f"ModeTable file {path}: not valid JSON ({exc}).") from None
        except RecursionError:
            raise ValueError(f"ModeTable file {path}: its JSON is nested too deeply.") from None
        except ValueError as exc:
            raise ValueError(f"ModeTable file {path}: {exc}") from None


_TABLE_KEYS = ("format", "version", "resolution", "angle_bins", "entries")
_RECORD_KEYS = ("bin", "n_robots", "speed", "omega", "success", "trials", "contacts")


def _is_number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def _record(r, field: str, angle_bins: int) -> ModeRecord:
    """One mode record of a table file, every field checked (names ``field`` and the bad key)."""
    if not isinstance(r, dict):
        raise ValueError(f"{field}: malformed mode record (expected an object with the keys "
                         f"{', '.join(_RECORD_KEYS)}; got {type(r).__name__}).")
    unknown = [k for k in r if k not in _RECORD_KEYS]
    missing = [k for k in _RECORD_KEYS[:-1] if k not in r]
    if unknown or missing:
        what = f"unknown key(s) {unknown}" if unknown else f"missing key(s) {missing}"
        raise ValueError(f"{field}: malformed mode record ({what}); the keys are {', '.join(_RECORD_KEYS)}.")
    ints = {"bin": (0, angle_bins - 1), "n_robots": (1, None), "success": (0, None), "trials": (0, None)}
    for key, (lo, hi) in ints.items():
        v = r[key]
        if type(v) is not int or v < lo or (hi is not None and v > hi):
            bound = f"in [{lo}, {hi}]" if hi is not None else f">= {lo}"
            raise ValueError(f"{field}.{key}: malformed mode record (must be an int {bound}; got {v!r}).")
    for key in ("speed", "omega"):
        if not _is_number(r[key]) or not math.isfinite(r[key]):
            raise ValueError(f"{field}.{key}: malformed mode record (must be a finite number; got {r[key]!r}).")
    if r["success"] > r["trials"]:
        raise ValueError(f"{field}: malformed mode record (success {r['success']} > trials {r['trials']}).")
    contacts = r.get("contacts")
    if contacts is not None and not (isinstance(contacts, list) and all(
            isinstance(c, list) and len(c) == 2 and all(_is_number(x) and math.isfinite(x) for x in c)
            for c in contacts)):
        raise ValueError(f"{field}.contacts: malformed mode record (must be null or a list of [x, y] "
                         f"numbers; got {contacts!r:.60}).")
    key = ModeKey(r["bin"], r["n_robots"], float(r["speed"]), float(r["omega"]))
    return ModeRecord(key, r["success"], r["trials"], contacts)
