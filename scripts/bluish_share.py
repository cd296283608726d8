#!/usr/bin/env python3
"""Share of an object's pixels that are bluish (docs/texture-term.md, "Plant x opart: the
off-palette hues"): over all views of a views artifact, pixels with alpha > 0.5, colour
un-premultiplied (rgb / alpha), with B > R + 0.08 and G > R. The op-art style (red, white,
black) has none.

    vendor/venv/bin/python scripts/bluish_share.py VIEWS_DIR [VIEWS_DIR ...]
"""
import os
import sys

import numpy as np


def bluish_share(views):
    rgb = np.load(os.path.join(views, "rgb.npy"))
    alpha = np.load(os.path.join(views, "alpha.npy"))
    obj = alpha > 0.5
    px = rgb[obj] / np.maximum(alpha[obj][:, None], 1e-3)
    return float(((px[:, 2] > px[:, 0] + 0.08) & (px[:, 1] > px[:, 0])).mean())


if __name__ == "__main__":
    if len(sys.argv) < 2:
        sys.exit(__doc__)
    for d in sys.argv[1:]:
        print(f"{d}: bluish {bluish_share(d):.4f}")
