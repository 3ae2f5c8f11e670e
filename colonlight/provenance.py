"""What made an output: versions of colonlight and the libraries whose behaviour shapes the pixels."""

from __future__ import annotations

import platform
from functools import lru_cache
from importlib.metadata import PackageNotFoundError, version


def distribution_versions(names: tuple[str, ...]) -> dict[str, str]:
    """Installed version of each distribution, ``"not installed"`` where absent."""
    out = {}
    for dist in names:
        try:
            out[dist] = version(dist)
        except PackageNotFoundError:
            out[dist] = "not installed"
    return out


@lru_cache(maxsize=1)
def library_versions() -> dict[str, str]:
    """Versions of colonlight, Python and the decoding/encoding/compute libraries."""
    out = {"python": platform.python_version()}
    out.update(distribution_versions(("colonlight", "torch", "av", "opencv-python-headless", "numpy")))
    try:
        import av

        out["ffmpeg (PyAV)"] = (
            ".".join(str(x) for x in av.ffmpeg_version_info)
            if isinstance(av.ffmpeg_version_info, tuple)
            else str(av.ffmpeg_version_info)
        )
    except Exception:  # noqa: BLE001 - informational only
        pass
    return out
