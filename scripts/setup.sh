#!/usr/bin/env bash
# Set-up for a fresh machine: everything fantasystyle needs that is not Rust source.
# Idempotent: each step skips what is already in place. Everything lands in vendor/
# (git-ignored); nothing fetched here is committed.
#
#   vendor/venv/                 Python (numpy, onnx) for conversion and reference scripts
#   vendor/onnxruntime/          the onnxruntime 1.31.1 shared library for this machine,
#                                from the PyPI onnxruntime wheel of its platform:
#                                libonnxruntime.so.1.31.1 (Linux x86_64, aarch64) or
#                                libonnxruntime.1.31.1.dylib (macOS arm64)
#   vendor/models/...            ONNX graphs and weights made by scripts/setup/*
#   vendor/venv/bin/snakemake    pinned Snakemake for `pipeline export --snakemake` (40_snakemake.sh)
#   vendor/viewer/               the report's 3D viewer bundle (50_viewer.sh, npm)
#   vendor/splat-transform/      an independent reader of the written scenes (55_splat_transform.sh, npm)
#
# Steps under scripts/setup/ run in name order; each is an executable shell or Python
# script that receives the repo root as $1 and uses vendor/venv/bin/python.
#
#   scripts/setup.sh --print-ort-wheel [OS ARCH]
# prints the wheel platform tag and library file chosen for this machine (or for the
# given `uname -s` and `uname -m` values) and exits, fetching nothing; exit status 2
# with the reason where no wheel fits.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
vendor="$root/vendor"
py="${PYTHON:-python3}"
ort_version=1.31.1

# ort_target OS ARCH [MACOS_VERSION]: sets ort_platform (PyPI wheel platform tag) and
# ort_lib_name (the library inside the wheel, as the runtime looks for it), or prints
# why no wheel fits and returns 2.
ort_target() {
  local os="$1" arch="$2" macos="${3:-}"
  case "$os/$arch" in
    Linux/x86_64 | Linux/amd64)
      ort_platform=manylinux_2_28_x86_64
      ort_lib_name="libonnxruntime.so.$ort_version" ;;
    Linux/aarch64 | Linux/arm64)
      ort_platform=manylinux_2_28_aarch64
      ort_lib_name="libonnxruntime.so.$ort_version" ;;
    Darwin/arm64 | Darwin/aarch64)
      if [ -n "$macos" ] && [ "${macos%%.*}" -lt 14 ]; then
        echo "setup: onnxruntime $ort_version's macOS arm64 wheel needs macOS 14 or later (this is $macos);" >&2
        echo "       update macOS, or build onnxruntime $ort_version from source and set FANTASYSTYLE_ORT_LIB to its library" >&2
        return 2
      fi
      ort_platform=macosx_14_0_arm64
      ort_lib_name="libonnxruntime.$ort_version.dylib" ;;
    Darwin/x86_64)
      echo "setup: PyPI has no onnxruntime $ort_version wheel for Intel macOS (the last one is 1.23.2, older than" >&2
      echo "       the onnxruntime API 31 this build needs); build onnxruntime $ort_version from source and set" >&2
      echo "       FANTASYSTYLE_ORT_LIB to its libonnxruntime.$ort_version.dylib, or use an arm64 Mac or Linux" >&2
      return 2 ;;
    *)
      echo "setup: no onnxruntime $ort_version wheel for $os $arch (this set-up supports Linux x86_64 and aarch64" >&2
      echo "       with glibc >= 2.28, and macOS 14+ arm64); build onnxruntime $ort_version from source and set" >&2
      echo "       FANTASYSTYLE_ORT_LIB to its shared library" >&2
      return 2 ;;
  esac
}

this_os="$(uname -s)"
this_arch="$(uname -m)"
this_macos=""
if [ "$this_os" = Darwin ] && command -v sw_vers >/dev/null; then
  this_macos="$(sw_vers -productVersion)"
fi

if [ "${1:-}" = --print-ort-wheel ]; then
  if [ $# -ge 3 ]; then
    ort_target "$2" "$3" "${4:-}" || exit 2
  else
    ort_target "$this_os" "$this_arch" "$this_macos" || exit 2
  fi
  echo "onnxruntime==$ort_version platform=$ort_platform library=$ort_lib_name"
  exit 0
fi

mkdir -p "$vendor"
if [ ! -x "$vendor/venv/bin/python" ]; then
  echo "setup: creating vendor/venv"
  "$py" -m venv "$vendor/venv"
fi
if ! "$vendor/venv/bin/python" -c 'import numpy, onnx' 2>/dev/null; then
  echo "setup: installing numpy and onnx into vendor/venv"
  "$vendor/venv/bin/pip" install -q --disable-pip-version-check -r "$root/scripts/requirements.txt"
fi

ort_target "$this_os" "$this_arch" "$this_macos" || exit 2
if [ "$this_os" = Linux ] && glibc="$(getconf GNU_LIBC_VERSION 2>/dev/null)"; then
  # "glibc 2.36": the manylinux_2_28 wheels need 2.28 or later.
  v="${glibc##* }"
  if [ "${v%%.*}" -eq 2 ] && [ "${v#*.}" -lt 28 ] 2>/dev/null; then
    echo "setup: the onnxruntime $ort_version wheels need glibc 2.28 or later (this machine has $v);" >&2
    echo "       build onnxruntime $ort_version from source and set FANTASYSTYLE_ORT_LIB to its library" >&2
    exit 2
  fi
fi
ort_lib="$vendor/onnxruntime/$ort_lib_name"
if [ ! -f "$ort_lib" ]; then
  echo "setup: fetching onnxruntime $ort_version ($ort_platform wheel from PyPI) for $ort_lib_name"
  tmp="$(mktemp -d)"
  "$vendor/venv/bin/pip" download -q --disable-pip-version-check --no-deps --only-binary=:all: \
    --platform "$ort_platform" --python-version 3.11 --implementation cp \
    "onnxruntime==$ort_version" -d "$tmp"
  mkdir -p "$vendor/onnxruntime"
  "$vendor/venv/bin/python" - "$tmp"/onnxruntime-*.whl "$vendor/onnxruntime" "$ort_lib_name" <<'PY'
import sys, zipfile, os
whl, out, name = sys.argv[1], sys.argv[2], sys.argv[3]
with zipfile.ZipFile(whl) as z:
    found = [n for n in z.namelist() if os.path.basename(n) == name]
    if not found:
        sys.exit(f"setup: {os.path.basename(whl)} holds no {name}")
    for n in z.namelist():
        base = os.path.basename(n)
        if base.startswith("libonnxruntime") and (".so" in base or base.endswith(".dylib")):
            with z.open(n) as src, open(os.path.join(out, base), "wb") as dst:
                dst.write(src.read())
PY
  rm -rf "$tmp"
fi

for step in "$root"/scripts/setup/*; do
  [ -x "$step" ] || continue
  echo "setup: $(basename "$step")"
  "$step" "$root"
done
echo "setup: done"
