#!/usr/bin/env bash
# Headless Chromium for the test that opens evaluate's report.html and checks that its
# images decode. Installed from Debian's packages when missing and we are root with
# apt-get; otherwise a note (the test then says SKIPPED, or fails under CI=true).
set -uo pipefail
for c in chromium chromium-browser google-chrome; do
  command -v "$c" >/dev/null 2>&1 && exit 0
done
if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then
  echo "setup: installing chromium (Debian package) for the report test"
  export DEBIAN_FRONTEND=noninteractive
  (apt-get update -qq && apt-get install -y -qq --no-install-recommends chromium) >/dev/null 2>&1 \
    || echo "setup: WARNING: could not install chromium; the report test will be skipped"
else
  echo "setup: note: chromium is not installed (apt-get install chromium); the report test will be skipped"
fi
exit 0
