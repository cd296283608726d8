#!/usr/bin/env python3
"""Independent numpy reference for one CSD step (FantasyStyle Sec. 4, CSD; src/csd.rs), and
the golden files under tests/golden/csd/.

Everything is computed here from the formulas, in float64, without the Rust code:

* the noise schedule: Stable Diffusion's scaled-linear alphas_cumprod (also written as
  alphas_cumprod.npy, for the mvfc-filter stage test);
* the timestep sets (src/scheduler.rs TimestepSet: `count` steps from t_min to t_max,
  rounded half away from zero);
* the CSD / SDS / DDS gradients w(t) g of src/csd.rs's table, with the three weightings,
  and the step z0' = z0 - lr w(t) g.

Two priors:

gaussian_*  The Gaussian prior (src/prior/gaussian.rs, scripts/setup/10_gaussian_prior.py)
            in closed form: 8x8-pool + ENC "VAE", conditioning statistics from the
            prompt/null/style/content tokens, eps = sqrt(1-ab)(z - sqrt(ab) mu) /
            (ab var + 1 - ab). Inputs: two 32x32 views, a 64x64 style image (u8, so a
            PNG round trip is exact), noised latents; outputs per case: the gradient and
            csd-step stage's targets before their clamp, render + decode(z0') - decode(z0).
            The stage test runs the real ONNX graphs through `csd-step`.

stylizer_*  The default prior, the 2D stylizer (src/prior/stylizer.rs), on a 2-view
            24x32 case. Its network's two outputs, stylizer_T_ps_tgt.npy = T(x^_tgt,
            s_style) and stylizer_T_p_src.npy = T(x^_src, s_own(control)), are *inputs*
            here: in tests/golden/csd, fixed images (a stylization the network once gave;
            any images serve CSD's algebra, which the test checks with a double that
            returns them); for the installed network, its outputs computed on the test
            machine by scripts/reference/stylizer_ref.py (set-up), which calls
            stylizer_cases() below with them (issue 40: no recorded network outputs).
            Everything else is computed here: the clean estimate x^ (blur of z/sqrt(ab)
            with the module's sigma rule, mirrored borders, clamp; written as
            stylizer_xhat_{tgt,src}.npy so the test checks the Rust one against it),
            eps = (z - sqrt(ab) x0_c) / sqrt(1-ab) for Prompt/PromptStyle, and the
            *oracle* unconditional branches: Null/Content on the target are
            (z_tgt - sqrt(ab) z0) / sqrt(1-ab), Null on the source is
            (z_src - sqrt(ab) z0_src) / sqrt(1-ab) when z0_src is given, else eps.

    python scripts/reference/csd_ref.py                 # (re)write tests/golden/csd
    python scripts/reference/csd_ref.py OUT_DIR

cases.json lists every case with its parameters.
"""
import json
import os
import sys

import numpy as np

# ---------------------------------------------------------------------------------
# Schedule and timestep sets.


def alphas_cumprod(n=1000, beta_start=0.00085, beta_end=0.012):
    betas = np.linspace(np.sqrt(beta_start), np.sqrt(beta_end), n, dtype=np.float64) ** 2
    return np.cumprod(1.0 - betas)


def round_half_away(x):
    return int(np.floor(x + 0.5)) if x >= 0 else -int(np.floor(-x + 0.5))


def timestep_set(t_min, t_max, count):
    if count == 1:
        return [(t_min + t_max) // 2]
    return [round_half_away(t_min + i / (count - 1) * (t_max - t_min)) for i in range(count)]


def weight(kind, ab):
    return {"1-ab": 1.0 - ab, "uniform": 1.0, "sqrt-ab-1-ab": np.sqrt(ab) * (1.0 - ab)}[kind]


def gradient(mode, beta, w, t_pred, s_pred, eps):
    """src/csd.rs's table. t_pred/s_pred: dicts cond -> eps prediction (float64)."""
    if mode in ("csd", "csd-no-neg"):
        neg = "Content" if mode == "csd" else "Null"
        g = beta * (t_pred["PS"] - t_pred[neg]) - beta * (s_pred["P"] - s_pred["Null"])
    elif mode == "sds":
        g = t_pred["Null"] + beta * (t_pred["PS"] - t_pred["Null"]) - eps
    elif mode == "dds":
        g = (t_pred["Null"] + beta * (t_pred["PS"] - t_pred["Null"])) - (
            s_pred["Null"] + beta * (s_pred["P"] - s_pred["Null"]))
    else:
        raise ValueError(mode)
    return w * g


def save(out_dir, name, a, dtype=np.float32):
    np.save(os.path.join(out_dir, name), np.ascontiguousarray(a, dtype=dtype))


# ---------------------------------------------------------------------------------
# The Gaussian prior in closed form.

ENC = np.array([[1, 1, 1], [1, -1, 1], [1, 1, -1], [1, -1, -1]], dtype=np.float64)
SCALE = 0.5
PROMPT_MEAN = np.array([0.2, -0.1, 0.05, 0.0])
PROMPT_VAR = np.array([0.8, 1.1, 0.9, 1.0])


def g_encode(img):
    """[B,3,H,W] in [0,1] -> scaled latents [B,4,H/8,W/8]."""
    b, c, h, w = img.shape
    x = 2.0 * img - 1.0
    pooled = x.reshape(b, c, h // 8, 8, w // 8, 8).mean(axis=(3, 5))
    return SCALE * np.einsum("kc,bchw->bkhw", ENC, pooled)


def g_decode(z):
    raw = np.einsum("kc,bkhw->bchw", ENC / 4.0, z / SCALE)
    return np.repeat(np.repeat((raw + 1.0) * 0.5, 8, axis=2), 8, axis=3)


def g_stats(style):
    """(mean, population var) per channel of the style image's latents."""
    lat = g_encode(style)
    return lat.mean(axis=(0, 2, 3)), lat.var(axis=(0, 2, 3))


def g_eps(z, ab, mean, var):
    sa, s1 = np.sqrt(ab), np.sqrt(1.0 - ab)
    return s1 * (z - sa * mean[None, :, None, None]) / (ab * var[None, :, None, None] + 1.0 - ab)


def gaussian_cases(out_dir, rng, meta):
    ac = alphas_cumprod()
    n, h, w = 2, 32, 32
    yy, xx = np.meshgrid(np.arange(h), np.arange(w), indexing="ij")
    views = np.stack([
        np.stack([0.5 + 0.35 * np.sin(0.3 * xx + v + c) * np.cos(0.2 * yy - c) for c in range(3)])
        for v in range(n)
    ])  # [N,3,H,W]
    views = np.clip(views + 0.05 * rng.standard_normal(views.shape), 0.02, 0.98)
    views = views.astype(np.float32).astype(np.float64)
    style_u8 = (rng.integers(0, 4, (8, 8, 3)) * 60 + 30).astype(np.uint8)
    style_u8 = np.repeat(np.repeat(style_u8, 8, axis=0), 8, axis=1)  # 64x64 blocks
    style = style_u8.astype(np.float64)[None].transpose(0, 3, 1, 2) / 255.0
    t = timestep_set(20, 980, 50)[10]
    ab = ac[t]
    z0 = g_encode(views).astype(np.float32).astype(np.float64)
    eps = rng.standard_normal(z0.shape).astype(np.float32).astype(np.float64)
    sa, sb = np.sqrt(ab), np.sqrt(1.0 - ab)
    z_src = (sa * z0 + sb * eps).astype(np.float32).astype(np.float64)
    # MVFC changed the target's low frequencies: any smooth change serves here.
    z_tgt = (sa * z0 + sb * eps + 0.3 * rng.standard_normal(z0.shape)).astype(
        np.float32).astype(np.float64)
    mu_s, var_s = g_stats(style)
    # Token averages (src/prior/gaussian.rs): PS = prompt + style; Content = null +
    # content (mean 0, the style's var); Null = N(0, 1); Prompt = the prompt's.
    stats = {
        "Null": (np.zeros(4), np.ones(4)),
        "P": (PROMPT_MEAN, PROMPT_VAR),
        "PS": ((PROMPT_MEAN + mu_s) / 2.0, (PROMPT_VAR + var_s) / 2.0),
        "Content": (np.zeros(4), (1.0 + var_s) / 2.0),
    }
    tp = {c: g_eps(z_tgt, ab, *stats[c]) for c in ("PS", "Content", "Null")}
    sp = {c: g_eps(z_src, ab, *stats[c]) for c in ("P", "Null")}
    save(out_dir, "gaussian_views.npy", views.transpose(0, 2, 3, 1))  # [N,H,W,3]
    save(out_dir, "gaussian_style.npy", style_u8, np.uint8)  # [64,64,3]
    save(out_dir, "gaussian_z0.npy", z0)
    save(out_dir, "gaussian_eps.npy", eps)
    save(out_dir, "gaussian_z_src.npy", z_src)
    save(out_dir, "gaussian_z_tgt.npy", z_tgt)
    cases = [
        # Step sizes large enough that the targets move the views visibly.
        ("gaussian_csd", "csd", "1-ab", 7.5, 2.0),
        ("gaussian_csd_sqrt", "csd", "sqrt-ab-1-ab", 7.5, 4.0),
        ("gaussian_sds", "sds", "uniform", 7.5, 0.2),
        ("gaussian_dds", "dds", "uniform", 5.0, 0.5),
        ("gaussian_csd_no_neg", "csd-no-neg", "uniform", 7.5, 1.0),
    ]
    for name, mode, wk, beta, lr in cases:
        g = gradient(mode, beta, weight(wk, ab), tp, sp, eps)
        z1 = z0 - lr * g
        raw = views + g_decode(z1) - g_decode(z0)
        save(out_dir, f"{name}_grad.npy", g)
        # The targets before the clamp ([N,H,W,3]); the stage clamps to [0, 1].
        save(out_dir, f"{name}_raw.npy", raw.transpose(0, 2, 3, 1))
        meta[name] = {"prior": "gaussian", "mode": mode, "weighting": wk, "guidance": beta,
                      "lr": lr, "timestep": t, "alpha_bar": ab}


# ---------------------------------------------------------------------------------
# The stylizer prior: everything but the network.


def mirror(i, n):
    if n == 1:
        return 0
    p = 2 * (n - 1)
    k = i % p
    return k if k < n else p - k


def clean_estimate(z, ab):
    """x^ = clamp(G_sigma * (z / sqrt(ab)), 0, 1) per image [3,H,W]."""
    r = np.sqrt((1.0 - ab) / ab)
    sigma = min(8.0, r / (2.0 * np.sqrt(np.pi) * 0.05))
    x = z / np.sqrt(ab)
    if sigma < 0.1:
        return np.clip(x, 0.0, 1.0), sigma
    rad = int(np.ceil(3.0 * sigma))
    d = np.arange(-rad, rad + 1, dtype=np.float64)
    k = np.exp(-d * d / (2.0 * sigma * sigma))
    k /= k.sum()
    c, h, w = x.shape
    ix = np.array([[mirror(xx + j - rad, w) for j in range(2 * rad + 1)] for xx in range(w)])
    iy = np.array([[mirror(yy + j - rad, h) for j in range(2 * rad + 1)] for yy in range(h)])
    tmp = (x[:, :, ix] * k).sum(axis=-1)            # along x
    out = (tmp[:, iy, :] * k[None, :, None]).sum(axis=2)  # along y
    return np.clip(out, 0.0, 1.0), sigma


STYLIZER_T = 160  # in the stylizer's set (t_min 20, t_max 300, count 25)


def stylizer_inputs(out_dir, rng):
    """The inputs (deterministic): z0, z0_src (= the control images), eps, z_tgt, z_src,
    the style image."""
    ac = alphas_cumprod()
    assert STYLIZER_T in timestep_set(20, 300, 25)
    ab = ac[STYLIZER_T]
    sa, sb = np.sqrt(ab), np.sqrt(1.0 - ab)
    n, h, w = 2, 24, 32
    yy, xx = np.meshgrid(np.arange(h), np.arange(w), indexing="ij")
    src = np.stack([
        np.stack([0.45 + 0.3 * np.sin(0.25 * xx * (c + 1) + v) * np.cos(0.3 * yy + c) for c in range(3)])
        for v in range(n)
    ])
    src = np.clip(src + 0.04 * rng.standard_normal(src.shape), 0.02, 0.98)
    # The current renders: the source moved a little (an earlier step's change).
    z0 = np.clip(src + 0.08 * rng.standard_normal(src.shape), 0.0, 1.0)
    eps = rng.standard_normal(src.shape)
    f = lambda a: a.astype(np.float32).astype(np.float64)
    src, z0, eps = f(src), f(z0), f(eps)
    # MVFC changed both noisy latents (the distill loop filters the source too), so
    # z_src is not add_noise(z0_src, eps): the oracle's z0_src branch differs from eps.
    z_src = f(sa * src + sb * eps + 0.2 * rng.standard_normal(src.shape))
    z_tgt = f(sa * z0 + sb * eps + 0.2 * rng.standard_normal(src.shape))
    yy, xx = np.meshgrid(np.arange(64), np.arange(64), indexing="ij")
    style_u8 = np.stack([((xx // 8 + yy // 8 + c) % 3) * 110 + 15 for c in range(3)], axis=-1)
    style_u8 = style_u8.astype(np.uint8)
    save(out_dir, "stylizer_z0.npy", z0)
    save(out_dir, "stylizer_z0_src.npy", src)
    save(out_dir, "stylizer_eps.npy", eps)
    save(out_dir, "stylizer_z_src.npy", z_src)
    save(out_dir, "stylizer_z_tgt.npy", z_tgt)
    save(out_dir, "stylizer_style.npy", style_u8, np.uint8)  # [64,64,3]
    return dict(ab=ab, z0=z0, src=src, eps=eps, z_src=z_src, z_tgt=z_tgt)


def stylizer_cases(out_dir, x, meta, T_ps=None, T_p=None):
    """The stylizer cases' expected gradients and steps from the network outputs T_ps =
    T(x^_tgt, s_style) and T_p = T(x^_src, s_own) (default: the fixed inputs
    stylizer_T_*.npy in out_dir)."""
    ab = x["ab"]
    xh_t = np.stack([clean_estimate(z, ab)[0] for z in x["z_tgt"]])
    xh_s = np.stack([clean_estimate(z, ab)[0] for z in x["z_src"]])
    sigma = clean_estimate(x["z_tgt"][0], ab)[1]
    save(out_dir, "stylizer_xhat_tgt.npy", xh_t)
    save(out_dir, "stylizer_xhat_src.npy", xh_s)
    if T_ps is None:
        T_ps = np.load(os.path.join(out_dir, "stylizer_T_ps_tgt.npy")).astype(np.float64)
        T_p = np.load(os.path.join(out_dir, "stylizer_T_p_src.npy")).astype(np.float64)
    sa, sb = np.sqrt(ab), np.sqrt(1.0 - ab)
    eps_of = lambda z, x0: (z - sa * x0) / sb
    z0, z_tgt, z_src, eps = x["z0"], x["z_tgt"], x["z_src"], x["eps"]
    # Oracle (exact) unconditional branches: no prior call, no blur.
    null_tgt = eps_of(z_tgt, z0)
    tp = {"PS": eps_of(z_tgt, T_ps), "Content": null_tgt, "Null": null_tgt}
    cases = [
        ("stylizer_csd", "csd", "1-ab", 7.5, 0.1, True),
        ("stylizer_csd_no_z0_src", "csd", "1-ab", 7.5, 0.1, False),
        ("stylizer_csd_no_neg", "csd-no-neg", "uniform", 7.5, 0.1, True),
        ("stylizer_sds", "sds", "uniform", 7.5, 0.1, True),
        ("stylizer_dds", "dds", "sqrt-ab-1-ab", 3.0, 0.1, True),
    ]
    for name, mode, wk, beta, lr, with_src in cases:
        null_src = eps_of(z_src, x["src"]) if with_src else eps
        sp = {"P": eps_of(z_src, T_p), "Null": null_src}
        g = gradient(mode, beta, weight(wk, ab), tp, sp, eps)
        if mode in ("csd", "csd-no-neg"):
            # The module docs' closed form: beta sqrt(ab/(1-ab)) w times
            # (z0 - T(x^_tgt, s_style)) - (z0_src - T(x^_src, s_own)).
            src0 = x["src"] if with_src else (z_src - sb * eps) / sa
            closed = weight(wk, ab) * beta * np.sqrt(ab / (1 - ab)) * ((z0 - T_ps) - (src0 - T_p))
            assert np.abs(closed - g).max() < 1e-9 * max(1.0, np.abs(g).max()), name
        save(out_dir, f"{name}_grad.npy", g)
        save(out_dir, f"{name}_z1.npy", z0 - lr * g)
        meta[name] = {"prior": "stylizer", "mode": mode, "weighting": wk, "guidance": beta,
                      "lr": lr, "timestep": STYLIZER_T, "alpha_bar": ab,
                      "z0_src": with_src, "sigma": sigma}


def main(out_dir):
    os.makedirs(out_dir, exist_ok=True)
    meta = {}
    np.save(os.path.join(out_dir, "alphas_cumprod.npy"), alphas_cumprod())
    gaussian_cases(out_dir, np.random.default_rng(20260202), meta)
    x = stylizer_inputs(out_dir, np.random.default_rng(20260303))
    stylizer_cases(out_dir, x, meta)
    with open(os.path.join(out_dir, "cases.json"), "w") as f:
        json.dump(meta, f, indent=1, sort_keys=True)
        f.write("\n")


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "tests/golden/csd")
