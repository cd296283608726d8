#!/usr/bin/env python3
"""Summary of the quality benchmark (benches/quality/quality.toml).

    quality_summary.py RUNS_DIR [--styles DIR] [--lock FILE] [--plot PNG]

Reads, for every scene/style/method under RUNS_DIR, what `evaluate` wrote
(metrics.json, whose `texture` section holds the texture and object measures), the
method's wall time (its stage's `duration_s` in the pipeline lock, default
RUNS_DIR/../quality.lock) and, for the budgeted baselines, their timing.json (steps done).
Prints a Markdown report:

* per case and method: Gram distance over the object per VGG layer (relu1_2, relu2_2,
  relu3_3, relu4_3) as stylized / original (below 1 = closer to the style than the
  original), KID_style (± 1.96 jackknife se), the KID of squares of the object's surface
  against squares of the style (and the original's, in brackets), the luminance-spectrum distance to the style
  (stylized / original) and the spectrum's peak period, LPIPS to the original, structure
  kept (the correlation of the band-passed luminance with the original's), short- and
  long-range consistency (LPIPS after warping; the original's own value is the floor),
  clipped object pixels, silhouette-fringe brightening, wall time (and steps);
* per method: mean and 95% confidence interval (Student t over cases);
* per baseline: in how many cases ours (and each ours_* variant) is lower (better) on relu1_2 / relu2_2 / KID;
* with RUNS_DIR/speed present, the speed-accuracy table (ours, ours_nnfm_gram and ng_noprior by
  iterations, the VGG baselines by steps) and, when matplotlib is importable, its plot
  (--plot, default RUNS_DIR/speed/speed_accuracy.png).

It also writes one contact sheet per case, RUNS_DIR/sheets/<scene>.<style>.png: rows =
style, original, per-view 2D stylizer (the refit baseline's targets), ours and its variants,
gram, nnfm,
then the other methods (ng_nomvfc, ng_sds, ng_noprior, nomvfc, sds, colour, refit);
columns = views 0, 4, 8, 12.
"""
import argparse
import json
import os
import struct
import sys
import zlib

import numpy as np

from make_styles import write_png

# "original": the untouched original renders evaluated as if stylized (runs/<scene>/<style>/original-eval,
# the DAG's eval_original stages), the reference row.
METHODS = ["original", "ours", "ours_nnfm", "ours_nnfm_gram", "ours_proj", "ours_proj80", "ours_split", "ours_nnfm_d2", "ng_nomvfc", "ng_sds", "ng_noprior", "nomvfc", "sds",
           "colour", "project", "gram", "nnfm", "refit", "gram_fast", "nnfm_fast"]
SHEET_ROWS = ["ours", "ours_nnfm", "ours_nnfm_gram", "ours_proj", "ours_split", "project", "ours_nnfm_d2", "gram", "nnfm", "ng_nomvfc", "ng_sds", "ng_noprior",
              "gram_fast", "nnfm_fast", "nomvfc", "sds", "colour", "refit"]
LAYERS = ["relu1_2", "relu2_2", "relu3_3", "relu4_3"]
T95 = {1: 12.71, 2: 4.303, 3: 3.182, 4: 2.776, 5: 2.571, 6: 2.447, 7: 2.365, 8: 2.306,
       9: 2.262, 10: 2.228, 11: 2.201, 12: 2.179, 15: 2.131, 20: 2.086, 30: 2.042}


def read_png(path):
    """8-bit RGB/RGBA PNG, any filter (style images, the refit's targets)."""
    data = open(path, "rb").read()
    assert data[:8] == b"\x89PNG\r\n\x1a\n", path
    pos, idat, w = 8, b"", None
    while pos < len(data):
        n = struct.unpack(">I", data[pos:pos + 4])[0]
        t, body = data[pos + 4:pos + 8], data[pos + 8:pos + 8 + n]
        if t == b"IHDR":
            w, h, depth, ctype = struct.unpack(">IIBB", body[:10])
            assert depth == 8 and ctype in (2, 6), f"{path}: only 8-bit RGB(A)"
            ch = 3 if ctype == 2 else 4
        elif t == b"IDAT":
            idat += body
        pos += 12 + n
    raw = np.frombuffer(zlib.decompress(idat), np.uint8).reshape(h, 1 + w * ch)
    out = np.zeros((h, w * ch), np.int32)
    for y in range(h):
        f, line = raw[y, 0], raw[y, 1:].astype(np.int32)
        prev = out[y - 1] if y else np.zeros(w * ch, np.int32)
        if f == 0:
            cur = line
        elif f == 2:
            cur = (line + prev) % 256
        elif f == 1:
            cur = np.zeros(w * ch, np.int32)
            for c in range(ch):
                cur[c::ch] = np.cumsum(line[c::ch]) % 256
        else:
            cur = np.zeros(w * ch, np.int32)
            for i in range(w * ch):
                a = cur[i - ch] if i >= ch else 0
                b = prev[i]
                c = prev[i - ch] if i >= ch else 0
                if f == 3:
                    p = (a + b) // 2
                else:
                    pa, pb, pc = abs(b - c), abs(a - c), abs(a + b - 2 * c)
                    p = a if pa <= pb and pa <= pc else (b if pb <= pc else c)
                cur[i] = (line[i] + p) % 256
        out[y] = cur
    return out.reshape(h, w, ch)[..., :3] / 255.0


def load_json(path):
    try:
        with open(path) as f:
            return json.load(f)
    except (OSError, ValueError):
        return None


def stage_seconds(lock, name):
    e = (lock or {}).get("stages", {}).get(name)
    return e["duration_s"] if e and e.get("status") == "ok" else None


def case(runs, scene, style, method, lock):
    base = os.path.join(runs, scene, style)
    m = load_json(os.path.join(base, method + "-eval", "metrics.json"))
    if m is None or "texture" not in m:
        return None
    t = m["texture"]
    g = {l["layer"]: l for l in t["gram_object"]}
    timing = load_json(os.path.join(base, method, "timing.json")) or {}
    r = {f"gram_{k}": g[k]["ratio"] for k in LAYERS}
    kid = t["kid_style"]
    sp, ob = t["spectrum"], t["object"]
    r.update({
        "kid": kid["value"], "kid_se": kid["se"],
        # KID over squares of the object's surface (absent from older metrics.json).
        "kid_obj": t.get("kid_object", {}).get("value"),
        "kid_obj_orig": t.get("kid_object_original", {}).get("value"),
        "spec": sp["distance_stylized"], "spec_ratio": sp["distance_ratio"],
        "peak": sp["peak_stylized"], "peak_style": sp["peak_style"],
        "lpips_content": m["lpips_content"],
        # Structure kept (src/metrics/structure.rs; absent from older metrics.json).
        "structure": m.get("structure_kept"),
        "short": m["short_range"]["lpips_mean"], "short_orig": m["short_range"]["original_lpips_mean"],
        "long": m["long_range"]["lpips_mean"], "long_orig": m["long_range"]["original_lpips_mean"],
        "clip": ob["clipped_stylized"], "clip_orig": ob["clipped_original"],
        "fringe": ob["fringe_brightening"],
        # Content leakage (src/metrics/leakage.rs; absent from older metrics.json).
        "leak": (m.get("leakage") or {}).get("value"),
        "leak_ci": (m.get("leakage") or {}).get("ci95"),
        "stats": ob["stats_distance_stylized"], "stats_orig": ob["stats_distance_original"],
        "gram_whole": m["gram_style"] / m["gram_style_original"] if m.get("gram_style_original") else None,
        "wall": stage_seconds(lock, f"{method}@{scene}.{style}"),
        "steps": timing.get("steps_done"),
        "views_n": m["views"],
    })
    return r


def fmt(v, d=3):
    return "-" if v is None else f"{v:.{d}f}"


def ci(xs, d=3):
    xs = np.asarray([x for x in xs if x is not None], float)
    if len(xs) == 0:
        return "-"
    if len(xs) < 2:
        return f"{xs.mean():.{d}f}"
    t = T95.get(len(xs) - 1, 2.0)
    return f"{xs.mean():.{d}f} ± {t * xs.std(ddof=1) / np.sqrt(len(xs)):.{d}f}"


COLUMNS = [("gram_relu1_2", "Gram relu1_2 (s/o)", 3), ("gram_relu2_2", "Gram relu2_2 (s/o)", 3),
           ("gram_relu3_3", "Gram relu3_3 (s/o)", 3), ("gram_relu4_3", "Gram relu4_3 (s/o)", 3),
           ("kid", "KID_style", 4), ("kid_obj", "KID object squares", 4), ("spec_ratio", "spectrum dist. (s/o)", 3),
           ("lpips_content", "LPIPS content", 3), ("structure", "structure", 3), ("short", "short-range LPIPS", 4),
           ("long", "long-range LPIPS", 4), ("clip", "clipped obj. px", 3),
           ("fringe", "fringe brightening", 4), ("leak", "content leakage", 3), ("wall", "wall s", 1)]


def case_table(res):
    print("| scene | style | method | " + " | ".join(c[1] for c in COLUMNS) + " | steps | spectrum peak period px (style) |")
    print("|---" * (3 + len(COLUMNS) + 2) + "|")
    for (sc, sty, me), r in sorted(res.items(), key=lambda kv: (kv[0][0], kv[0][1], METHODS.index(kv[0][2]))):
        vals = []
        for k, _, d in COLUMNS:
            if k == "kid" and r["kid"] is not None and r["kid_se"] is not None:
                vals.append(f"{r['kid']:.4f} ± {1.96 * r['kid_se']:.4f}")
            elif k == "kid_obj":
                vals.append(f"{fmt(r['kid_obj'], 4)} (orig {fmt(r['kid_obj_orig'], 4)})")
            elif k == "short":
                vals.append(f"{fmt(r['short'], 4)} (orig {fmt(r['short_orig'], 4)})")
            elif k == "clip":
                vals.append(f"{100 * (r['clip_orig'] or 0):.1f}% -> {100 * (r['clip'] or 0):.1f}%")
            elif k == "fringe":
                vals.append("-" if r["fringe"] is None else f"{r['fringe']:+.4f}")
            elif k == "leak" and r["leak_ci"]:
                vals.append(f"{fmt(r['leak'], d)} [{r['leak_ci'][0]:.{d}f}, {r['leak_ci'][1]:.{d}f}]")
            else:
                vals.append(fmt(r[k], d))
        per = lambda p: "-" if not p else f"{1 / p:.1f}"
        vals.append("-" if r["steps"] is None else str(r["steps"]))
        vals.append(f"{per(r['peak'])} ({per(r['peak_style'])})")
        print(f"| {sc} | {sty} | {me} | " + " | ".join(vals) + " |")


def method_table(res):
    print("Mean ± 95% CI over cases (Student t):")
    print()
    print("| method | cases | " + " | ".join(c[1] for c in COLUMNS) + " |")
    print("|---" * (2 + len(COLUMNS)) + "|")
    for me in METHODS:
        rs = [r for (_, _, m), r in res.items() if m == me]
        if rs:
            print(f"| {me} | {len(rs)} | " + " | ".join(ci([r[k] for r in rs], d) for k, _, d in COLUMNS) + " |")
    # The reference: the original renders' squares (the same in every method's metrics.json).
    orig = {(sc, sty): r["kid_obj_orig"] for (sc, sty, _), r in res.items() if r["kid_obj_orig"] is not None}
    if orig:
        print()
        print(f"KID object squares of the original renders (the value of a method that changes nothing): "
              f"{ci(list(orig.values()), 4)} over {len(orig)} cases")


# The prior benchmark (benches/quality/prior.toml, --methods prior): the default (fs), its
# ablations, the arf preset and the baselines.
PRIOR_METHODS = ["original", "fs", "fs_nomvfc", "fs_sds", "fs_dds", "fs_neg", "fs_cfg3", "fs_cfg15",
                 "sds_cfg3", "sds_cfg15", "arf", "colour", "project", "gram", "nnfm"]
WINS = {"quality": (["ours", "ours_nnfm", "ours_nnfm_gram", "ours_proj", "ours_proj80", "ours_split", "ours_nnfm_d2", "ng_noprior"],
                    ["colour", "project", "gram", "nnfm", "refit", "nomvfc", "sds", "ng_nomvfc", "ng_sds", "ng_noprior", "ours",
                     "ours_nnfm", "ours_nnfm_gram", "ours_proj", "ours_proj80"]),
        "prior": (["fs"], ["arf", "colour", "project", "gram", "nnfm", "fs_nomvfc", "fs_sds", "fs_dds", "fs_neg"])}
WHICH = "quality"


def wins(res, cases):
    keys = [("gram_relu1_2", "Gram relu1_2"), ("gram_relu2_2", "Gram relu2_2"), ("kid", "KID_style"),
            ("kid_obj", "KID object squares"), ("spec", "spectrum distance"), ("short", "short-range LPIPS"),
            ("lpips_content", "LPIPS content")]
    mines, all_others = WINS[WHICH]
    for mine in mines:
        others = all_others
        if mine == "ng_noprior":
            # The default without the prior's calls, against the baselines at its own time.
            others = ["colour", "gram_fast", "nnfm_fast", "ours_nnfm_gram"]
        for other in others:
            if other == mine:
                continue
            pairs = [(res[(sc, sty, mine)], res[(sc, sty, other)]) for sc, sty in cases
                     if (sc, sty, mine) in res and (sc, sty, other) in res]
            if not pairs:
                continue
            s = ", ".join(f"{name} {sum(o[k] is not None and b[k] is not None and o[k] < b[k] for o, b in pairs)}/{len(pairs)}"
                          for k, name in keys)
            print(f"- {mine} lower (better) than {other}: {s}")


def fit_rows(img, hh, ww):
    yi = (np.arange(hh) * img.shape[0] / hh).astype(int)
    xi = (np.arange(ww) * img.shape[1] / ww).astype(int)
    return img[yi][:, xi]


def sheet(runs, styles_dir, sc, sty, present):
    src = np.load(os.path.join(runs, sc, "source", "rgb.npy"))
    cols = list(range(0, src.shape[0], max(1, src.shape[0] // 4)))[:4]
    hh, ww = src.shape[1:3]
    style = read_png(os.path.join(styles_dir, sty + ".png"))
    rows = [np.concatenate([fit_rows(style, hh, ww)] * len(cols), 1),
            np.concatenate([src[c] for c in cols], 1)]
    names = ["style", "original"]
    refit = os.path.join(runs, sc, sty, "refit")
    if os.path.isfile(os.path.join(refit, "target_000.png")):
        rows.append(np.concatenate([read_png(os.path.join(refit, f"target_{c:03}.png")) for c in cols], 1))
        names.append("2D stylizer per view")
    for me in SHEET_ROWS:
        p = os.path.join(runs, sc, sty, me + "-views", "rgb.npy")
        if me in present and os.path.isfile(p):
            v = np.load(p)
            rows.append(np.concatenate([v[c] for c in cols], 1))
            names.append(me)
    # Crop each view to the object (the original's alpha, + 8 px; one box size for all
    # views, centred on each view's object) and enlarge it by an integer factor, so the
    # texture on a small object can be seen.
    alpha_path = os.path.join(runs, sc, "source", "alpha.npy")
    if os.path.isfile(alpha_path):
        a = np.load(alpha_path)
        a = a.reshape(a.shape[0], hh, ww)
        boxes = []
        for c in cols:
            ys, xs = np.where(a[c] > 0.05)
            if ys.size:
                boxes.append((ys.min(), ys.max() + 1, xs.min(), xs.max() + 1))
        if len(boxes) == len(cols):
            bh = min(hh, max(b[1] - b[0] for b in boxes) + 16)
            bw = min(ww, max(b[3] - b[2] for b in boxes) + 16)
            f = max(2, min(hh // bh, ww // bw))
            def crop(r):
                parts = []
                for k, (y0, y1, x0, x1) in enumerate(boxes):
                    cy = min(max((y0 + y1) // 2 - bh // 2, 0), hh - bh)
                    cx = min(max((x0 + x1) // 2 - bw // 2, 0), ww - bw)
                    parts.append(r[cy:cy + bh, k * ww + cx:k * ww + cx + bw])
                return np.concatenate(parts, 1).repeat(f, 0).repeat(f, 1)
            rows = [crop(r) for r in rows[1:]]
            rows.insert(0, np.concatenate([fit_rows(style, bh * f, bw * f)] * len(cols), 1))
            names[1] += f" (object crops x{f})"
    out = os.path.join(runs, "sheets", f"{sc}.{sty}.png")
    write_png(out, np.concatenate(rows, 0) * 255.0 + 0.5)
    print(f"contact sheet: {out} (rows: {', '.join(names)}; views {cols})", file=sys.stderr)


def speed(runs, lock, plot):
    d = os.path.join(runs, "speed")
    if not os.path.isdir(d):
        return
    pts = []
    # (method, checkpoint prefix under speed/, init stage, chunk stage)
    for me, pre, init, chunk in [("ours", "ours", "speed-init", "speed-ours"),
                                 ("ours_nnfm_gram", "ng", "speed-init-ng", "speed-ng"),
                                 ("ng_noprior", "np", "speed-init-np", "speed-np")]:
        t = stage_seconds(lock, init) or 0.0
        k = 1
        while os.path.isdir(os.path.join(d, f"{pre}-c{k}")):
            s = stage_seconds(lock, f"{chunk}@c{k}")
            st = load_json(os.path.join(d, f"{pre}-c{k}", "state.json")) or {}
            t = None if s is None or t is None else t + s
            m = load_json(os.path.join(d, f"{pre}-c{k}-eval", "metrics.json"))
            if m and "texture" in m:
                pts.append((me, st.get("iteration", k), t, m))
            k += 1
    for me in ["gram", "nnfm"]:
        tm = load_json(os.path.join(d, me, "timing.json"))
        if not tm:
            continue
        for c in tm["checkpoints"]:
            m = load_json(os.path.join(d, f"{me}-s{c['step']}-eval", "metrics.json"))
            if m and "texture" in m:
                pts.append((me, c["step"], c["elapsed_s"], m))
    if not pts:
        return
    print()
    print("Speed-accuracy (one case; ours by iterations, the VGG baselines by steps; wall s from "
          "the stage start, ours summed over its resumed chunks):")
    print()
    print("| method | iterations / steps | wall s | Gram relu1_2 (s/o) | Gram relu2_2 (s/o) | KID_style | spectrum dist. (s/o) | LPIPS content | structure | short-range LPIPS |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    rows = []
    for me, n, t, m in pts:
        tx = m["texture"]
        g = {l["layer"]: l["ratio"] for l in tx["gram_object"]}
        r = dict(method=me, n=n, t=t, g1=g["relu1_2"], g2=g["relu2_2"], kid=tx["kid_style"]["value"],
                 spec=tx["spectrum"]["distance_ratio"])
        rows.append(r)
        print(f"| {me} | {n} | {fmt(t, 1)} | {fmt(r['g1'])} | {fmt(r['g2'])} | {fmt(r['kid'], 4)} | "
              f"{fmt(r['spec'])} | {fmt(m['lpips_content'])} | {fmt(m.get('structure_kept'))} | "
              f"{fmt(m['short_range']['lpips_mean'], 4)} |")
    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        print(f"\n(no plot: matplotlib is not importable; `vendor/venv/bin/pip install matplotlib`)", file=sys.stderr)
        return
    fig, axes = plt.subplots(1, 4, figsize=(16, 3.6))
    for ax, (key, label) in zip(axes, [("g1", "Gram relu1_2, stylized / original"),
                                       ("g2", "Gram relu2_2, stylized / original"),
                                       ("kid", "KID_style"), ("spec", "spectrum distance, stylized / original")]):
        for me, colour in [("ours", "tab:blue"), ("ours_nnfm_gram", "tab:purple"), ("ng_noprior", "tab:orange"),
                           ("gram", "tab:red"), ("nnfm", "tab:green")]:
            xs = [(r["t"], r[key], r["n"]) for r in rows if r["method"] == me and r["t"] is not None and r[key] is not None]
            if xs:
                xs.sort()
                ax.plot([x[0] for x in xs], [x[1] for x in xs], "o-", color=colour, label=me)
                for x, y, n in xs:
                    ax.annotate(str(n), (x, y), fontsize=7, xytext=(3, 3), textcoords="offset points")
        ax.set_xlabel("wall time (s)")
        ax.set_title(label, fontsize=9)
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(plot, dpi=110)
    print(f"speed-accuracy plot: {plot}", file=sys.stderr)


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("runs")
    p.add_argument("--styles")
    p.add_argument("--lock")
    p.add_argument("--plot")
    p.add_argument("--methods", choices=["quality", "prior"], default="quality",
                   help="which benchmark's methods: quality.toml's or prior.toml's")
    a = p.parse_args()
    global METHODS, SHEET_ROWS, WHICH
    WHICH = a.methods
    if a.methods == "prior":
        METHODS = PRIOR_METHODS
        SHEET_ROWS = [m for m in PRIOR_METHODS if m != "original"]
    runs = a.runs.rstrip("/")
    parent = os.path.dirname(os.path.abspath(runs))
    styles_dir = a.styles or os.path.join(parent, "styles")
    lock = load_json(a.lock or os.path.join(parent, "quality.lock"))
    if lock is None:
        print("note: no pipeline lock found: wall times are unknown", file=sys.stderr)
    scenes = sorted(d for d in os.listdir(runs) if os.path.isdir(os.path.join(runs, d, "source")))
    res = {}
    for sc in scenes:
        for sty in sorted(os.listdir(os.path.join(runs, sc))):
            if not os.path.isdir(os.path.join(runs, sc, sty)):
                continue
            for me in METHODS:
                r = case(runs, sc, sty, me, lock)
                if r is not None:
                    res[(sc, sty, me)] = r
    cases = sorted({(sc, sty) for sc, sty, _ in res})
    if res:
        case_table(res)
        print()
        method_table(res)
        print()
        wins(res, cases)
    os.makedirs(os.path.join(runs, "sheets"), exist_ok=True)
    for sc, sty in cases:
        sheet(runs, styles_dir, sc, sty, {me for (s, t, me) in res if (s, t) == (sc, sty)})
    speed(runs, lock, a.plot or os.path.join(runs, "speed", "speed_accuracy.png"))


if __name__ == "__main__":
    main()
