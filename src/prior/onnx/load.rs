//! Loading the ONNX diffusion prior's parts: the text embeddings (`.npy` or the text
//! encoder), the VAE, UNet and ControlNet sessions checked against the manifest's graph
//! contract ([`crate::prior::manifest`]), and the IP-Adapter image-prompt tokens of the
//! style image with InstantStyle's per-layer scales (Wang et al. 2024, "InstantStyle",
//! Sec. 3).

use super::*;

fn load_npy3(md: &ModelDir, what: &str, file: &str) -> Result<Array3<f32>> {
    let a = read_npy_f32(&md.file(file))?;
    let p = md.file(file);
    if a.shape.len() != 3 || a.shape[0] != 1 {
        return Err(Error::input(
            &p,
            format!("{what}: expected shape [1, L, D], found {:?}", a.shape),
        ));
    }
    if a.data.iter().any(|x| !x.is_finite()) {
        return Err(Error::input(
            &p,
            format!("{what}: contains NaN or infinity"),
        ));
    }
    Array3::from_shape_vec((1, a.shape[1], a.shape[2]), a.data)
        .map_err(|e| Error::input(&p, e.to_string()))
}

fn load_npy2(md: &ModelDir, what: &str, file: &str) -> Result<Array2<f32>> {
    let p = md.file(file);
    let a = read_npy_f32(&p)?;
    if a.shape.len() != 2 || a.shape[0] != 1 || a.data.iter().any(|x| !x.is_finite()) {
        return Err(Error::input(
            &p,
            format!(
                "{what}: expected finite values of shape [1, P], found {:?}",
                a.shape
            ),
        ));
    }
    Array2::from_shape_vec((1, a.shape[1]), a.data).map_err(|e| Error::input(&p, e.to_string()))
}

impl OnnxPrior {
    /// The null and prompt text embeddings: the prompt pre-embedded if exported, else
    /// through the text encoder; their shapes must agree.
    pub(super) fn texts(
        md: &ModelDir,
        text_cfg: &TextConfig,
        opts: &PriorOptions,
        cfg: &SessionConfig,
    ) -> Result<(Text, Text)> {
        let read_text = |file: &str, pooled: &Option<String>, what: &str| -> Result<Text> {
            Ok(Text {
                hidden: load_npy3(md, what, file)?,
                pooled: pooled
                    .as_ref()
                    .map(|p| load_npy2(md, what, p))
                    .transpose()?,
            })
        };
        let null = read_text(&text_cfg.null.file, &text_cfg.null.pooled, "text.null")?;
        // The prompt: pre-embedded if exported, else through the text encoder.
        let exported = match &opts.prompt {
            None => Some(&text_cfg.prompts[0]),
            Some(want) => text_cfg.prompts.iter().find(|p| &p.text == want),
        };
        let (prompt, source) = match (exported, &opts.prompt, &text_cfg.encoder) {
            (Some(e), _, _) => (
                read_text(&e.file, &e.pooled, "text.prompts")?,
                e.file.clone(),
            ),
            (None, Some(want), Some(enc)) => {
                let mut te = TextEncoder::load(md, enc, cfg)?;
                (te.encode(want)?, enc.file.clone())
            }
            (None, want, _) => {
                return Err(md.err(format!(
                    "no embedding for prompt {:?} and no text encoder in this model; exported \
                     prompts: {:?} (re-export with scripts/export_models.py, which adds the text \
                     encoder, or pass one of these)",
                    want.as_deref().unwrap_or_default(),
                    text_cfg.prompts.iter().map(|p| &p.text).collect::<Vec<_>>()
                )));
            }
        };
        if prompt.hidden.shape() != null.hidden.shape()
            || prompt.pooled.as_ref().map(|p| p.dim()) != null.pooled.as_ref().map(|p| p.dim())
        {
            return Err(md.err(format!(
                "the prompt embedding from {source} has shape {:?} (pooled {:?}), the null \
                 embedding {:?} (pooled {:?}): they must agree",
                prompt.hidden.shape(),
                prompt.pooled.as_ref().map(|p| p.dim()),
                null.hidden.shape(),
                null.pooled.as_ref().map(|p| p.dim()),
            )));
        }
        Ok((null, prompt))
    }

    /// The VAE encoder and decoder, checked against the manifest (`c` latent channels).
    pub(super) fn vae(
        md: &ModelDir,
        ve: &SimpleGraph,
        vd: &SimpleGraph,
        c: usize,
        cfg: &SessionConfig,
    ) -> Result<(Graph, Graph)> {
        let vae_encoder = Graph::load(md, "vae_encoder", &ve.file, cfg)?;
        vae_encoder.check(false, &ve.input, Kind::F32(&[4]), &[(1, 3)])?;
        vae_encoder.check(true, &ve.output, Kind::F32(&[4]), &[])?;
        vae_encoder.check_all_fed(&[&ve.input])?;
        if let Some(ch) = vae_encoder
            .session
            .outputs()
            .iter()
            .find(|o| o.name() == ve.output)
            .and_then(|o| match o.dtype() {
                ValueType::Tensor { shape, .. } => shape.get(1).copied(),
                _ => None,
            })
            && ch >= 0
            && ch as usize != c
            && ch as usize != 2 * c
        {
            return Err(vae_encoder.err(format_args!(
                "output `{}` has {ch} channels, expected {c} (mean) or {} (mean and logvar)",
                ve.output,
                2 * c
            )));
        }
        let vae_decoder = Graph::load(md, "vae_decoder", &vd.file, cfg)?;
        vae_decoder.check(false, &vd.input, Kind::F32(&[4]), &[(1, c)])?;
        vae_decoder.check(true, &vd.output, Kind::F32(&[4]), &[(1, 3)])?;
        vae_decoder.check_all_fed(&[&vd.input])?;
        Ok((vae_encoder, vae_decoder))
    }

    /// The UNet, checked against the manifest: `(c, l, d)` = latent channels, text
    /// tokens and text width; every input fed.
    pub(super) fn unet(
        md: &ModelDir,
        u: &UnetGraph,
        (c, l, d): (usize, usize, usize),
        null: &Text,
        image_tokens: Option<&ImageTokens>,
        cfg: &SessionConfig,
    ) -> Result<Graph> {
        let unet = Graph::load(md, "unet", &u.file, cfg)?;
        let mut fed: Vec<&str> = vec![&u.sample, &u.timestep, &u.encoder_hidden_states];
        unet.check(false, &u.sample, Kind::F32(&[4]), &[(1, c)])?;
        unet.check(false, &u.timestep, Kind::Timestep, &[])?;
        unet.check(
            false,
            &u.encoder_hidden_states,
            Kind::F32(&[3]),
            &[(1, l), (2, d)],
        )?;
        unet.check(true, &u.output, Kind::F32(&[4]), &[(1, c)])?;
        if let Some(te) = &u.text_embeds {
            let p = null.pooled.as_ref().expect("validated").dim().1;
            unet.check(false, te, Kind::F32(&[2]), &[(1, p)])?;
            fed.push(te);
        }
        if let Some(ti) = &u.time_ids {
            unet.check(false, ti, Kind::F32(&[2]), &[(1, 6)])?;
            fed.push(ti);
        }
        match (&u.image_tokens, image_tokens) {
            (Some(it), Some(tok)) => {
                let (_, n, dd) = tok.uncond.dim();
                unet.check(false, it, Kind::F32(&[3]), &[(1, n), (2, dd)])?;
                fed.push(it);
                if let (Some(sc), Some(s)) = (&u.image_scale, &tok.scales) {
                    unet.check(false, sc, Kind::F32(&[2]), &[(1, s.none.dim().1)])?;
                    fed.push(sc);
                }
            }
            (Some(it), None) => {
                return Err(unet.err(format_args!(
                    "input `{it}` (image tokens) needs an image_encoder graph in the manifest"
                )));
            }
            _ => {}
        }
        for r in &u.down_residuals {
            unet.check(false, r, Kind::F32(&[4]), &[])?;
            fed.push(r);
        }
        if let Some(r) = &u.mid_residual {
            unet.check(false, r, Kind::F32(&[4]), &[])?;
            fed.push(r);
        }
        unet.check_all_fed(&fed)?;
        Ok(unet)
    }

    /// The ControlNet, checked against the manifest like the UNet.
    pub(super) fn controlnet(
        md: &ModelDir,
        cn: &ControlNetGraph,
        (c, l, d): (usize, usize, usize),
        cfg: &SessionConfig,
    ) -> Result<Graph> {
        let g = Graph::load(md, "controlnet", &cn.file, cfg)?;
        let mut fed: Vec<&str> = vec![
            &cn.sample,
            &cn.timestep,
            &cn.encoder_hidden_states,
            &cn.cond,
        ];
        g.check(false, &cn.sample, Kind::F32(&[4]), &[(1, c)])?;
        g.check(false, &cn.timestep, Kind::Timestep, &[])?;
        g.check(
            false,
            &cn.encoder_hidden_states,
            Kind::F32(&[3]),
            &[(1, l), (2, d)],
        )?;
        g.check(false, &cn.cond, Kind::F32(&[4]), &[(1, 3)])?;
        if let Some(te) = &cn.text_embeds {
            g.check(false, te, Kind::F32(&[2]), &[])?;
            fed.push(te);
        }
        if let Some(ti) = &cn.time_ids {
            g.check(false, ti, Kind::F32(&[2]), &[(1, 6)])?;
            fed.push(ti);
        }
        for o in cn.down_outputs.iter().chain([&cn.mid_output]) {
            g.check(true, o, Kind::F32(&[4]), &[])?;
        }
        g.check_all_fed(&fed)?;
        Ok(g)
    }

    /// The style image through the image encoder: its style and content tokens
    /// (`[1, N, D]` each).
    pub(super) fn encode_style(
        g: &mut Graph,
        ie: &ImageEncoderGraph,
        img: &Array4<f32>,
    ) -> Result<(Array3<f32>, Array3<f32>)> {
        if img.dim().0 != 1 {
            return Err(Error::param(format!(
                "style image: expected [1, 3, H, W], got {:?}",
                img.shape()
            )));
        }
        check_images(img.view(), 1, "style image")?;
        let mut x = fit_square(img.view(), ie.size);
        for (k, mut ch) in x.axis_iter_mut(Axis(1)).enumerate() {
            ch.mapv_inplace(|v| (v - ie.mean[k]) / ie.std[k]);
        }
        let out = g.run(
            vec![input(&ie.input, f32_value(x)?)],
            &[&ie.style_output, &ie.content_output],
        )?;
        let to3 = |a: &ArrayD<f32>, o: &str| -> Result<Array3<f32>> {
            a.clone()
                .into_dimensionality()
                .ok()
                .filter(|a: &Array3<f32>| a.dim().0 == 1)
                .ok_or_else(|| {
                    g.err(format_args!(
                        "output `{o}` has shape {:?}, expected [1, N, D]",
                        a.shape()
                    ))
                })
        };
        Ok((
            to3(&out[0], &ie.style_output)?,
            to3(&out[1], &ie.content_output)?,
        ))
    }

    /// Run the image encoder on the style image: (uncond, style, content) tokens, and the
    /// per-layer scales of `image_conditioning`.
    pub(super) fn image_tokens(
        md: &ModelDir,
        ie: &ImageEncoderGraph,
        ic: Option<&ImageConditioning>,
        cfg: &SessionConfig,
        style: Option<&Array4<f32>>,
    ) -> Result<ImageTokens> {
        let mut g = Graph::load(md, "image_encoder", &ie.file, cfg)?;
        g.check(
            false,
            &ie.input,
            Kind::F32(&[4]),
            &[(1, 3), (2, ie.size), (3, ie.size)],
        )?;
        g.check(true, &ie.style_output, Kind::F32(&[3]), &[])?;
        g.check(true, &ie.content_output, Kind::F32(&[3]), &[])?;
        g.check_all_fed(&[&ie.input])?;
        let (style_t, content_t) = match style {
            None => (None, None),
            Some(img) => {
                let (st, ct) = Self::encode_style(&mut g, ie, img)?;
                (Some(st), Some(ct))
            }
        };
        let uncond = match (&ie.uncond_tokens, &style_t) {
            (Some(f), _) => load_npy3(md, "image_encoder.uncond_tokens", f)?,
            (None, Some(s)) => Array3::zeros(s.dim()),
            (None, None) => {
                // No style image: zeros shaped like the encoder's static output, else one token.
                let shape = g
                    .session
                    .outputs()
                    .iter()
                    .find(|o| o.name() == ie.style_output)
                    .and_then(|o| match o.dtype() {
                        ValueType::Tensor { shape, .. } => Some(shape.to_vec()),
                        _ => None,
                    })
                    .unwrap_or_default();
                let n = shape.get(1).copied().filter(|&d| d > 0).unwrap_or(1) as usize;
                let d = shape.get(2).copied().filter(|&d| d > 0).ok_or_else(|| {
                    g.err("the token width is dynamic: give a style image or uncond_tokens")
                })? as usize;
                Array3::zeros((1, n, d))
            }
        };
        for (what, t) in [("style", &style_t), ("content", &content_t)] {
            if let Some(t) = t
                && t.dim() != uncond.dim()
            {
                return Err(g.err(format_args!(
                    "{what} tokens have shape {:?}, the no-image tokens {:?}: they must agree",
                    t.shape(),
                    uncond.shape()
                )));
            }
        }
        Ok(ImageTokens {
            uncond,
            style: style_t,
            content: content_t,
            scales: ic.map(Scales::new),
        })
    }
}
