//! The network's passes: the f32 forward against an independent f64 forward, the
//! backward against finite differences, the gradient's support, errors and banding.

use super::*;

fn image(seed: u64, h: usize, w: usize) -> Vec<f32> {
    let mut r = crate::rng::Rng::new(seed);
    (0..h * w * 3).map(|_| r.uniform() as f32).collect()
}

/// The support of one relu4_3 unit's input gradient fits in the closed-form
/// receptive field (an independent check of `receptive_field`).
#[test]
fn gradient_support_within_receptive_field() {
    let net = Vgg16::random(3, 16);
    let (h, w) = (120, 120);
    let img = image(1, h, w);
    let f = net.forward(&img, h, w, Layer::Relu4_3).unwrap();
    let a = f.get(Layer::Relu4_3);
    let mut g = Tensor3::zeros(a.c, a.h, a.w);
    // All channels of the centre unit (some are active).
    let (cy, cx) = (a.h / 2, a.w / 2);
    for c in 0..a.c {
        g.data[(c * a.h + cy) * a.w + cx] = 1.0;
    }
    let dx = net.backward(&f, &[(Layer::Relu4_3, &g)]).unwrap();
    let (mut y0, mut y1) = (usize::MAX, 0);
    for p in 0..h * w {
        if (0..3).any(|c| dx[p * 3 + c] != 0.0) {
            y0 = y0.min(p / w);
            y1 = y1.max(p / w);
        }
    }
    assert!(y1 >= y0, "gradient is all zero");
    assert!(y1 - y0 < 92, "support {} rows", y1 - y0 + 1);
}

/// An independent f64 forward pass (direct convolution loops, no im2col, no GEMM):
/// returns the ReLU outputs of convolutions `0..=upto`.
fn forward_f64(net: &Vgg16, rgb: &[f64], h: usize, w: usize, upto: Layer) -> Vec<Vec<f64>> {
    let mut x: Vec<f64> = (0..3 * h * w)
        .map(|q| {
            let (c, p) = (q / (h * w), q % (h * w));
            (rgb[p * 3 + c] - IMAGENET_MEAN[c] as f64) / IMAGENET_STD[c] as f64
        })
        .collect();
    let (mut hh, mut ww) = (h, w);
    let mut out = Vec::new();
    for i in 0..=upto.index() {
        if pooled_before(i) {
            let (h2, w2) = (hh / 2, ww / 2);
            let c = net.convs[i].cin;
            let mut y = vec![0.0; c * h2 * w2];
            for ch in 0..c {
                for a in 0..h2 {
                    for b in 0..w2 {
                        let at = |dy: usize, dx: usize| x[(ch * hh + 2 * a + dy) * ww + 2 * b + dx];
                        y[(ch * h2 + a) * w2 + b] =
                            at(0, 0).max(at(0, 1)).max(at(1, 0)).max(at(1, 1));
                    }
                }
            }
            x = y;
            hh = h2;
            ww = w2;
        }
        let conv = &net.convs[i];
        let mut y = vec![0.0; conv.cout * hh * ww];
        for o in 0..conv.cout {
            for a in 0..hh {
                for b in 0..ww {
                    let mut s = conv.b[o] as f64;
                    for ci in 0..conv.cin {
                        for ky in 0..3 {
                            for kx in 0..3 {
                                let (sy, sx) = (a + ky, b + kx);
                                if sy < 1 || sx < 1 || sy > hh || sx > ww {
                                    continue;
                                }
                                s += conv.w[[o, ci * 9 + ky * 3 + kx]] as f64
                                    * x[(ci * hh + sy - 1) * ww + sx - 1];
                            }
                        }
                    }
                    y[(o * hh + a) * ww + b] = s.max(0.0);
                }
            }
        }
        out.push(y.clone());
        x = y;
    }
    out
}

/// The f32 GEMM forward agrees with the f64 direct forward, and the f32 backward agrees
/// with central differences of the f64 forward (eps 1e-6, where ReLU/max-pool kinks are
/// practically never straddled): directional derivative along a random direction and
/// 40 single entries. Tolerance: 1e-3 of the gradient scale.
#[test]
fn backward_matches_finite_differences() {
    let net = Vgg16::random(11, 16);
    let (h, w) = (18, 21);
    let img = image(5, h, w);
    let f0 = net.forward(&img, h, w, Layer::Relu4_3).unwrap();
    let img64: Vec<f64> = img.iter().map(|&v| v as f64).collect();
    let r64 = forward_f64(&net, &img64, h, w, Layer::Relu4_3);
    for (a, b) in f0.acts.iter().zip(&r64) {
        let scale = b.iter().fold(0f64, |m, v| m.max(v.abs()));
        let err = a
            .data
            .iter()
            .zip(b)
            .fold(0f64, |m, (&x, &y)| m.max((x as f64 - y).abs()));
        assert!(
            err <= 1e-5 * scale.max(1.0),
            "forward err {err} scale {scale}"
        );
    }
    let taps = [
        Layer::Relu1_2,
        Layer::Relu2_2,
        Layer::Relu3_3,
        Layer::Relu4_3,
    ];
    let mut r = crate::rng::Rng::new(9);
    let weights: Vec<Tensor3> = taps
        .iter()
        .map(|&l| {
            let a = f0.get(l);
            let mut t = Tensor3::zeros(a.c, a.h, a.w);
            t.data.iter_mut().for_each(|v| *v = r.normal() as f32);
            t
        })
        .collect();
    let loss = |x: &[f64]| -> f64 {
        let f = forward_f64(&net, x, h, w, Layer::Relu4_3);
        taps.iter()
            .zip(&weights)
            .map(|(&l, wt)| {
                f[l.index()]
                    .iter()
                    .zip(&wt.data)
                    .map(|(&a, &b)| a * b as f64)
                    .sum::<f64>()
            })
            .sum()
    };
    let gl: Vec<(Layer, &Tensor3)> = taps.iter().copied().zip(weights.iter()).collect();
    let g = net.backward(&f0, &gl).unwrap();
    let gmax = g.iter().fold(0f32, |m, x| m.max(x.abs())) as f64;
    let eps = 1e-6;
    let v: Vec<f64> = (0..img.len()).map(|_| r.normal()).collect();
    let plus: Vec<f64> = img64.iter().zip(&v).map(|(a, b)| a + eps * b).collect();
    let minus: Vec<f64> = img64.iter().zip(&v).map(|(a, b)| a - eps * b).collect();
    let fd = (loss(&plus) - loss(&minus)) / (2.0 * eps);
    let an: f64 = g.iter().zip(&v).map(|(&a, &b)| a as f64 * b).sum();
    let vnorm = v.iter().map(|x| x * x).sum::<f64>().sqrt();
    assert!(
        (fd - an).abs() <= 1e-3 * gmax * vnorm,
        "directional: fd {fd} analytic {an}"
    );
    for _ in 0..40 {
        let i = (r.next_u64() % img.len() as u64) as usize;
        let mut p = img64.clone();
        p[i] += eps;
        let mut m = img64.clone();
        m[i] -= eps;
        let fd = (loss(&p) - loss(&m)) / (2.0 * eps);
        assert!(
            (fd - g[i] as f64).abs() <= 1e-3 * gmax,
            "pixel {i}: fd {fd} analytic {} (max |g| {gmax})",
            g[i]
        );
    }
}

#[test]
fn too_small_and_bad_gradient_are_errors() {
    let net = Vgg16::random(1, 16);
    assert!(net.forward(&image(1, 7, 9), 7, 9, Layer::Relu4_3).is_err());
    assert!(net.forward(&image(1, 8, 8), 8, 8, Layer::Relu4_3).is_ok());
    assert!(net.forward(&[0.0; 5], 8, 8, Layer::Relu1_1).is_err());
    let f = net
        .forward(&image(1, 16, 16), 16, 16, Layer::Relu2_2)
        .unwrap();
    let t = Tensor3::zeros(1, 1, 1);
    assert!(net.backward(&f, &[(Layer::Relu2_2, &t)]).is_err());
    let a = f.get(Layer::Relu2_2).clone();
    assert!(net.backward(&f, &[(Layer::Relu3_1, &a)]).is_err());
    assert!(net.backward(&f, &[]).is_err());
}

#[test]
fn banding_does_not_change_results() {
    // A single-thread pool gives different band splits than the default pool.
    let net = Vgg16::random(2, 8);
    let (h, w) = (37, 29);
    let img = image(4, h, w);
    let a = net.forward(&img, h, w, Layer::Relu3_3).unwrap();
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap();
    let b = pool.install(|| net.forward(&img, h, w, Layer::Relu3_3).unwrap());
    assert_eq!(a.get(Layer::Relu3_3), b.get(Layer::Relu3_3));
}
