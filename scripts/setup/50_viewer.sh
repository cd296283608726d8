#!/usr/bin/env bash
# The report's interactive 3D viewer: Spark (@sparkjsdev/spark) and three.js from the npm
# registry at the exact versions of scripts/viewer/package-lock.json, bundled with
# scripts/viewer/entry.js by esbuild (pinned there too) into one classic script,
# vendor/viewer/viewer.js, which `evaluate` inlines into report.html (src/metrics/viewer.rs).
# The bundle ends with the packages' licence texts.
#
# Idempotent: does nothing when vendor/viewer/viewer.js was built from the same package
# files. Touches nothing outside vendor/viewer. Without Node.js and npm it prints a note:
# reports then say the viewer is not installed, and the browser test says SKIPPED (or
# fails under CI=true).
set -euo pipefail
root="$1"
src="$root/scripts/viewer"
dest="$root/vendor/viewer"
files="package.json package-lock.json entry.js"

same=1
for f in $files; do
  cmp -s "$src/$f" "$dest/built-from/$f" || same=0
done
if [ "$same" = 1 ] && [ -f "$dest/viewer.js" ]; then
  exit 0
fi
if ! command -v npm >/dev/null 2>&1 || ! command -v node >/dev/null 2>&1; then
  echo "setup: note: Node.js and npm are not installed; the report's 3D viewer is not set up" \
    "(install nodejs and npm, then rerun scripts/setup.sh)"
  exit 0
fi
echo "setup: installing the report's 3D viewer (Spark, three.js) into vendor/viewer"
mkdir -p "$dest"
rm -rf "$dest/built-from" "$dest/viewer.js"
for f in $files; do
  cp "$src/$f" "$dest/$f"
done
(cd "$dest" && npm ci --no-audit --no-fund --ignore-scripts --loglevel=error \
  --omit-lockfile-registry-resolved)
tmp="$dest/viewer.js.tmp"
"$dest/node_modules/.bin/esbuild" "$dest/entry.js" --bundle --format=iife \
  --global-name=FantasyViewerLib --minify --legal-comments=eof --log-level=error \
  --outfile="$tmp"
{
  echo
  echo "/*! Licences of the bundled packages:"
  for p in @sparkjsdev/spark three fflate; do
    pj="$dest/node_modules/$p/package.json"
    [ -f "$pj" ] || continue
    echo
    node -e 'const p = require(process.argv[1]); console.log(`${p.name} ${p.version} (${p.license})`)' "$pj"
    cat "$dest/node_modules/$p/LICENSE"
  done
  echo "*/"
} >>"$tmp"
if grep -qi -e '</script' -e '<!--' "$tmp"; then
  echo "setup: the viewer bundle contains </script or <!-- and cannot be inlined" >&2
  exit 1
fi
mv "$tmp" "$dest/viewer.js"
mkdir -p "$dest/built-from"
for f in $files; do
  cp "$src/$f" "$dest/built-from/$f"
done
