#!/usr/bin/env bash
# Set-up for a fresh machine: everything fantasystyle needs that is not Rust source.
# Idempotent: each step skips what is already in place. Everything lands in vendor/
# (git-ignored); nothing fetched here is committed.
#
#   vendor/venv/                 Python (numpy, onnx) for conversion and reference scripts
#   vendor/onnxruntime/          libonnxruntime.so.1.31.1 from the PyPI onnxruntime wheel
#   vendor/models/...            ONNX graphs and weights made by scripts/setup/*
#   vendor/venv/bin/snakemake    pinned Snakemake for `pipeline export --snakemake` (40_snakemake.sh)
#
# Steps under scripts/setup/ run in name order; each is an executable shell or Python
# script that receives the repo root as $1 and uses vendor/venv/bin/python.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
vendor="$root/vendor"
mkdir -p "$vendor"
py="${PYTHON:-python3}"

if [ ! -x "$vendor/venv/bin/python" ]; then
  echo "setup: creating vendor/venv"
  "$py" -m venv "$vendor/venv"
fi
if ! "$vendor/venv/bin/python" -c 'import numpy, onnx' 2>/dev/null; then
  echo "setup: installing numpy and onnx into vendor/venv"
  "$vendor/venv/bin/pip" install -q --disable-pip-version-check -r "$root/scripts/requirements.txt"
fi

ort_lib="$vendor/onnxruntime/libonnxruntime.so.1.31.1"
if [ ! -f "$ort_lib" ]; then
  echo "setup: fetching onnxruntime 1.31.1 (PyPI wheel) for its shared library"
  tmp="$(mktemp -d)"
  "$vendor/venv/bin/pip" download -q --disable-pip-version-check --no-deps --only-binary=:all: \
    --platform manylinux_2_28_x86_64 --python-version 3.11 --implementation cp \
    onnxruntime==1.31.1 -d "$tmp"
  mkdir -p "$vendor/onnxruntime"
  "$vendor/venv/bin/python" - "$tmp"/onnxruntime-*.whl "$vendor/onnxruntime" <<'PY'
import sys, zipfile, os
whl, out = sys.argv[1], sys.argv[2]
with zipfile.ZipFile(whl) as z:
    for n in z.namelist():
        base = os.path.basename(n)
        if base.startswith("libonnxruntime") and ".so" in base:
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
