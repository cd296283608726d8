//! Polynomial exp and ln built from plain float operations (so that lane loops
//! vectorise): Cephes-style polynomials in f32.

/// `exp(x)` for x in [-87, 88] (clamped outside), Cephes-style polynomial, relative
/// error about 2e-7. NaN in gives an unspecified value (callers mask such lanes).
#[inline(always)]
pub fn exp_f32(x: f32) -> f32 {
    exp_poly(x.clamp(-87.0, 88.0))
}

/// The polynomial behind [`exp_f32`] and the rasterizer's `exp_neg`, for `x` in
/// [-87, 88] (the callers clamp to the part of that range they need).
#[inline(always)]
pub(crate) fn exp_poly(x: f32) -> f32 {
    let magic = 12_582_912.0f32;
    let kf = x * std::f32::consts::LOG2_E + magic;
    let k = kf - magic;
    let r = x - k * 0.693_359_4 - k * -2.121_944_4e-4;
    let mut p = 1.987_569_1e-4f32;
    p = p * r + 1.398_2e-3;
    p = p * r + 8.333_452e-3;
    p = p * r + 4.166_579_6e-2;
    p = p * r + 1.666_666_5e-1;
    p = p * r + 0.5;
    let e = p * r * r + r + 1.0;
    let bits = ((kf.to_bits() as i32 - magic.to_bits() as i32 + 127) as u32) << 23;
    e * f32::from_bits(bits)
}

/// Natural log for finite normal `x > 0` (Cephes `logf`), relative error about 1e-7.
#[inline(always)]
pub fn ln_f32(x: f32) -> f32 {
    let bits = x.to_bits();
    // x = m 2^e with m in [0.5, 1).
    let e = ((bits >> 23) & 0xff) as i32 - 126;
    let m = f32::from_bits((bits & 0x007f_ffff) | 0x3f00_0000);
    let small = m < std::f32::consts::FRAC_1_SQRT_2;
    let e = (e - small as i32) as f32;
    let m = if small { m + m } else { m } - 1.0;
    let z = m * m;
    let mut y = 7.037_683_6e-2f32;
    y = y * m - 1.151_461e-1;
    y = y * m + 1.167_699_9e-1;
    y = y * m - 1.242_014_1e-1;
    y = y * m + 1.424_932_3e-1;
    y = y * m - 1.666_805_8e-1;
    y = y * m + 2.000_071_4e-1;
    y = y * m - 2.499_999_4e-1;
    y = y * m + 0.333_333_3;
    y = y * m * z;
    y += -2.121_944_4e-4 * e;
    y += -0.5 * z;
    m + y + 0.693_359_4 * e
}
#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn exp_and_ln_are_accurate() {
        let mut worst_exp = 0.0f64;
        for i in -870_000..=880_000 {
            let x = i as f32 * 1e-4;
            let (a, b) = (exp_f32(x) as f64, (x as f64).exp());
            worst_exp = worst_exp.max(((a - b) / b).abs());
        }
        assert!(worst_exp < 5e-7, "exp relative error {worst_exp}");
        let mut worst_ln = 0.0f64;
        let mut x = 1e-30f32;
        while x < 1e30 {
            let (a, b) = (ln_f32(x) as f64, (x as f64).ln());
            worst_ln = worst_ln.max((a - b).abs() / b.abs().max(1.0));
            x *= 1.0007;
        }
        assert!(worst_ln < 3e-7, "ln error {worst_ln}");
        assert_eq!(ln_f32(1.0), 0.0);
    }
}
