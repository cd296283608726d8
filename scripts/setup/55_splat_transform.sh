#!/usr/bin/env bash
# An independent reader of the scenes we write: PlayCanvas's splat-transform
# (npm @playcanvas/splat-transform, pinned in scripts/splat-transform/package-lock.json),
# installed into vendor/splat-transform. The formats read-back test
# (tests/integration/formats.rs) converts runs' scene.ply, scene.splat and scene.spz to
# CSV with it and renders what it read.
#
# Idempotent: does nothing when vendor/splat-transform was installed from the same
# package files. Touches nothing outside vendor/splat-transform. Without Node.js and npm
# it prints a note; the read-back test then says SKIPPED (or fails under CI=true).
set -euo pipefail
root="$1"
src="$root/scripts/splat-transform"
dest="$root/vendor/splat-transform"
files="package.json package-lock.json"

same=1
for f in $files; do
  cmp -s "$src/$f" "$dest/built-from/$f" || same=0
done
if [ "$same" = 1 ] && [ -x "$dest/node_modules/.bin/splat-transform" ]; then
  exit 0
fi
if ! command -v npm >/dev/null 2>&1 || ! command -v node >/dev/null 2>&1; then
  echo "setup: note: Node.js and npm are not installed; the formats read-back reader is not set up" \
    "(install nodejs and npm, then rerun scripts/setup.sh)"
  exit 0
fi
echo "setup: installing splat-transform (the formats read-back test's reader) into vendor/splat-transform"
mkdir -p "$dest"
rm -rf "$dest/built-from"
for f in $files; do
  cp "$src/$f" "$dest/$f"
done
(cd "$dest" && npm ci --no-audit --no-fund --ignore-scripts --loglevel=error)
"$dest/node_modules/.bin/splat-transform" --version >/dev/null 2>&1
mkdir -p "$dest/built-from"
for f in $files; do
  cp "$src/$f" "$dest/built-from/$f"
done
