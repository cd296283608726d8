//! Deterministic random numbers: SplitMix64 seeding a xoshiro256** generator, with
//! Box-Muller normals. Our own, so that a seed gives the same noise on every platform
//! and every version of every dependency (reproducible runs and resumable DAGs).

/// xoshiro256** seeded through SplitMix64.
#[derive(Debug, Clone)]
pub struct Rng {
    s: [u64; 4],
    spare: Option<f64>,
}

impl Rng {
    pub fn new(seed: u64) -> Self {
        let mut x = seed;
        let mut next = || {
            x = x.wrapping_add(0x9E37_79B9_7F4A_7C15);
            let mut z = x;
            z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
            z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
            z ^ (z >> 31)
        };
        Rng {
            s: [next(), next(), next(), next()],
            spare: None,
        }
    }

    /// A generator for a sub-stream (e.g. one per round or per purpose).
    pub fn derive(seed: u64, stream: &str) -> Self {
        let h = blake3::hash(format!("{seed}/{stream}").as_bytes());
        let b = h.as_bytes();
        Rng::new(u64::from_le_bytes(b[..8].try_into().expect("8 bytes")))
    }

    pub fn next_u64(&mut self) -> u64 {
        let r = self.s[1].wrapping_mul(5).rotate_left(7).wrapping_mul(9);
        let t = self.s[1] << 17;
        self.s[2] ^= self.s[0];
        self.s[3] ^= self.s[1];
        self.s[1] ^= self.s[2];
        self.s[0] ^= self.s[3];
        self.s[2] ^= t;
        self.s[3] = self.s[3].rotate_left(45);
        r
    }

    /// Uniform in [0, 1).
    pub fn uniform(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
    }

    /// Standard normal (Box-Muller).
    pub fn normal(&mut self) -> f64 {
        if let Some(z) = self.spare.take() {
            return z;
        }
        let u1 = 1.0 - self.uniform(); // (0, 1]
        let u2 = self.uniform();
        let r = (-2.0 * u1.ln()).sqrt();
        let th = std::f64::consts::TAU * u2;
        self.spare = Some(r * th.sin());
        r * th.cos()
    }

    /// `n` standard normals as f32: the same values as `n` calls of [`Self::normal`]
    /// (the uniforms are drawn in order, Box-Muller's logarithm, square root, sine and
    /// cosine are computed for many pairs at once on all cores), leaving the same state.
    pub fn normals_f32(&mut self, n: usize) -> Vec<f32> {
        use rayon::prelude::*;
        let mut out = Vec::with_capacity(n);
        if n > 0
            && let Some(z) = self.spare.take()
        {
            out.push(z as f32);
        }
        let left = n - out.len();
        let pairs = left.div_ceil(2);
        let u: Vec<(f64, f64)> = (0..pairs)
            .map(|_| (1.0 - self.uniform(), self.uniform()))
            .collect();
        let z: Vec<(f64, f64)> = u
            .par_chunks(4096)
            .flat_map_iter(|c| {
                c.iter().map(|&(u1, u2)| {
                    let r = (-2.0 * u1.ln()).sqrt();
                    let th = std::f64::consts::TAU * u2;
                    (r * th.cos(), r * th.sin())
                })
            })
            .collect();
        for (k, &(c, s)) in z.iter().enumerate() {
            out.push(c as f32);
            if out.len() < n {
                out.push(s as f32);
            } else if k + 1 == z.len() {
                // An odd count: the sine of the last pair is kept, as `normal` does.
                self.spare = Some(s);
            }
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The batched draw equals one `normal` call after another, value for value and
    /// in the state it leaves (odd and even counts, with and without a spare).
    #[test]
    fn normals_f32_equals_single_draws() {
        for (first, n) in [(0, 9), (1, 9), (0, 10), (1, 10000), (2, 1), (3, 0)] {
            let (mut a, mut b) = (Rng::new(3), Rng::new(3));
            for _ in 0..first {
                a.normal();
                b.normal();
            }
            let batch = a.normals_f32(n);
            let single: Vec<f32> = (0..n).map(|_| b.normal() as f32).collect();
            assert_eq!(batch, single, "first {first}, n {n}");
            assert_eq!(a.normal().to_bits(), b.normal().to_bits());
            assert_eq!(a.next_u64(), b.next_u64());
        }
    }

    #[test]
    fn deterministic_and_roughly_standard() {
        let a = Rng::new(7).normals_f32(20000);
        let b = Rng::new(7).normals_f32(20000);
        assert_eq!(a, b);
        let m = a.iter().map(|&x| x as f64).sum::<f64>() / a.len() as f64;
        let v = a.iter().map(|&x| (x as f64 - m).powi(2)).sum::<f64>() / a.len() as f64;
        assert!(m.abs() < 0.03 && (v - 1.0).abs() < 0.05, "mean {m} var {v}");
        assert_ne!(
            Rng::derive(1, "a").next_u64(),
            Rng::derive(1, "b").next_u64()
        );
    }
}
