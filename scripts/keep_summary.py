#!/usr/bin/env python3
"""Summary of the structure benchmark (benches/quality/keep.toml, issue 47).

    keep_summary.py [RUNS_DIR]        (default benches/quality/runs-keep)

Reads RUNS_DIR/<scene>/<style>/<method>-eval/metrics.json (what `evaluate` wrote) and
prints Markdown (plain Python and numpy only):

* per case, for default / motifs / shaded / unguided / loop / colour / original / preview: structure kept (the
  top-level `structure_kept`, the mean over views; "-" where a metrics.json lacks it),
  the object's Gram distance to the style at relu1_2 and relu2_2 as stylized / original
  (texture.gram_object[].ratio: below 1 is closer to the style than the untouched
  object), the object KID (texture.kid_object: squares of the object's surface against
  squares of the style), LPIPS to the original (lpips_content), long-range LPIPS (after
  warping, views far apart) and the original renders' own long-range LPIPS (its floor);
* the Done checks of issue 47 (each with its numbers and PASS / FAIL, "n/a" where the
  measure is missing): default's structure kept, mean >= 0.80 and min >= 0.70 over its
  cases; relu1_2 and relu2_2 below colour's in how many of the 15 base cases (plant,
  bob_100k, fish_10k x painting, brick, opart, astronaut, coffee) and their means there
  (<= 0.30, <= 0.60); the object KID's mean there (<= 0.23); long-range LPIPS <= 1.5 x
  the original's + 0.02 in how many cases (the failures listed), the same bound met by
  colour transfer (seam-free by construction: one colour map of the Gaussians) and the
  default against 1.5 x colour transfer's own + 0.02; the long-range excess over the
  warp's own loss (`long_range.excess_lpips_mean`) <= 1.5 x the original's excess + 0.02
  for default, colour, unguided, motifs, shaded and preview; loop minus default,
  paired over the loop's cases, each measure's mean difference with a 95% interval
  (Student t);
* issue 53's checks, of the default and of the `motifs` and `shaded` presets: edge
  recall (mean >= 0.85, min >= 0.75), motif
  contrast against the unguided end's (`unguided`, >= 0.8x in every case), both Gram
  layers below colour transfer's (>= 14 of the 15 base cases); the per-case table adds
  interior structure, edge recall, motif contrast and style texture;
* each sweep (methods control_W, guidance_W, negative_W) per case: the measures by W,
  and whether structure kept, the two Gram distances, edge recall, motif contrast and
  style texture move monotonically with W.
"""
import json
import math
import os
import sys

METHODS = ["default", "motifs", "shaded", "unguided", "loop", "colour", "original", "preview"]
BASE_SCENES = ["plant", "bob_100k", "fish_10k"]
BASE_STYLES = ["painting", "brick", "opart", "astronaut", "coffee"]
SWEEPS = ["control", "guidance", "negative"]
# Two-sided 95% Student t quantiles by degrees of freedom.
T95 = {1: 12.71, 2: 4.303, 3: 3.182, 4: 2.776, 5: 2.571, 6: 2.447, 7: 2.365, 8: 2.306,
       9: 2.262, 10: 2.228, 11: 2.201, 12: 2.179, 13: 2.160, 14: 2.145, 15: 2.131,
       20: 2.086, 30: 2.042}
# (key, column title, decimals)
MEASURES = [("structure", "structure kept", 3), ("g1", "Gram relu1_2 (s/o)", 3),
            ("g2", "Gram relu2_2 (s/o)", 3), ("kid", "object KID", 4),
            ("lpips", "LPIPS content", 3), ("long", "long-range LPIPS", 4),
            ("excess", "long-range excess", 4),
            ("interior", "interior structure", 3), ("edge", "edge recall", 3),
            ("motif", "motif contrast", 3), ("tex", "style texture", 3)]


def load_json(path):
    try:
        with open(path) as f:
            return json.load(f)
    except (OSError, ValueError):
        return None


def measures(m):
    """The measures of one metrics.json (None where absent)."""
    t = m.get("texture") or {}
    g = {x.get("layer"): x.get("ratio") for x in t.get("gram_object") or []}
    lr = m.get("long_range") or {}
    return {
        "structure": m.get("structure_kept"),
        "g1": g.get("relu1_2"),
        "g2": g.get("relu2_2"),
        "kid": (t.get("kid_object") or {}).get("value"),
        "lpips": m.get("lpips_content"),
        "long": lr.get("lpips_mean"),
        "long_orig": lr.get("original_lpips_mean"),
        "excess": lr.get("excess_lpips_mean"),
        "excess_orig": lr.get("original_excess_lpips_mean"),
        "interior": m.get("interior_structure"),
        "edge": m.get("edge_recall"),
        "motif": m.get("motif_contrast"),
        "tex": m.get("style_texture"),
    }


def read_runs(runs):
    """{(scene, style, method): measures} for every <method>-eval/metrics.json."""
    res = {}
    for sc in sorted(os.listdir(runs)):
        for sty in sorted(os.listdir(os.path.join(runs, sc))) if os.path.isdir(os.path.join(runs, sc)) else []:
            d = os.path.join(runs, sc, sty)
            if not os.path.isdir(d):
                continue
            for e in sorted(os.listdir(d)):
                if not e.endswith("-eval"):
                    continue
                m = load_json(os.path.join(d, e, "metrics.json"))
                if m is not None:
                    res[(sc, sty, e[:-len("-eval")])] = measures(m)
    return res


def fmt(v, d=3):
    return "-" if v is None else f"{v:.{d}f}"


def mean_ci(xs):
    """(mean, half-width of the 95% interval or None, n) over the values present."""
    xs = [x for x in xs if x is not None]
    if not xs:
        return None, None, 0
    mu = sum(xs) / len(xs)
    if len(xs) < 2:
        return mu, None, 1
    sd = math.sqrt(sum((x - mu) ** 2 for x in xs) / (len(xs) - 1))
    t = T95.get(len(xs) - 1) or T95[max(k for k in T95 if k <= len(xs) - 1)]
    return mu, t * sd / math.sqrt(len(xs)), len(xs)


def case_table(res, cases):
    print("## Per case")
    print()
    print("| scene | style | method | " + " | ".join(c[1] for c in MEASURES)
          + " | original's long-range LPIPS | original's long-range excess |")
    print("|---" * (5 + len(MEASURES)) + "|")
    for sc, sty in cases:
        for me in METHODS:
            r = res.get((sc, sty, me))
            if r is None:
                continue
            vals = [fmt(r[k], d) for k, _, d in MEASURES] + [fmt(r["long_orig"], 4), fmt(r["excess_orig"], 4)]
            print(f"| {sc} | {sty} | {me} | " + " | ".join(vals) + " |")
    print()


def verdict(ok):
    return "n/a" if ok is None else ("PASS" if ok else "FAIL")


def check_structure(res, cases):
    xs = [(c, res[c + ("default",)]["structure"]) for c in cases if c + ("default",) in res]
    have = [v for _, v in xs if v is not None]
    if not have:
        print(f"- structure kept (default): not in the metrics.json of its {len(xs)} cases: {verdict(None)}")
        return
    mu, lo = sum(have) / len(have), min(have)
    worst = min((v, c) for c, v in xs if v is not None)[1]
    print(f"- structure kept (default), {len(have)} of {len(xs)} cases: mean {mu:.3f} (>= 0.80: "
          f"{verdict(mu >= 0.80)}), min {lo:.3f} at {worst[0]} x {worst[1]} (>= 0.70: {verdict(lo >= 0.70)})")


def check_texture(res, cases):
    base = [(sc, sty) for sc in BASE_SCENES for sty in BASE_STYLES]
    present = [c for c in base if c + ("default",) in res]
    print(f"- the base cases present: {len(present)} of {len(base)}")
    for k, name, bound in [("g1", "Gram relu1_2 (s/o)", 0.30), ("g2", "Gram relu2_2 (s/o)", 0.60)]:
        pairs = [(res[c + ("default",)][k], res[c + ("colour",)][k]) for c in present
                 if c + ("colour",) in res]
        pairs = [(a, b) for a, b in pairs if a is not None and b is not None]
        below = sum(a < b for a, b in pairs)
        mu, hw, n = mean_ci([res[c + ("default",)][k] for c in present])
        ok = None if mu is None else mu <= bound
        iv = "" if hw is None else f" ± {hw:.3f}"
        every = [(res[c + ("default",)][k], res[c + ("colour",)][k]) for c in cases
                 if c + ("default",) in res and c + ("colour",) in res]
        every = [(a, b) for a, b in every if a is not None and b is not None]
        print(f"- {name}: default below colour in {below} of {len(pairs)} base cases "
              f"({sum(a < b for a, b in every)} of {len(every)} over every case); default's mean over the "
              f"base cases {fmt(mu)}{iv} (n = {n}; <= {bound:.2f}: {verdict(ok)})")
    mu, hw, n = mean_ci([res[c + ("default",)]["kid"] for c in present])
    iv = "" if hw is None else f" ± {hw:.4f}"
    print(f"- object KID: default's mean over the base cases {fmt(mu, 4)}{iv} (n = {n}; "
          f"<= 0.23: {verdict(None if mu is None else mu <= 0.23)})")


def within_bound(res, cases, me, key, orig_key):
    """Method `me`'s cases with `key` and `orig_key` measured: (rows, values, fails), a
    case failing where `key` > 1.5 x `orig_key` + 0.02."""
    rows, vals, fails = 0, [], []
    for c in cases:
        r = res.get(c + (me,))
        if r is None or r[key] is None or r[orig_key] is None:
            continue
        rows += 1
        vals.append(r[key])
        bound = 1.5 * r[orig_key] + 0.02
        if r[key] > bound:
            fails.append(f"{c[0]} x {c[1]} ({r[key]:.4f} > {bound:.4f})")
    return rows, vals, fails


def check_long_range(res, cases):
    rows, _, fails = within_bound(res, cases, "default", "long", "long_orig")
    print(f"- long-range LPIPS <= 1.5 x the original's + 0.02 (default): {rows - len(fails)} of {rows} cases "
          f"({verdict(None if rows == 0 else not fails)})" + (f"; fails: {', '.join(fails)}" if fails else ""))
    check_long_range_floor(res, cases)


def check_long_range_floor(res, cases):
    """The same bound met by colour transfer (one colour map of the Gaussians: the same
    geometry, view-independent colours, no seams possible) and the default against the
    bound taken from colour transfer's own long-range LPIPS: how much of the default's
    excess a seam-free result of a changed palette shares."""
    rows, colour_fails, fails = 0, [], []
    for c in cases:
        r, k = res.get(c + ("default",)), res.get(c + ("colour",))
        if r is None or k is None or None in (r["long"], r["long_orig"], k["long"]):
            continue
        rows += 1
        if k["long"] > 1.5 * r["long_orig"] + 0.02:
            colour_fails.append(f"{c[0]} x {c[1]}")
        bound = 1.5 * k["long"] + 0.02
        if r["long"] > bound:
            fails.append(f"{c[0]} x {c[1]} ({r['long']:.4f} > {bound:.4f})")
    if rows == 0:
        return
    print(f"  - colour transfer against the same bound: {rows - len(colour_fails)} of {rows} cases "
          f"(a seam-free result; fails: {', '.join(colour_fails) or 'none'})")
    print(f"  - default <= 1.5 x colour transfer's + 0.02: {rows - len(fails)} of {rows} cases"
          + (f"; fails: {', '.join(fails)}" if fails else ""))
    for me in ("default", "colour", "unguided", "motifs", "shaded", "preview"):
        check_long_range_excess(res, cases, me)


def check_long_range_excess(res, cases, me):
    """The long-range excess over the warp's own loss (`long_range.excess_lpips_mean`: the
    pair's LPIPS minus a view's round trip through its partner; src/metrics/consistency.rs)
    <= 1.5 x the original renders' own excess + 0.02, for method `me`."""
    rows, vals, fails = within_bound(res, cases, me, "excess", "excess_orig")
    if rows == 0:
        return
    print(f"- long-range excess LPIPS <= 1.5 x the original's excess + 0.02 ({me}): {rows - len(fails)} of "
          f"{rows} cases ({verdict(not fails)}; mean {sum(vals) / rows:.4f}, max {max(vals):.4f})"
          + (f"; fails: {', '.join(fails)}" if fails else ""))


def check_motifs(res, cases, me="default"):
    """Issue 53's checks of method `me`: edge recall, motif contrast against the unguided
    end, both Gram layers below colour transfer's."""
    if not any(c + (me,) in res for c in cases):
        print(f"- {me}: not evaluated yet")
        return
    edges = [(res[c + (me,)]["edge"], c) for c in cases
             if c + (me,) in res and res[c + (me,)]["edge"] is not None]
    if edges:
        mu, (lo, worst) = sum(e for e, _ in edges) / len(edges), min(edges)
        print(f"- edge recall ({me}), {len(edges)} cases: mean {mu:.3f} (>= 0.85: {verdict(mu >= 0.85)}), "
              f"min {lo:.3f} at {worst[0]} x {worst[1]} (>= 0.75: {verdict(lo >= 0.75)})")
    else:
        print(f"- edge recall ({me}): {verdict(None)}")
    pairs = [(res[c + (me,)]["motif"], res[c + ("unguided",)]["motif"], c) for c in cases
             if c + (me,) in res and c + ("unguided",) in res]
    pairs = [(a, b, c) for a, b, c in pairs if a is not None and b]
    fails = [f"{c[0]} x {c[1]} ({a / b:.2f})" for a, b, c in pairs if a < 0.8 * b]
    ratios = [a / b for a, b, _ in pairs]
    lo = f", lowest {min(ratios):.2f}" if ratios else ""
    print(f"- motif contrast >= 0.8 x the unguided end's ({me}): {len(pairs) - len(fails)} of {len(pairs)} cases"
          f"{lo} ({verdict(None if not pairs else not fails)})" + (f"; fails: {', '.join(fails)}" if fails else ""))
    base = [(sc, sty) for sc in BASE_SCENES for sty in BASE_STYLES]
    both = []
    for c in base:
        d, k = res.get(c + (me,)), res.get(c + ("colour",))
        if d and k and None not in (d["g1"], d["g2"], k["g1"], k["g2"]):
            both.append(d["g1"] < k["g1"] and d["g2"] < k["g2"])
    print(f"- relu1_2 and relu2_2 object Gram of {me} both below colour transfer's: {sum(both)} of {len(both)} base cases "
          f"(>= 14 of 15: {verdict(None if len(both) < 15 else sum(both) >= 14)})")


def check_loop(res, cases):
    pairs = [(res[c + ("loop",)], res[c + ("default",)]) for c in cases
             if c + ("loop",) in res and c + ("default",) in res]
    print(f"- loop minus default, paired over {len(pairs)} cases (mean difference, 95% interval):")
    for k, name, d in MEASURES:
        diffs = [a[k] - b[k] for a, b in pairs if a[k] is not None and b[k] is not None]
        mu, hw, n = mean_ci(diffs)
        if mu is None:
            print(f"  - {name}: -")
        elif hw is None:
            print(f"  - {name}: {mu:+.{d}f} (n = {n}: no interval)")
        else:
            print(f"  - {name}: {mu:+.{d}f} [{mu - hw:+.{d}f}, {mu + hw:+.{d}f}] (n = {n})")


def monotone(vals):
    """'rises', 'falls', 'flat' or 'not monotonic' (None values skipped; '-' if < 2)."""
    v = [x for x in vals if x is not None]
    if len(v) < 2:
        return "-"
    d = [b - a for a, b in zip(v, v[1:])]
    if all(x == 0 for x in d):
        return "flat"
    if all(x >= 0 for x in d):
        return "rises"
    if all(x <= 0 for x in d):
        return "falls"
    return "not monotonic"


def sweeps(res, cases):
    print("## Sweeps")
    if not any(me.startswith(tuple(k + "_" for k in SWEEPS)) for _, _, me in res):
        print()
        print("(none evaluated yet)")
    for sc, sty in cases:
        for key in SWEEPS:
            pts = sorted((float(me[len(key) + 1:]), me) for (s, t, me) in res
                         if (s, t) == (sc, sty) and me.startswith(key + "_") and is_number(me[len(key) + 1:]))
            if not pts:
                continue
            print()
            print(f"### {sc} x {sty}: synthesis.{key}")
            print()
            print(f"| {key} | " + " | ".join(c[1] for c in MEASURES) + " |")
            print("|---" * (1 + len(MEASURES)) + "|")
            rows = [res[(sc, sty, me)] for _, me in pts]
            for (w, _), r in zip(pts, rows):
                print(f"| {w:g} | " + " | ".join(fmt(r[k], d) for k, _, d in MEASURES) + " |")
            print()
            notes = [f"{name} {monotone([r[k] for r in rows])}" for k, name, _ in MEASURES
                     if k in ("structure", "g1", "g2", "edge", "motif", "tex")]
            print(f"As {key} grows: " + "; ".join(notes) + ".")


def is_number(s):
    try:
        float(s)
        return True
    except ValueError:
        return False


def main():
    args = sys.argv[1:]
    if len(args) > 1 or (args and args[0].startswith("-")):
        sys.exit(__doc__)
    runs = (args[0] if args else "benches/quality/runs-keep").rstrip("/")
    if not os.path.isdir(runs):
        sys.exit(f"{runs}: no such directory (run the DAG first: pipeline run --dag benches/quality/keep.toml)")
    res = read_runs(runs)
    if not res:
        sys.exit(f"{runs}: no <scene>/<style>/<method>-eval/metrics.json yet")
    cases = sorted({(sc, sty) for sc, sty, _ in res})
    print(f"# The structure benchmark: {len(cases)} cases, {len(res)} evaluations ({runs})")
    print()
    case_table(res, cases)
    print("## The Done checks of issue 47")
    print()
    check_structure(res, cases)
    check_texture(res, cases)
    check_long_range(res, cases)
    check_loop(res, cases)
    print()
    print("## The Done checks of issue 53")
    print()
    check_motifs(res, cases)
    check_motifs(res, cases, "motifs")
    check_motifs(res, cases, "shaded")
    print()
    sweeps(res, cases)


if __name__ == "__main__":
    main()
