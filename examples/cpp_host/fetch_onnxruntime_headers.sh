#!/usr/bin/env bash
# ONNX Runtime's C and C++ headers into DEST/include (DEST/include/onnxruntime_cxx_api.h ...), from Debian's
# libonnxruntime-dev package, fetched with apt-get (no root needed for this step, nothing installed system-wide).
#
# pip's onnxruntime wheel ships the shared library but not the headers. Debian packages them from trixie on; on an
# older Debian (bookworm) the package is fetched from trixie with a private apt state (the machine's own mirror,
# read from its apt sources, with the suite changed), so the machine's apt configuration is left as it is.
# The headers' API version (1.21) is older than the wheel's library (1.32 here): ONNX Runtime keeps its C API
# backward compatible, so a host built against older headers runs on a newer library.
set -euo pipefail
DEST=$(realpath -m "${1:?usage: fetch_onnxruntime_headers.sh DEST}")
SUITE=${ONNXRUNTIME_HEADERS_SUITE:-trixie}
if [ -f "$DEST/include/onnxruntime_cxx_api.h" ]; then exit 0; fi
command -v apt-get >/dev/null && command -v dpkg-deb >/dev/null || {
    echo "fetch_onnxruntime_headers: needs apt-get and dpkg-deb (Debian or Ubuntu)" >&2; exit 1; }
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
cd "$work"
mirror=$(sed -n 's/^URIs:[[:space:]]*\([^[:space:]]*\).*/\1/p' /etc/apt/sources.list.d/*.sources 2>/dev/null | head -n1)
[ -n "$mirror" ] || mirror=$(awk '$1 == "deb" && $2 !~ /^\[/ {print $2; exit}' /etc/apt/sources.list 2>/dev/null)
[ -n "$mirror" ] || { echo "fetch_onnxruntime_headers: no Debian mirror in the apt sources" >&2; exit 1; }
mkdir -p lists/partial cache/archives/partial parts
echo "deb $mirror $SUITE main" > sources.list
apt=(apt-get -q -o Dir::Etc::SourceList="$work/sources.list" -o Dir::Etc::SourceParts="$work/parts"
     -o Dir::State::Lists="$work/lists" -o Dir::Cache="$work/cache" -o Dir::State::Status=/var/lib/dpkg/status
     -o APT::Sandbox::User="$(id -un)" -o Debug::NoLocking=1)
# The machine's own suite first (trixie or later packages it), else the private trixie lists.
if ! (apt-get download -q -o APT::Sandbox::User="$(id -un)" libonnxruntime-dev >/dev/null 2>&1); then
    "${apt[@]}" update >/dev/null
    "${apt[@]}" download libonnxruntime-dev >/dev/null
fi
dpkg-deb -x libonnxruntime-dev_*.deb root
mkdir -p "$DEST"
rm -rf "$DEST/include.tmp"
cp -r root/usr/include/onnxruntime "$DEST/include.tmp"
mv "$DEST/include.tmp" "$DEST/include"
echo "ONNX Runtime headers ($(dpkg-deb -f libonnxruntime-dev_*.deb Version)) in $DEST/include"
