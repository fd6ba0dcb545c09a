"""Where every benchmark's results go: ``experiments/results/<stem>.json`` and ``<stem>.md``."""
from __future__ import annotations

import json
from pathlib import Path


def write_results(results_dir: Path, stem: str, result: dict, markdown: str, *, allow_nan: bool = False) -> None:
    """Write ``result`` as JSON and the markdown table beside it, creating the directory; print the
    table. Strict JSON unless ``allow_nan`` (then NaN and Infinity are written as Python's json does)."""
    results_dir.mkdir(parents=True, exist_ok=True)
    (results_dir / f"{stem}.json").write_text(json.dumps(result, indent=1, allow_nan=allow_nan) + "\n")
    (results_dir / f"{stem}.md").write_text(markdown)
    print(markdown)
