#!/usr/bin/env python3
"""Independent numpy reference of the 3DGS forward rasterizer (float64).

Writes tests/golden/render/cases.json (scenes + cameras, f32 values) and, per case,
<case>_rgb.npy [H,W,3], <case>_depth.npy [H,W], <case>_alpha.npy [H,W] (float32).
Run from the repo root:  vendor/venv/bin/python scripts/reference/render_ref.py

Semantics (Kerbl et al. 2023; INRIA diff-gaussian-rasterization conventions):
- camera space t = R p + T; culled if t.z < 0.2;
- Sigma = R(q) S S^T R(q)^T; Sigma' = J R Sigma R^T J^T + 0.3 I, where J uses x/z, y/z
  clamped to the frustum widened by 0.3 tan(fov/2) on each side;
- radius = ceil(3 sqrt(mid + sqrt(max(0.1, mid^2 - det)))); a Gaussian may touch the
  pixels of every 16x16 tile that meets the square mean +- radius (pixel centres at
  i + 0.5);
- depth order by (float32 depth, index); alpha = min(0.99, o exp(-power)), skipped if
  power < 0 is violated or alpha < 1/255; a pixel stops before the Gaussian that would
  take T below 1e-4; colour = max(0, SH + 0.5) (INRIA constants); out = C + T bg.
This is a straightforward loop over Gaussians vectorised over pixels, sharing no code
with the Rust rasterizer.
"""
import json
import os
import sys

import numpy as np

C0 = 0.28209479177387814
C1 = 0.4886025119029199
C2 = [1.0925484305920792, -1.0925484305920792, 0.31539156525252005,
      -1.0925484305920792, 0.5462742152960396]
C3 = [-0.5900435899266435, 2.890611442640554, -0.4570457994644658,
      0.3731763325901154, -0.4570457994644658, 1.445305721320277,
      -0.5900435899266435]
TILE = 16


def sh_basis(d):
    x, y, z = d
    xx, yy, zz = x * x, y * y, z * z
    return np.array([
        C0, -C1 * y, C1 * z, -C1 * x,
        C2[0] * x * y, C2[1] * y * z, C2[2] * (2 * zz - xx - yy), C2[3] * x * z,
        C2[4] * (xx - yy),
        C3[0] * y * (3 * xx - yy), C3[1] * x * y * z, C3[2] * y * (4 * zz - xx - yy),
        C3[3] * z * (2 * zz - 3 * xx - 3 * yy), C3[4] * x * (4 * zz - xx - yy),
        C3[5] * z * (xx - yy), C3[6] * x * (xx - 3 * yy)])


def quat_to_rot(q):
    q = np.asarray(q, np.float64)
    w, x, y, z = q / np.linalg.norm(q)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def render(scene, cam, bg):
    W, H = cam["width"], cam["height"]
    fx, fy, cx, cy = (float(cam[k]) for k in ("fx", "fy", "cx", "cy"))
    R = np.array(cam["rotation"], np.float64)
    T = np.array(cam["translation"], np.float64)
    centre = -R.T @ T
    deg = scene["sh_degree"]
    K = (deg + 1) ** 2
    n = len(scene["positions"])
    tanx, tany = 0.5 * W / fx, 0.5 * H / fy
    lxp, lxn = (W - cx) / fx + 0.3 * tanx, cx / fx + 0.3 * tanx
    lyp, lyn = (H - cy) / fy + 0.3 * tany, cy / fy + 0.3 * tany
    tiles_x, tiles_y = -(-W // TILE), -(-H // TILE)
    px = np.arange(W)[None, :] + 0.5
    py = np.arange(H)[:, None] + 0.5
    items = []
    for i in range(n):
        p = np.array(scene["positions"][i], np.float64)
        t = R @ p + T
        if not t[2] >= 0.2:
            continue
        op = 1 / (1 + np.exp(-float(scene["opacity_logits"][i])))
        Rq = quat_to_rot(scene["rotations"][i])
        S = np.diag(np.exp(np.array(scene["log_scales"][i], np.float64)))
        Sig = Rq @ S @ S.T @ Rq.T
        z = t[2]
        tx = z * np.clip(t[0] / z, -lxn, lxp)
        ty = z * np.clip(t[1] / z, -lyn, lyp)
        J = np.array([[fx / z, 0, -fx * tx / z**2], [0, fy / z, -fy * ty / z**2]])
        cov = J @ R @ Sig @ R.T @ J.T + 0.3 * np.eye(2)
        det = np.linalg.det(cov)
        if not det > 0:
            continue
        mx, my = fx * t[0] / z + cx, fy * t[1] / z + cy
        mid = 0.5 * (cov[0, 0] + cov[1, 1])
        lam = mid + np.sqrt(max(0.1, mid * mid - det))
        r = np.ceil(3 * np.sqrt(lam))
        x0, x1 = max(mx - r, 0.0), min(mx + r, W - 1e-3)
        y0, y1 = max(my - r, 0.0), min(my + r, H - 1e-3)
        if x1 < x0 or y1 < y0:
            continue
        rect = (int(x0 // TILE), int(y0 // TILE), int(x1 // TILE) + 1, int(y1 // TILE) + 1)
        d = p - centre
        d = d / np.linalg.norm(d)
        b = sh_basis(d)[:K]
        coeffs = np.zeros((K, 3))
        coeffs[0] = scene["sh_dc"][i]
        if K > 1:
            coeffs[1:] = np.array(scene["sh_rest"][i * (K - 1) * 3:(i + 1) * (K - 1) * 3]
                                  ).reshape(K - 1, 3)
        colour = np.maximum(b @ coeffs + 0.5, 0.0)
        items.append((np.float32(z), i, mx, my, np.linalg.inv(cov), op, rect, colour, z))
    items.sort(key=lambda it: (it[0], it[1]))
    Tr = np.ones((H, W))
    live = np.ones((H, W), bool)
    C = np.zeros((H, W, 3))
    D = np.zeros((H, W))
    for _, i, mx, my, con, op, rect, colour, z in items:
        mask = np.zeros((H, W), bool)
        mask[rect[1] * TILE:rect[3] * TILE, rect[0] * TILE:rect[2] * TILE] = True
        dx = mx - px
        dy = my - py
        power = -0.5 * (con[0, 0] * dx * dx + con[1, 1] * dy * dy) - con[0, 1] * dx * dy
        alpha = np.minimum(0.99, op * np.exp(power))
        ok = mask & live & (power <= 0) & (alpha >= 1 / 255)
        nxt = Tr * (1 - alpha)
        finish = ok & (nxt < 1e-4)
        blend = ok & ~finish
        w = np.where(blend, alpha * Tr, 0.0)
        C += w[..., None] * colour
        D += w * z
        Tr = np.where(blend, nxt, Tr)
        live &= ~finish
    rgb = C + Tr[..., None] * np.asarray(bg, np.float64)
    return rgb, D, 1 - Tr


def f32list(a):
    return [float(v) for v in np.asarray(a, np.float32).ravel()]


def random_scene(rng, n, deg, spread, log_scale, opacity, dc=2.5, rest=0.5):
    K = (deg + 1) ** 2
    pos = rng.uniform(-spread, spread, (n, 3))
    return {
        "sh_degree": deg,
        "positions": [f32list(p) for p in pos],
        "log_scales": [f32list(s) for s in rng.uniform(*log_scale, (n, 3))],
        "rotations": [f32list(q) for q in rng.normal(size=(n, 4))],
        "opacity_logits": f32list(rng.uniform(*opacity, n)),
        "sh_dc": [f32list(c) for c in rng.uniform(-dc, dc, (n, 3))],
        "sh_rest": f32list(rng.uniform(-rest, rest, n * (K - 1) * 3)),
    }


def look_at(eye, target, up=(0.0, -1.0, 0.0)):
    eye, target, up = (np.asarray(v, np.float64) for v in (eye, target, up))
    f = target - eye
    f /= np.linalg.norm(f)
    r = np.cross(f, up)
    r /= np.linalg.norm(r)
    d = np.cross(f, r)
    Rw = np.stack([r, d, f])  # rows: camera axes in world (x right, y down, z forward)
    return Rw, -Rw @ eye


def camera(name, w, h, f, eye, target=(0, 0, 0), cx=None, cy=None):
    R, T = look_at(eye, target)
    return {"name": name, "width": w, "height": h, "fx": float(np.float32(f)),
            "fy": float(np.float32(f)),
            "cx": float(np.float32(w / 2 if cx is None else cx)),
            "cy": float(np.float32(h / 2 if cy is None else cy)),
            "rotation": [f32list(row) for row in R], "translation": f32list(T)}


def cases():
    rng = np.random.default_rng(20260521)
    return [
        ("deg0_sparse", random_scene(rng, 60, 0, 1.0, (-3.0, -1.5), (-1, 3)),
         camera("c0", 48, 40, 45.0, (0, 0, -3.5)), [0.0, 0.0, 0.0]),
        ("deg1_background_offcentre", random_scene(rng, 100, 1, 1.0, (-3.2, -1.6), (-2, 2)),
         camera("c1", 64, 48, 55.0, (1.5, -1.0, -3.0), cx=28.3, cy=26.1), [0.2, 0.5, 0.9]),
        ("deg2_guardband_near", random_scene(rng, 120, 2, 2.0, (-3.0, -1.0), (-1, 3)),
         camera("c2", 56, 56, 40.0, (0.3, 0.2, -2.2)), [1.0, 1.0, 1.0]),
        ("deg3_dense_saturating", random_scene(rng, 200, 3, 0.6, (-3.0, -1.8), (1, 6)),
         camera("c3", 64, 64, 70.0, (-2.0, -1.5, -2.5)), [0.0, 0.0, 0.0]),
    ]


def main():
    root = sys.argv[1] if len(sys.argv) > 1 else "."
    out = os.path.join(root, "tests", "golden", "render")
    os.makedirs(out, exist_ok=True)
    doc = []
    for name, scene, cam, bg in cases():
        rgb, depth, alpha = render(scene, cam, bg)
        np.save(os.path.join(out, f"{name}_rgb.npy"), rgb.astype(np.float32))
        np.save(os.path.join(out, f"{name}_depth.npy"), depth.astype(np.float32))
        np.save(os.path.join(out, f"{name}_alpha.npy"), alpha.astype(np.float32))
        doc.append({"name": name, "scene": scene, "camera": cam, "background": bg})
        print(f"{name}: coverage {np.mean(alpha > 0.5):.3f}, mean rgb {rgb.mean():.4f}, "
              f"saturated {np.mean(alpha > 0.999):.3f}")
    with open(os.path.join(out, "cases.json"), "w") as f:
        json.dump(doc, f)


if __name__ == "__main__":
    main()
