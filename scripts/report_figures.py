"""Copy the plots of a `colonlight evaluate` report into image files (for the README).

    python scripts/report_figures.py REPORT.html OUT_DIR [--clip NAME]

The report embeds every plot as a base64 data URI, so it stays one self-contained file; this writes the success
bars as ``eval_success.png`` and one clip's luminance/gamma plot as ``eval_luminance.png`` (the first clip unless
``--clip`` names another), decoded byte for byte, so the README shows exactly what the report shows.
"""

from __future__ import annotations

import argparse
import base64
import html
import re
from pathlib import Path

_IMG = re.compile(r'<img alt="([^"]*)" src="data:image/png;base64,([A-Za-z0-9+/=]+)">')


def images(report: str) -> dict[str, bytes]:
    """alt text -> PNG bytes of every PNG embedded in the report."""
    return {html.unescape(alt): base64.b64decode(data) for alt, data in _IMG.findall(report)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("report", type=Path)
    parser.add_argument("out_dir", type=Path)
    parser.add_argument("--clip", help="clip whose luminance plot to copy (default: the first)")
    args = parser.parse_args()
    found = images(args.report.read_text(encoding="utf-8"))
    curves = [alt for alt in found if alt.startswith("luminance of ")]
    if "success bars" not in found or not curves:
        raise SystemExit(f"{args.report}: no success bars or luminance plots found")
    clip = f"luminance of {args.clip}" if args.clip else curves[0]
    if clip not in found:
        raise SystemExit(f"{args.report}: no plot for clip {args.clip!r}")
    args.out_dir.mkdir(parents=True, exist_ok=True)
    for name, alt in (("eval_success.png", "success bars"), ("eval_luminance.png", clip)):
        (args.out_dir / name).write_bytes(found[alt])
        print(args.out_dir / name)


if __name__ == "__main__":
    main()
