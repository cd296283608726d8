//! The 2D stylizer as a diffusion prior: the [`Prior`] implementation and its batch of
//! views. Each conditioning's clean image x0_c (the identity for Null and Content,
//! T(x^, s_own) for Prompt, T(x^, s_a) for PromptStyle, with x^ the blurred clean
//! estimate; Ghiasi et al. 2017's transfer network T) gives
//! eps(z_t, t, c) = (z_t - sqrt(ab) x0_c) / sqrt(1 - ab), as the parent module's docs
//! derive.

use super::*;

impl Prior for StylizerPrior {
    fn info(&self) -> &PriorInfo {
        &self.info
    }

    fn unconditional_is_identity(&self) -> bool {
        true
    }

    fn encode(&mut self, images: ArrayView4<'_, f32>) -> Result<Array4<f32>> {
        check_rgb(images, "images")?;
        Ok(images.to_owned())
    }

    fn decode(&mut self, latents: ArrayView4<'_, f32>) -> Result<Array4<f32>> {
        check_rgb(latents, "latents")?;
        Ok(latents.to_owned())
    }

    fn predict_eps(
        &mut self,
        z_t: ArrayView4<'_, f32>,
        t: usize,
        conds: &[Cond],
        control: Option<ArrayView4<'_, f32>>,
    ) -> Result<Vec<Array4<f32>>> {
        self.check_predict_inputs(z_t, conds, control)?;
        let nb = z_t.shape()[0];
        let needs_x0 = conds
            .iter()
            .any(|c| matches!(c, Cond::Prompt | Cond::PromptStyle));
        let (own, styled) = self.view_styles(z_t, t, conds, control)?;
        if needs_x0 {
            // Make the sessions before the parallel part (loading is not timed there).
            for l in self.lanes(nb) {
                l.get()?;
            }
        }

        // Per view (views side by side, one transfer session per worker): the clean
        // estimate, the redrawings it needs, eps for every conditioning.
        let ph = crate::timing::span("views");
        let schedule = &self.schedule;
        let tr = &self.manifest.transform;
        let zoom = self.motif_scale;
        let lanes: &mut [LazyGraph] = if needs_x0 {
            let n = self.lanes.len();
            &mut self.lanes[..n]
        } else {
            &mut []
        };
        let (own, styled) = (&own, &styled);
        // One view on `g` (None: no redrawing needed): eps per conditioning, and the
        // seconds spent (clean estimate, transfer, eps).
        let one = |b: usize, mut g: Option<&mut Graph>| -> Result<ViewOut> {
            let zb = z_t.index_axis(Axis(0), b);
            let t0 = std::time::Instant::now();
            let xh = clean_estimate(schedule, zb, t)?;
            let t1 = std::time::Instant::now();
            let mut calls = 0;
            let mut redraw = |s: &Option<Vec<f32>>| -> Result<Option<Array3<f32>>> {
                match (s, g.as_deref_mut()) {
                    (Some(s), Some(g)) => {
                        calls += 1;
                        stylize_with(g, tr, xh.view(), s, zoom).map(Some)
                    }
                    _ => Ok(None),
                }
            };
            let redrawn = if conds.contains(&Cond::Prompt) {
                redraw(&own[b])?
            } else {
                None
            };
            let restyled = redraw(&styled[b])?;
            let t2 = std::time::Instant::now();
            let eps = conds
                .iter()
                .map(|c| {
                    let x0 = match c {
                        Cond::Null | Cond::Content => &xh,
                        Cond::Prompt => redrawn.as_ref().expect("redrawn above"),
                        Cond::PromptStyle => restyled.as_ref().expect("redrawn above"),
                    };
                    schedule.eps_from_x0(zb, x0.view(), t)
                })
                .collect::<Result<Vec<_>>>()?;
            let secs = |a: std::time::Instant, b: std::time::Instant| (b - a).as_secs_f64();
            let done = [
                secs(t0, t1),
                secs(t1, t2),
                secs(t2, std::time::Instant::now()),
            ];
            Ok((eps, done, calls))
        };
        let per_lane = run_lanes(lanes, nb, one);
        let outs = gather_views(per_lane, conds.len(), z_t, nb)?;
        drop(ph);
        Ok(outs)
    }
}

impl StylizerPrior {
    /// `predict_eps`'s input checks: RGB latents, control images matching them, a style
    /// image for the PromptStyle conditioning.
    pub(super) fn check_predict_inputs(
        &self,
        z_t: ArrayView4<'_, f32>,
        conds: &[Cond],
        control: Option<ArrayView4<'_, f32>>,
    ) -> Result<()> {
        check_rgb(z_t, "z_t")?;
        if let Some(c) = control
            && (c.shape()[0] != z_t.shape()[0] || c.shape()[1] != 3)
        {
            return Err(Error::param(format!(
                "stylizer prior: control images {:?} for latents {:?}",
                c.shape(),
                z_t.shape()
            )));
        }
        if conds.contains(&Cond::PromptStyle) && self.style.is_none() {
            return Err(Error::param(
                "the stylizer prior needs a style image for the PromptStyle conditioning",
            ));
        }
        Ok(())
    }

    /// The style vectors each view is redrawn with: (own, for Prompt; styled, for
    /// PromptStyle), per view.
    pub(super) fn view_styles(
        &mut self,
        z_t: ArrayView4<'_, f32>,
        t: usize,
        conds: &[Cond],
        control: Option<ArrayView4<'_, f32>>,
    ) -> Result<(ViewStyles, ViewStyles)> {
        let nb = z_t.shape()[0];
        let needs_own = conds.contains(&Cond::Prompt)
            || (conds.contains(&Cond::PromptStyle) && self.strength < 1.0);
        // Own styles come from the control images (cached) or, without
        // them, from the clean estimate (computed here for that, and again below).
        let mut own: Vec<Option<Vec<f32>>> = vec![None; nb];
        if needs_own {
            let ph = crate::timing::span("own style");
            for (b, o) in own.iter_mut().enumerate() {
                *o = Some(match control {
                    Some(c) => self.own_style(c.index_axis(Axis(0), b))?,
                    None => {
                        let xh = self.clean_estimate(z_t.index_axis(Axis(0), b), t)?;
                        self.style_vector(xh.view())?
                    }
                });
            }
            drop(ph);
        }
        let (a, target) = (self.strength, self.style.clone());
        let styled: Vec<Option<Vec<f32>>> = (0..nb)
            .map(|b| {
                let target = target.clone()?;
                conds.contains(&Cond::PromptStyle).then(|| match &own[b] {
                    Some(o) if a < 1.0 => o
                        .iter()
                        .zip(&target)
                        .map(|(o, t)| (1.0 - a) * o + a * t)
                        .collect(),
                    _ => target,
                })
            })
            .collect();
        Ok((own, styled))
    }
}

/// Per view, the style vector it is redrawn with (None: not redrawn).
type ViewStyles = Vec<Option<Vec<f32>>>;

/// One view's eps per conditioning, the seconds spent (clean estimate, transfer, eps)
/// and the transfer calls.
type ViewOut = (Vec<Array3<f32>>, [f64; 3], usize);

/// Each lane's views: `(view, result)` for views `k, k + lanes, ...` on lane `k`, the
/// lanes side by side; one lane without a graph when `lanes` is empty.
fn run_lanes(
    lanes: &mut [LazyGraph],
    nb: usize,
    one: impl Fn(usize, Option<&mut Graph>) -> Result<ViewOut> + Sync,
) -> LaneResults {
    let n_lanes = lanes.len().max(1);
    if lanes.is_empty() {
        vec![(0..nb).map(|b| Ok((b, one(b, None)?))).collect()]
    } else {
        use rayon::prelude::*;
        lanes
            .par_iter_mut()
            .enumerate()
            .map(|(k, lane)| {
                let g = lane.get()?;
                (k..nb)
                    .step_by(n_lanes)
                    .map(|b| Ok((b, one(b, Some(&mut *g))?)))
                    .collect()
            })
            .collect()
    }
}

/// Per lane, its views' `(view, result)`.
type LaneResults = Vec<Result<Vec<(usize, ViewOut)>>>;

/// The views' eps gathered into one batch per conditioning (`n_conds` of `z_t`'s shape),
/// with the summed times recorded.
fn gather_views(
    per_lane: LaneResults,
    n_conds: usize,
    z_t: ArrayView4<'_, f32>,
    nb: usize,
) -> Result<Vec<Array4<f32>>> {
    let mut outs: Vec<Array4<f32>> = (0..n_conds).map(|_| Array4::zeros(z_t.raw_dim())).collect();
    let (mut spent, mut transfers) = ([0.0f64; 3], 0u64);
    for r in per_lane {
        for (b, (eps, secs, calls)) in r? {
            for (k, e) in eps.into_iter().enumerate() {
                outs[k].index_axis_mut(Axis(0), b).assign(&e);
            }
            spent.iter_mut().zip(secs).for_each(|(a, s)| *a += s);
            transfers += calls as u64;
        }
    }
    let d = std::time::Duration::from_secs_f64;
    crate::timing::add("clean estimate [summed]", d(spent[0]), nb as u64);
    crate::timing::add("transfer net [summed]", d(spent[1]), transfers);
    crate::timing::add("eps [summed]", d(spent[2]), nb as u64);
    Ok(outs)
}

fn check_rgb(a: ArrayView4<'_, f32>, what: &str) -> Result<()> {
    if a.shape()[1] != 3 {
        return Err(Error::param(format!(
            "stylizer prior: {what} must have 3 channels, got shape {:?}",
            a.shape()
        )));
    }
    if a.iter().any(|v| !v.is_finite()) {
        return Err(Error::param(format!(
            "stylizer prior: {what} hold NaN or infinity"
        )));
    }
    Ok(())
}
