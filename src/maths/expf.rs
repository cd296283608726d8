//! `f32::exp` of many values at once, bit for bit what the platform's `expf` returns.
//!
//! On x86-64 glibc (2.27 and later) `expf` is Szabolcs Nagy's algorithm (ARM optimized
//! routines): `x` in double, `2^(k/32)` from a 32-entry table and a cubic in the rest,
//! one rounding to float at the end; on CPUs with AVX2 and FMA glibc runs its FMA build
//! (`__expf_fma`), whose operations are listed in [`expf_fma`]. [`exp_in_place`] does those
//! same operations four lanes at a time there (the same table, constants, fused
//! multiply-adds and special cases, read off glibc 2.36's `__expf_fma`), so every lane
//! is what `expf` gives; on any other CPU it calls `f32::exp` itself. Either way the
//! values are the platform's `expf`'s, bit for bit, which the tests check against
//! `f32::exp` over a dense sweep of the floats (and [`tests::every_float`], run by hand
//! with `--ignored`, over all 2^32 of them).
//!
//! Used by the balance's Sinkhorn rounds ([`super::sinkhorn_scaling`]) for their kernel.

/// `2^(i/32)` as the bits of an f64 with `i` taken off its exponent (glibc's
/// `__exp2f_data.tab`).
const TAB: [u64; 32] = [
    0x3ff0000000000000,
    0x3fefd9b0d3158574,
    0x3fefb5586cf9890f,
    0x3fef9301d0125b51,
    0x3fef72b83c7d517b,
    0x3fef54873168b9aa,
    0x3fef387a6e756238,
    0x3fef1e9df51fdee1,
    0x3fef06fe0a31b715,
    0x3feef1a7373aa9cb,
    0x3feedea64c123422,
    0x3feece086061892d,
    0x3feebfdad5362a27,
    0x3feeb42b569d4f82,
    0x3feeab07dd485429,
    0x3feea47eb03a5585,
    0x3feea09e667f3bcd,
    0x3fee9f75e8ec5f74,
    0x3feea11473eb0187,
    0x3feea589994cce13,
    0x3feeace5422aa0db,
    0x3feeb737b0cdc5e5,
    0x3feec49182a3f090,
    0x3feed503b23e255d,
    0x3feee89f995ad3ad,
    0x3feeff76f2fb5e47,
    0x3fef199bdd85529c,
    0x3fef3720dcef9069,
    0x3fef5818dcfba487,
    0x3fef7c97337b9b5f,
    0x3fefa4afa2a490da,
    0x3fefd0765b6e4540,
];
/// `32 / ln 2`.
const INV_LN2_N: u64 = 0x40471547652b82fe;
/// `1.5 * 2^52`: adding it rounds to an integer.
const SHIFT: u64 = 0x4338000000000000;
/// The cubic's coefficients (of `r^3`, `r^2`, `r`).
const C: [u64; 3] = [0x3ebc6af84b912394, 0x3f2ebfce50fac4f3, 0x3f962e42ff0c52d6];
/// Above this `expf` overflows (`log(2^128)`).
const OVERFLOW: u32 = 0x42b17217;
/// Below this `expf` is 0 (`log(2^-150)`).
const UNDERFLOW: u32 = 0xc2cff1b4;
/// Below this (and not below [`UNDERFLOW`]) `expf` is the least subnormal, `2^-149`
/// (glibc's `__math_may_uflowf`; `log(2^-149)`).
const MAY_UNDERFLOW: u32 = 0xc2ce8ecf;

/// glibc's `__expf_fma` of one value, operation by operation (with `mul_add` where it
/// fuses): the reference [`exp_in_place`]'s lanes follow.
pub fn expf_fma(x: f32) -> f32 {
    let bits = x.to_bits();
    let abstop = (bits >> 20) & 0x7ff;
    if abstop > 0x42a {
        // |x| >= 88, or not finite.
        if bits == f32::NEG_INFINITY.to_bits() {
            return 0.0;
        }
        if abstop > 0x7f7 {
            return x + x;
        }
        if x > f32::from_bits(OVERFLOW) {
            return f32::INFINITY;
        }
        if x < f32::from_bits(UNDERFLOW) {
            return 0.0;
        }
        if x < f32::from_bits(MAY_UNDERFLOW) {
            return f32::from_bits(1);
        }
    }
    let d = |b: u64| f64::from_bits(b);
    let xd = f64::from(x);
    let z = d(INV_LN2_N).mul_add(xd, d(SHIFT));
    let ki = z.to_bits();
    let kd = z - d(SHIFT);
    let r = d(INV_LN2_N).mul_add(xd, -kd);
    let s = d(TAB[(ki & 31) as usize].wrapping_add(ki << 47));
    let p = d(C[0]).mul_add(r, d(C[1]));
    let r2 = r * r;
    let y = d(C[2]).mul_add(r, 1.0);
    let y = p.mul_add(r2, y);
    (y * s) as f32
}

/// Every `v[i]` replaced by `v[i].exp()`, bit for bit (module docs).
pub fn exp_in_place(v: &mut [f32]) {
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma") {
        // SAFETY: the function needs AVX2 and FMA, which the CPU has (checked just
        // above).
        #[allow(unsafe_code)]
        unsafe {
            avx2::exp_in_place(v)
        };
        return;
    }
    for x in v {
        *x = x.exp();
    }
}

#[cfg(target_arch = "x86_64")]
#[allow(unsafe_code)]
mod avx2 {
    use super::{C, INV_LN2_N, MAY_UNDERFLOW, SHIFT, TAB, UNDERFLOW, expf_fma};
    use std::arch::x86_64::*;

    /// [`super::exp_in_place`] four values at a time ([`exp4`]), the tail one by one.
    #[target_feature(enable = "avx2,fma")]
    pub(super) fn exp_in_place(v: &mut [f32]) {
        let mut v4 = v.chunks_exact_mut(4);
        for x in &mut v4 {
            let e = exp4([x[0], x[1], x[2], x[3]]);
            x.copy_from_slice(&e);
        }
        for x in v4.into_remainder() {
            *x = expf_fma(*x);
        }
    }

    /// [`expf_fma`] of four values: its ordinary path in every lane, then the lanes
    /// below [`UNDERFLOW`] set to 0 and those below [`MAY_UNDERFLOW`] to `2^-149`; when
    /// a lane is NaN, infinite or above 88, all four are taken one by one.
    #[target_feature(enable = "avx2,fma")]
    pub(super) fn exp4(x: [f32; 4]) -> [f32; 4] {
        if x.iter().any(|v| {
            let b = v.to_bits();
            ((b >> 20) & 0x7ff) > 0x42a && (b >> 31 == 0 || (b & 0x7fff_ffff) > 0x7f80_0000)
        }) {
            // Positive and |x| >= 88 (overflow, +inf), or NaN: rare, one by one.
            return x.map(expf_fma);
        }
        let d = |b: u64| _mm256_set1_pd(f64::from_bits(b));
        // SAFETY (loads and stores): `x` and `out` are 4 f32 each, `TAB` 32 u64 and
        // the gather's indices are below 32.
        let xs = unsafe { _mm_loadu_ps(x.as_ptr()) };
        let xd = _mm256_cvtps_pd(xs);
        let z = _mm256_fmadd_pd(d(INV_LN2_N), xd, d(SHIFT));
        let ki = _mm256_castpd_si256(z);
        let kd = _mm256_sub_pd(z, d(SHIFT));
        let r = _mm256_fmsub_pd(d(INV_LN2_N), xd, kd);
        let idx = _mm256_and_si256(ki, _mm256_set1_epi64x(31));
        let t = unsafe { _mm256_i64gather_epi64::<8>(TAB.as_ptr().cast(), idx) };
        let s = _mm256_castsi256_pd(_mm256_add_epi64(t, _mm256_slli_epi64::<47>(ki)));
        let p = _mm256_fmadd_pd(d(C[0]), r, d(C[1]));
        let r2 = _mm256_mul_pd(r, r);
        let y = _mm256_fmadd_pd(d(C[2]), r, _mm256_set1_pd(1.0));
        let y = _mm256_fmadd_pd(p, r2, y);
        let y = _mm256_cvtpd_ps(_mm256_mul_pd(y, s));
        // The lanes below the bounds (-inf among them).
        let f = |b: u32| _mm_set1_ps(f32::from_bits(b));
        let zero = _mm_cmplt_ps(xs, f(UNDERFLOW));
        let least = _mm_andnot_ps(zero, _mm_cmplt_ps(xs, f(MAY_UNDERFLOW)));
        let y = _mm_blendv_ps(y, _mm_castsi128_ps(_mm_set1_epi32(1)), least);
        let y = _mm_andnot_ps(zero, y);
        let mut out = [0.0f32; 4];
        unsafe { _mm_storeu_ps(out.as_mut_ptr(), y) };
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn check(xs: &[f32]) {
        let mut got = xs.to_vec();
        exp_in_place(&mut got);
        for (&x, &g) in xs.iter().zip(&got) {
            assert_eq!(g.to_bits(), x.exp().to_bits(), "exp({x:e}) = {g:e}");
        }
    }

    /// [`check`] of the floats whose bits `bits` gives, a block at a time.
    fn check_all(bits: impl Iterator<Item = u32>) {
        let mut block = Vec::with_capacity(1 << 16);
        for b in bits {
            block.push(f32::from_bits(b));
            if block.len() == block.capacity() {
                check(&block);
                block.clear();
            }
        }
        check(&block);
    }

    /// Every lane is `f32::exp`'s, bit for bit: the bounds and their neighbours, the
    /// special values, groups of four mixing them with ordinary values, every 61st
    /// float from -110 to 90 and every 4099th bit pattern.
    #[test]
    fn every_lane_is_the_platforms_expf() {
        let mut xs = vec![
            0.0,
            -0.0,
            1.0,
            -1.0,
            f32::INFINITY,
            f32::NEG_INFINITY,
            f32::NAN,
            f32::MIN_POSITIVE,
            -f32::MIN_POSITIVE,
            f32::MAX,
            f32::MIN,
            88.0,
            -88.0,
            -104.0,
        ];
        for b in [OVERFLOW, UNDERFLOW, MAY_UNDERFLOW, 0x42b0_0000, 0xc2b0_0000] {
            xs.extend((b - 8..b + 8).map(f32::from_bits));
        }
        check(&xs);
        let mixed = [
            -1.0,
            f32::NAN,
            -200.0,
            -103.5,
            89.0,
            -0.5,
            -103.9,
            -2.0,
            -90.0,
        ];
        check(&mixed);
        let (lo, hi) = ((-110.0f32).to_bits(), 90.0f32.to_bits());
        check_all((0..=hi).step_by(61).chain((0x8000_0000..=lo).step_by(61)));
        check_all((0..=u32::MAX).step_by(4099));
        // The scalar reference itself, where the platform's expf is the FMA build.
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma")
        {
            for &x in xs.iter().chain(&mixed) {
                assert_eq!(expf_fma(x).to_bits(), x.exp().to_bits(), "{x:e}");
            }
        }
    }

    /// All 2^32 floats (about a minute): `cargo test --release --lib expf -- --ignored`.
    #[test]
    #[ignore]
    fn every_float() {
        check_all(0..=u32::MAX);
    }
}
