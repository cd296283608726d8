//! Run-time prompts: the model's own tokenizer(s) and text encoder graph turn any prompt
//! into the UNet's text conditioning, so `--prompt` takes any text (FantasyStyle's CSD,
//! Sec. 4, conditions the target branch on a prompt P).
//!
//! `model.json`'s `text.encoder` names the graph (`text_encoder.onnx`: `input_ids` int64
//! `[B, 77]`, plus `input_ids_2` for SDXL's second encoder) and, per input, the
//! Hugging Face `tokenizer.json` written beside it by `scripts/export_models.py`, the
//! sequence length and the padding id. Tokenizing follows the diffusers pipelines:
//! CLIP's byte-level BPE with start and end marks, truncated to the length (keeping
//! both marks) and padded with the pad id. Outputs: hidden states `[1, L, D]` and, for
//! SDXL, the pooled embedding `[1, P]`.
//!
//! The `tokenizers` crate reads the files; `scripts/reference/clip_bpe_ref.py` (an
//! independent plain-Python BPE) wrote the token ids the tests compare against.

use super::manifest::{ModelDir, TextEncoderGraph};
use super::session::{Graph, Kind};
use crate::runtime::SessionConfig;
use crate::{Error, Result};
use ndarray::{Array2, Array3};
use ort::session::SessionInputValue;
use ort::value::Tensor;
use std::borrow::Cow;
use std::path::PathBuf;
use tokenizers::{PaddingParams, PaddingStrategy, Tokenizer, TruncationParams};

/// A text conditioning: hidden states `[1, L, D]` and, for SDXL, the pooled embedding
/// `[1, P]`.
#[derive(Debug, Clone)]
pub struct Text {
    pub hidden: Array3<f32>,
    pub pooled: Option<Array2<f32>>,
}

/// One tokenizer and the encoder input it feeds.
struct Input {
    name: String,
    file: PathBuf,
    max_length: usize,
    tokenizer: Tokenizer,
}

/// The model's tokenizer(s) and text encoder graph.
pub struct TextEncoder {
    inputs: Vec<Input>,
    graph: Graph,
    cfg: TextEncoderGraph,
}

impl std::fmt::Debug for TextEncoder {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("TextEncoder")
            .field("file", &self.graph.file)
            .finish()
    }
}

impl TextEncoder {
    /// Load the tokenizers and the graph named by `cfg`, and check the graph's inputs and
    /// outputs.
    pub fn load(md: &ModelDir, cfg: &TextEncoderGraph, scfg: &SessionConfig) -> Result<Self> {
        let mut inputs = Vec::new();
        for t in &cfg.tokenizers {
            let file = md.file(&t.tokenizer);
            let mut tokenizer = Tokenizer::from_file(&file)
                .map_err(|e| Error::input(&file, format!("cannot read the tokenizer: {e}")))?;
            tokenizer
                .with_truncation(Some(TruncationParams {
                    max_length: t.max_length,
                    ..Default::default()
                }))
                .map_err(|e| Error::input(&file, format!("tokenizer truncation: {e}")))?;
            let pad_token = tokenizer.id_to_token(t.pad_id).ok_or_else(|| {
                Error::input(
                    &file,
                    format!("pad id {} (model.json) is not in the vocabulary", t.pad_id),
                )
            })?;
            tokenizer.with_padding(Some(PaddingParams {
                strategy: PaddingStrategy::Fixed(t.max_length),
                pad_id: t.pad_id,
                pad_token,
                ..Default::default()
            }));
            inputs.push(Input {
                name: t.input.clone(),
                file,
                max_length: t.max_length,
                tokenizer,
            });
        }
        let graph = Graph::load(md, "text_encoder", &cfg.file, scfg)?;
        for i in &inputs {
            graph.check(false, &i.name, Kind::I64(&[2]), &[(1, i.max_length)])?;
        }
        graph.check(true, &cfg.hidden_output, Kind::F32(&[3]), &[])?;
        if let Some(p) = &cfg.pooled_output {
            graph.check(true, p, Kind::F32(&[2]), &[])?;
        }
        let fed: Vec<&str> = inputs.iter().map(|i| i.name.as_str()).collect();
        graph.check_all_fed(&fed)?;
        Ok(TextEncoder {
            inputs,
            graph,
            cfg: cfg.clone(),
        })
    }

    /// Token ids of `prompt` for each encoder input, in the manifest's order.
    pub fn tokenize(&self, prompt: &str) -> Result<Vec<Vec<u32>>> {
        self.inputs
            .iter()
            .map(|i| {
                let enc = i
                    .tokenizer
                    .encode(prompt, true)
                    .map_err(|e| Error::input(&i.file, format!("tokenizing {prompt:?}: {e}")))?;
                let ids = enc.get_ids().to_vec();
                if ids.len() != i.max_length {
                    return Err(Error::input(
                        &i.file,
                        format!(
                            "tokenizing {prompt:?} gave {} ids, expected {}",
                            ids.len(),
                            i.max_length
                        ),
                    ));
                }
                Ok(ids)
            })
            .collect()
    }

    /// Hidden states (and pooled embedding) of `prompt`.
    pub fn encode(&mut self, prompt: &str) -> Result<Text> {
        let ids = self.tokenize(prompt)?;
        let mut feeds: Vec<(Cow<'static, str>, SessionInputValue<'static>)> = Vec::new();
        for (i, ids) in self.inputs.iter().zip(ids) {
            let v: Vec<i64> = ids.into_iter().map(i64::from).collect();
            let t =
                Tensor::from_array((vec![1usize, v.len()], v)).map_err(|e| self.graph.err(e))?;
            feeds.push((Cow::Owned(i.name.clone()), t.into()));
        }
        let mut names = vec![self.cfg.hidden_output.as_str()];
        names.extend(self.cfg.pooled_output.as_deref());
        let mut out = self.graph.run(feeds, &names)?.into_iter();
        let hidden = out
            .next()
            .expect("one output per name")
            .into_dimensionality()
            .map_err(|e| self.graph.err(format_args!("output `{}`: {e}", names[0])))?;
        let pooled = match out.next() {
            Some(p) => Some(
                p.into_dimensionality()
                    .map_err(|e| self.graph.err(format_args!("pooled output: {e}")))?,
            ),
            None => None,
        };
        let text = Text { hidden, pooled };
        if text.hidden.dim().0 != 1 || text.pooled.as_ref().is_some_and(|p| p.dim().0 != 1) {
            return Err(self.graph.err("outputs must have batch 1 for one prompt"));
        }
        if text
            .hidden
            .iter()
            .chain(text.pooled.iter().flatten())
            .any(|x| !x.is_finite())
        {
            return Err(self
                .graph
                .err(format_args!("NaN or infinity encoding {prompt:?}")));
        }
        Ok(text)
    }
}
