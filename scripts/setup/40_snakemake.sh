#!/usr/bin/env bash
# Snakemake (pinned, from PyPI) into vendor/venv, for `pipeline export --snakemake` and
# its integration tests. Idempotent: does nothing when the pinned version is there.
# Touches nothing but vendor/venv's site-packages and bin/.
set -euo pipefail
root="$1"
want="9.27.1"
venv="$root/vendor/venv"
have="$("$venv/bin/snakemake" --version 2>/dev/null || true)"
if [ "$have" = "$want" ]; then
  exit 0
fi
echo "setup: installing snakemake $want into vendor/venv${have:+ (found $have)}"
"$venv/bin/pip" install -q --disable-pip-version-check "snakemake==$want"
got="$("$venv/bin/snakemake" --version)"
if [ "$got" != "$want" ]; then
  echo "setup: snakemake --version says $got, expected $want" >&2
  exit 1
fi
