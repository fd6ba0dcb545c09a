"""Reading a schedule back from a ``jaxplan pusharound`` result.json."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from jaxplan.pusharound.push import PushTask

__all__ = ["load_schedule"]


def load_schedule(result) -> list:
    """The schedule of a ``jaxplan pusharound`` result.json (a path or the parsed dict) as a list of
    ``search.ScheduledPush``, ready for :func:`execute_schedule` (e.g. to replay a ``--no-execute``
    plan). Values carry the file's rounding (1e-6)."""
    from jaxplan.pusharound.search import ScheduledPush  # noqa: PLC0415 (search is heavier; load on use)

    data = json.loads(Path(result).read_text()) if not isinstance(result, dict) else result
    if not isinstance(data, dict) or data.get("format") != "jaxplan.pusharound.result":
        raise ValueError("result: not a jaxplan pusharound result.json (format 'jaxplan.pusharound.result').")
    out = []
    for k, p in enumerate(data.get("schedule", [])):
        try:
            task = PushTask(int(p["movable"]), np.asarray(p["contacts_body"], np.float64),
                            np.asarray(p["directions_body"], np.float64), np.asarray(p["active"], bool),
                            np.asarray(p["velocity"], np.float64), float(p["duration_s"]))
            out.append(ScheduledPush(task, tuple(p["gap"]) if p.get("gap") is not None else None, float(p["cost"]),
                                     np.asarray(p["poses_before"], np.float64),
                                     np.asarray(p["poses_after"], np.float64),
                                     np.asarray(p["robots_before"], np.float64),
                                     np.asarray(p["robots_after"], np.float64)))
        except (KeyError, TypeError, ValueError) as e:
            raise ValueError(f"schedule[{k}]: malformed push record ({type(e).__name__}: {e}).") from None
    return out
