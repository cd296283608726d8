#!/usr/bin/env bash
# Numpy reference features of the real VGG16 weights (made by step 30) for the baselines'
# golden test: vendor/models/lpips/vgg16-golden/{input,relu1_2,relu2_2,relu3_3,relu4_3}.npy.
# Idempotent; skipped when the weights are absent.
set -euo pipefail
root="$1"
w="$root/vendor/models/lpips/vgg16"
out="$root/vendor/models/lpips/vgg16-golden"
if [ ! -f "$w/conv9_weight.npy" ]; then
  echo "35_vgg_golden: $w has no VGG16 weights; skipped"
  exit 0
fi
if [ -f "$out/relu4_3.npy" ]; then
  exit 0
fi
"$root/vendor/venv/bin/python" "$root/scripts/reference/vgg_ref.py" \
  --weights "$w" --out "$out.tmp" --height 64 --width 48
rm -rf "$out"
mv "$out.tmp" "$out"
