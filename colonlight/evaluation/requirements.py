"""Which packages of the ``eval`` extra an evaluation needs, checked without importing any of them.

Apart from the runner because the runner's own imports (the tracker's SE(3) maths on scipy, the SSIM on
scikit-image) need the extra: the check has to be importable where the extra is missing, so that ``colonlight
evaluate`` can say what to install in one line instead of failing on an import.
"""

from __future__ import annotations

import importlib.util

from ..errors import MissingExtraError
from ..extras import install_command

#: import name -> distribution, for what every evaluation needs and what COLMAP and the trajectory errors add
ALWAYS_NEEDED = {"skimage": "scikit-image", "matplotlib": "matplotlib", "scipy": "scipy"}
COLMAP_NEEDED = {"pycolmap": "pycolmap", "evo": "evo"}


def missing_extras(colmap: bool = True) -> list[str]:
    """Distributions of the ``eval`` extra this evaluation needs that are not installed."""
    needed = {**ALWAYS_NEEDED, **(COLMAP_NEEDED if colmap else {})}
    return [dist for module, dist in needed.items() if importlib.util.find_spec(module) is None]


def require_extras(colmap: bool = True) -> None:
    """:class:`ColonlightError` (one line) naming what to install when part of the ``eval`` extra is missing."""
    missing = missing_extras(colmap)
    if missing:
        raise MissingExtraError(
            f"colonlight evaluate needs {', '.join(missing)}: {install_command('eval')}"
            + (" (or run with --no-colmap)" if set(COLMAP_NEEDED.values()) & set(missing) else "")
        )


__all__ = ["ALWAYS_NEEDED", "COLMAP_NEEDED", "missing_extras", "require_extras"]
