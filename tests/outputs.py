"""What a run wrote, as bytes, for tests that compare two runs' outputs (local vs cluster, before vs after a resume)."""

from __future__ import annotations

import json
from pathlib import Path


def tree_bytes(root: Path) -> dict[str, bytes]:
    """Every file under ``root`` by its relative path."""
    return {p.relative_to(root).as_posix(): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


def output_bytes(root: Path) -> dict[str, bytes]:
    """Every output byte of an `enhance` run except the manifest's run timings (which differ run to run)."""
    files = tree_bytes(root)
    manifest = json.loads(files.pop("manifest.json"))
    for c in manifest["clips"]:
        c.pop("seconds"), c.pop("skipped", None)
    files["manifest.json"] = json.dumps(manifest, sort_keys=True).encode()
    return files
