#!/bin/sh
# The install steps of the Docker image, shared by the Dockerfile and by tests/project/test_docker.py, which runs them in a
# fresh virtual environment in CI (no Docker engine there) and then starts the image's default command.
#
#   docker-steps.sh deps      torch (from TORCH_INDEX), then the dependencies listed in pyproject.toml (and EXTRAS),
#                             read from pyproject.toml alone: this layer is rebuilt only when they change
#   docker-steps.sh package   colonlight itself from the source tree in the working directory (no dependencies:
#                             they are all there), with its package data (the default weights); then a smoke check
#   docker-steps.sh user      the non-root user that runs the image and its writable /data (image only: root)
#
# Environment: PYTHON (default python3), TORCH_VERSION (default 2.13.0), TORCH_INDEX (a pip index URL such as
# https://download.pytorch.org/whl/cpu; empty: pip's configured index), EXTRAS (comma-separated extras, e.g. cluster),
# APP_USER / APP_UID (default colonlight / 10001), DATA_DIR (default /data).
set -eu

PYTHON=${PYTHON:-python3}
TORCH_VERSION=${TORCH_VERSION:-2.13.0}
TORCH_INDEX=${TORCH_INDEX:-}
EXTRAS=${EXTRAS:-}

pip_install() {
    "$PYTHON" -m pip install --no-cache-dir --disable-pip-version-check --no-input "$@"
}

case "${1:-}" in
deps)
    # torch first, alone, from the chosen index: CPU-only by default, a CUDA build with another index. The
    # requirements below ask for a range this torch satisfies, so pip keeps it.
    if [ -n "$TORCH_INDEX" ]; then
        pip_install --index-url "$TORCH_INDEX" "torch==$TORCH_VERSION"
    else
        pip_install "torch==$TORCH_VERSION"
    fi
    requirements=$(mktemp)
    "$PYTHON" - "$EXTRAS" >"$requirements" <<'PY'
import sys
import tomllib

with open("pyproject.toml", "rb") as fh:
    project = tomllib.load(fh)["project"]
extras = [e.strip() for e in sys.argv[1].split(",") if e.strip()]
optional = project.get("optional-dependencies", {})
missing = [e for e in extras if e not in optional]
if missing:
    sys.exit(f"pyproject.toml has no optional-dependencies {missing} (asked for by EXTRAS={sys.argv[1]!r})")
for req in project.get("dependencies", []) + [r for e in extras for r in optional[e]]:
    if not req.startswith(project["name"]):  # an extra naming another extra of this project
        print(req)
PY
    pip_install --requirement "$requirements"
    rm -f "$requirements"
    ;;
package)
    pip_install --no-deps .
    "$PYTHON" -m pip check
    # The weights in the source tree must have been installed with the package (package data), not left behind.
    "$PYTHON" -P - <<'PY'
import sys
from pathlib import Path

import colonlight

source = sorted(p.name for p in Path("colonlight/weights").glob("*.safetensors"))
installed = sorted(p.name for p in (Path(colonlight.__file__).parent / "weights").glob("*.safetensors"))
if source != installed:
    sys.exit(f"weights in the source tree {source} but installed {installed}: check [tool.setuptools.package-data]")
print(f"colonlight {colonlight.__version__} installed; default weights: {', '.join(installed) or 'none shipped'}")
PY
    ;;
user)
    APP_USER=${APP_USER:-colonlight}
    APP_UID=${APP_UID:-10001}
    DATA_DIR=${DATA_DIR:-/data}
    groupadd --system --gid "$APP_UID" "$APP_USER"
    useradd --system --uid "$APP_UID" --gid "$APP_UID" --create-home --home-dir "/home/$APP_USER" \
        --shell /usr/sbin/nologin "$APP_USER"
    mkdir -p "$DATA_DIR"
    chown "$APP_USER:$APP_USER" "$DATA_DIR"
    ;;
*)
    echo "usage: $0 deps|package|user" >&2
    exit 2
    ;;
esac
