#!/usr/bin/env -S sh -c 'exec "$(dirname "$0")/../../vendor/venv/bin/python" "$0" "$@"'
"""Set-up step: the Gaussian prior as ONNX graphs with a real diffusion model's I/O.

Writes vendor/models/gaussian-prior/:
  vae_encoder.onnx    sample [B,3,H,W] in [-1,1] -> latent [B,4,H/8,W/8] (unscaled mean)
                      8x8 average pool, then a 1x1 linear map ENC (4x3)
  vae_decoder.onnx    latent_sample [B,4,h,w] (unscaled) -> sample [B,3,8h,8w] in [-1,1]
                      1x1 linear map pinv(ENC) = ENC^T/4, then 8x nearest upsampling
  image_encoder.onnx  image [B,3,64,64] (normalised to [-1,1]) -> style_tokens, content_tokens
                      [B,1,9]: the latents' per-channel mean/variance packed as tokens
  unet.onnx           sample [B,4,h,w], timestep int64 [B], encoder_hidden_states [B,L,9],
                      image_tokens [B,N,9] -> out_sample [B,4,h,w]: the closed-form eps
  null.npy, prompt.npy  text "embeddings" [1,2,9] (one token and one zero padding token)
  model.json          the model manifest (family gaussian)
and vendor/models/gaussian-prior-controlnet/, a test-only variant (family custom) whose
UNet also takes SDXL text_embeds/time_ids and ControlNet residuals from a test
ControlNet, and whose VAE encoder outputs mean+logvar moments (see controlnet(),
unet_controlled() and vae_encoder_moments() below).

The maths is documented in src/prior/gaussian.rs; the constants below must equal the
ones there (the Rust tests compare both implementations). Idempotent: skips when the
output's stamp matches this script's hash. Uses numpy and onnx only.
"""
import hashlib
import json
import os
import shutil
import sys

import numpy as np
import onnx
from onnx import TensorProto, helper, numpy_helper

C = 4
DOWNSAMPLE = 8
SCALING_FACTOR = 0.5
TOKEN_DIM = 1 + 2 * C
ENCODER_SIZE = 64
ENC = np.array([[1, 1, 1], [1, -1, 1], [1, 1, -1], [1, -1, -1]], dtype=np.float32)
DEC = ENC.T / 4.0
PROMPT_MEAN = np.array([0.2, -0.1, 0.05, 0.0], dtype=np.float32)
PROMPT_VAR = np.array([0.8, 1.1, 0.9, 1.0], dtype=np.float32)
OPSET = 17


def alphas_cumprod(n=1000, beta_start=0.00085, beta_end=0.012):
    """Stable Diffusion's scaled-linear schedule, in float64 (as src/scheduler.rs)."""
    betas = np.linspace(np.sqrt(beta_start), np.sqrt(beta_end), n, dtype=np.float64) ** 2
    return np.cumprod(1.0 - betas)


def const(name, arr):
    return numpy_helper.from_array(np.asarray(arr), name)


def model(nodes, inputs, outputs, inits, name):
    g = helper.make_graph(nodes, name, inputs, outputs, inits)
    m = helper.make_model(g, opset_imports=[helper.make_opsetid("", OPSET)],
                          producer_name="fantasystyle-setup")
    m.ir_version = 8
    onnx.checker.check_model(m)
    return m


def f32(name, shape):
    return helper.make_tensor_value_info(name, TensorProto.FLOAT, shape)


def encoder_nodes(inp, out, scale):
    """pool 8x8 -> 1x1 conv ENC (-> * scale)."""
    nodes = [
        helper.make_node("AveragePool", [inp], ["pooled"], kernel_shape=[8, 8], strides=[8, 8]),
        helper.make_node("Conv", ["pooled", "enc_w"], ["raw" if scale != 1.0 else out]),
    ]
    inits = [const("enc_w", ENC.reshape(C, 3, 1, 1))]
    if scale != 1.0:
        nodes.append(helper.make_node("Mul", ["raw", "scale"], [out]))
        inits.append(const("scale", np.float32(scale)))
    return nodes, inits


def vae_encoder():
    nodes, inits = encoder_nodes("sample", "latent", 1.0)
    return model(nodes, [f32("sample", ["B", 3, "H", "W"])],
                 [f32("latent", ["B", C, "h", "w"])], inits, "vae_encoder")


def vae_encoder_moments():
    """As vae_encoder, but the output is diffusers' moments [mean, logvar] (2C channels,
    logvar = -3): fantasystyle must take the first C channels."""
    nodes, inits = encoder_nodes("sample", "mean", 1.0)
    nodes += [helper.make_node("Mul", ["mean", "zero"], ["z"]),
              helper.make_node("Add", ["z", "minus3"], ["logvar"]),
              helper.make_node("Concat", ["mean", "logvar"], ["latent"], axis=1)]
    inits += [const("zero", np.float32(0)), const("minus3", np.float32(-3))]
    return model(nodes, [f32("sample", ["B", 3, "H", "W"])],
                 [f32("latent", ["B", 2 * C, "h", "w"])], inits, "vae_encoder_moments")


def vae_decoder():
    nodes = [
        helper.make_node("Conv", ["latent_sample", "dec_w"], ["small"]),
        helper.make_node("Resize", ["small", "", "scales"], ["sample"], mode="nearest"),
    ]
    inits = [const("dec_w", DEC.reshape(3, C, 1, 1).astype(np.float32)),
             const("scales", np.array([1, 1, DOWNSAMPLE, DOWNSAMPLE], dtype=np.float32))]
    return model(nodes, [f32("latent_sample", ["B", C, "h", "w"])],
                 [f32("sample", ["B", 3, "H", "W"])], inits, "vae_decoder")


def image_encoder():
    nodes, inits = encoder_nodes("image", "lat", SCALING_FACTOR)
    nodes += [
        helper.make_node("ReduceMean", ["lat"], ["mean_k"], axes=[2, 3], keepdims=1),
        helper.make_node("Sub", ["lat", "mean_k"], ["dev"]),
        helper.make_node("Mul", ["dev", "dev"], ["dev2"]),
        helper.make_node("ReduceMean", ["dev2"], ["var"], axes=[2, 3], keepdims=0),
        helper.make_node("ReduceMean", ["lat"], ["mean"], axes=[2, 3], keepdims=0),
        # weight column: 1 per image, built from the batch dimension
        helper.make_node("Slice", ["mean", "s0", "s1", "ax1"], ["m0"]),
        helper.make_node("Mul", ["m0", "zero"], ["z0"]),
        helper.make_node("Add", ["z0", "one"], ["w"]),
        helper.make_node("Mul", ["mean", "zero"], ["zmean"]),
        helper.make_node("Concat", ["w", "mean", "var"], ["st2"], axis=1),
        helper.make_node("Concat", ["w", "zmean", "var"], ["ct2"], axis=1),
        helper.make_node("Unsqueeze", ["st2", "ax1"], ["style_tokens"]),
        helper.make_node("Unsqueeze", ["ct2", "ax1"], ["content_tokens"]),
    ]
    inits += [const("s0", np.array([0], np.int64)), const("s1", np.array([1], np.int64)),
              const("ax1", np.array([1], np.int64)), const("zero", np.float32(0)),
              const("one", np.float32(1))]
    return model(nodes, [f32("image", ["B", 3, ENCODER_SIZE, ENCODER_SIZE])],
                 [f32("style_tokens", ["B", 1, TOKEN_DIM]),
                  f32("content_tokens", ["B", 1, TOKEN_DIM])], inits, "image_encoder")


def unet():
    ab = alphas_cumprod().astype(np.float32)
    nodes = [
        helper.make_node("Gather", ["ab_table", "timestep"], ["ab1"], axis=0),
        helper.make_node("Reshape", ["ab1", "shape_b111"], ["ab"]),
        helper.make_node("Sqrt", ["ab"], ["sa"]),
        helper.make_node("Sub", ["one", "ab"], ["omab"]),
        helper.make_node("Sqrt", ["omab"], ["s1"]),
        helper.make_node("ReduceSum", ["encoder_hidden_states", "ax1"], ["st"], keepdims=0),
        helper.make_node("ReduceSum", ["image_tokens", "ax1"], ["si"], keepdims=0),
        helper.make_node("Add", ["st", "si"], ["tok"]),
        helper.make_node("Slice", ["tok", "i0", "i1", "ax1"], ["w"]),
        helper.make_node("Slice", ["tok", "i1", "i5", "ax1"], ["wmu"]),
        helper.make_node("Slice", ["tok", "i5", "i9", "ax1"], ["wvar"]),
        helper.make_node("Div", ["wmu", "w"], ["mu2"]),
        helper.make_node("Div", ["wvar", "w"], ["var2"]),
        helper.make_node("Reshape", ["mu2", "shape_bc11"], ["mu"]),
        helper.make_node("Reshape", ["var2", "shape_bc11"], ["var"]),
        helper.make_node("Mul", ["sa", "mu"], ["samu"]),
        helper.make_node("Sub", ["sample", "samu"], ["num0"]),
        helper.make_node("Mul", ["s1", "num0"], ["num"]),
        helper.make_node("Mul", ["ab", "var"], ["abvar"]),
        helper.make_node("Add", ["abvar", "omab"], ["den"]),
        helper.make_node("Div", ["num", "den"], ["out_sample"]),
    ]
    inits = [const("ab_table", ab), const("one", np.float32(1)),
             const("shape_b111", np.array([-1, 1, 1, 1], np.int64)),
             const("shape_bc11", np.array([-1, C, 1, 1], np.int64)),
             const("ax1", np.array([1], np.int64))]
    inits += [const(f"i{k}", np.array([k], np.int64)) for k in (0, 1, 5, 9)]
    inputs = [f32("sample", ["B", C, "h", "w"]),
              helper.make_tensor_value_info("timestep", TensorProto.INT64, ["B"]),
              f32("encoder_hidden_states", ["B", "L", TOKEN_DIM]),
              f32("image_tokens", ["B", "N", TOKEN_DIM])]
    return model(nodes, inputs, [f32("out_sample", ["B", C, "h", "w"])], inits, "unet")


def controlnet():
    """Test ControlNet with SDXL-style inputs: down_0 = ENC pool8(2 cond - 1) (raw
    latents of the control image), mid = time_ids[:,0]/1000 + text_embeds[:,0]
    broadcast over the latent; sample/timestep/encoder_hidden_states are read but unused
    numerically (multiplied by zero) so the graph keeps them as inputs."""
    nodes, inits = encoder_nodes("cond_pm", "down_0", 1.0)
    nodes = [helper.make_node("Mul", ["controlnet_cond", "two"], ["c2"]),
             helper.make_node("Sub", ["c2", "one"], ["cond_pm"])] + nodes
    nodes += [
        helper.make_node("Slice", ["time_ids", "i0", "i1", "ax1"], ["h0"]),
        helper.make_node("Div", ["h0", "thousand"], ["h1"]),
        helper.make_node("Slice", ["text_embeds", "i0", "i1", "ax1"], ["te0"]),
        helper.make_node("Add", ["h1", "te0"], ["m0"]),
        helper.make_node("Reshape", ["m0", "shape_b111"], ["m1"]),
        helper.make_node("Mul", ["sample", "zero"], ["zs"]),
        helper.make_node("Add", ["zs", "m1"], ["m2"]),
        helper.make_node("ReduceSum", ["encoder_hidden_states"], ["ehs_sum"], keepdims=0),
        helper.make_node("Cast", ["timestep"], ["tf"], to=TensorProto.FLOAT),
        helper.make_node("ReduceSum", ["tf"], ["t_sum"], keepdims=0),
        helper.make_node("Add", ["ehs_sum", "t_sum"], ["junk"]),
        helper.make_node("Mul", ["junk", "zero"], ["junk0"]),
        helper.make_node("Add", ["m2", "junk0"], ["mid"]),
    ]
    inits += [const("two", np.float32(2)), const("one", np.float32(1)),
              const("zero", np.float32(0)), const("thousand", np.float32(1000)),
              const("i0", np.array([0], np.int64)), const("i1", np.array([1], np.int64)),
              const("ax1", np.array([1], np.int64)),
              const("shape_b111", np.array([-1, 1, 1, 1], np.int64))]
    inputs = [f32("sample", ["B", C, "h", "w"]),
              helper.make_tensor_value_info("timestep", TensorProto.INT64, ["B"]),
              f32("encoder_hidden_states", ["B", "L", TOKEN_DIM]),
              f32("controlnet_cond", ["B", 3, "H", "W"]),
              f32("text_embeds", ["B", 2]), f32("time_ids", ["B", 6])]
    return model(nodes, inputs, [f32("down_0", ["B", C, "h", "w"]),
                                 f32("mid", ["B", C, "h", "w"])], inits, "controlnet")


def unet_controlled():
    """The Gaussian UNet plus SDXL inputs and ControlNet residuals:
    out = eps + down_res_0 + mid_res + text_embeds[:,1] + 0 * time_ids."""
    m = unet()
    g = m.graph
    last = g.node[-1]
    last.output[0] = "eps"
    g.node.extend([
        helper.make_node("Add", ["eps", "down_res_0"], ["e1"]),
        helper.make_node("Add", ["e1", "mid_res"], ["e2"]),
        helper.make_node("Slice", ["text_embeds", "i1", "i2", "ax1"], ["te1"]),
        helper.make_node("Reshape", ["te1", "shape_b111"], ["te1r"]),
        helper.make_node("Add", ["e2", "te1r"], ["e3"]),
        helper.make_node("ReduceSum", ["time_ids"], ["ti_sum"], keepdims=0),
        helper.make_node("Mul", ["ti_sum", "zero"], ["ti0"]),
        helper.make_node("Add", ["e3", "ti0"], ["out_sample"]),
    ])
    g.initializer.extend([const("i2", np.array([2], np.int64)), const("zero", np.float32(0))])
    g.input.extend([f32("text_embeds", ["B", 2]), f32("time_ids", ["B", 6]),
                    f32("down_res_0", ["B", C, "h", "w"]), f32("mid_res", ["B", C, "h", "w"])])
    onnx.checker.check_model(m)
    return m


NULL_POOLED = np.array([[0.0, 0.0]], np.float32)
PROMPT_POOLED = np.array([[0.1, 0.2]], np.float32)
CONTROL_SCALE = 0.5


def write_controlled_dir(out):
    """A test model (family custom) exercising ControlNet residuals and SDXL inputs."""
    tmp = write_model_dir(out)
    onnx.save(unet_controlled(), os.path.join(tmp, "unet.onnx"))
    onnx.save(controlnet(), os.path.join(tmp, "controlnet.onnx"))
    onnx.save(vae_encoder_moments(), os.path.join(tmp, "vae_encoder.onnx"))
    np.save(os.path.join(tmp, "null_pooled.npy"), NULL_POOLED)
    np.save(os.path.join(tmp, "prompt_pooled.npy"), PROMPT_POOLED)
    man = manifest()
    man.update(family="custom", name="gaussian-prior-controlnet")
    man["unet"].update(text_embeds="text_embeds", time_ids="time_ids",
                       down_residuals=["down_res_0"], mid_residual="mid_res")
    man["text"]["null"]["pooled"] = "null_pooled.npy"
    man["text"]["prompts"][0]["pooled"] = "prompt_pooled.npy"
    man["controlnet"] = {"file": "controlnet.onnx", "sample": "sample", "timestep": "timestep",
                         "encoder_hidden_states": "encoder_hidden_states",
                         "cond": "controlnet_cond", "text_embeds": "text_embeds",
                         "time_ids": "time_ids", "down_outputs": ["down_0"],
                         "mid_output": "mid", "control": "depth", "scale": CONTROL_SCALE}
    with open(os.path.join(tmp, "model.json"), "w") as f:
        json.dump(man, f, indent=2)
        f.write("\n")
    return tmp


def token(mean, var):
    return np.concatenate([[1.0], mean, var]).astype(np.float32)


def text_tokens(mean, var):
    t = np.zeros((1, 2, TOKEN_DIM), np.float32)
    t[0, 0] = token(mean, var)
    return t


def manifest():
    return {
        "format": "fantasystyle-model/1",
        "family": "gaussian",
        "name": "gaussian-prior",
        "latent_channels": C,
        "vae_scaling_factor": SCALING_FACTOR,
        "downsample": DOWNSAMPLE,
        "precision": "fp32",
        "scheduler": {"num_train_timesteps": 1000, "beta_start": 0.00085, "beta_end": 0.012,
                      "beta_schedule": "scaled_linear", "prediction_type": "epsilon"},
        "vae_encoder": {"file": "vae_encoder.onnx", "input": "sample", "output": "latent"},
        "vae_decoder": {"file": "vae_decoder.onnx", "input": "latent_sample",
                        "output": "sample"},
        "unet": {"file": "unet.onnx", "sample": "sample", "timestep": "timestep",
                 "encoder_hidden_states": "encoder_hidden_states",
                 "image_tokens": "image_tokens", "output": "out_sample"},
        "text": {"null": {"file": "null.npy"},
                 "prompts": [{"text": "a gaussian", "file": "prompt.npy"}]},
        "image_encoder": {"file": "image_encoder.onnx", "input": "image",
                          "size": ENCODER_SIZE, "mean": [0.5, 0.5, 0.5],
                          "std": [0.5, 0.5, 0.5], "style_output": "style_tokens",
                          "content_output": "content_tokens"},
    }


def write_model_dir(out):
    tmp = out + ".partial"
    shutil.rmtree(tmp, ignore_errors=True)
    os.makedirs(tmp)
    for name, m in [("vae_encoder", vae_encoder()), ("vae_decoder", vae_decoder()),
                    ("image_encoder", image_encoder()), ("unet", unet())]:
        onnx.save(m, os.path.join(tmp, name + ".onnx"))
    np.save(os.path.join(tmp, "null.npy"), text_tokens(np.zeros(C, np.float32),
                                                       np.ones(C, np.float32)))
    np.save(os.path.join(tmp, "prompt.npy"), text_tokens(PROMPT_MEAN, PROMPT_VAR))
    with open(os.path.join(tmp, "model.json"), "w") as f:
        json.dump(manifest(), f, indent=2)
        f.write("\n")
    return tmp


def install(out, writer, stamp):
    """Write `out` with `writer` unless its stamp matches; replace it atomically."""
    stamp_file = os.path.join(out, ".stamp")
    if os.path.isfile(stamp_file) and open(stamp_file).read().strip() == stamp:
        print(f"gaussian prior: {out} is up to date")
        return
    os.makedirs(os.path.dirname(os.path.abspath(out)), exist_ok=True)
    tmp = writer(out)
    with open(os.path.join(tmp, ".stamp"), "w") as f:
        f.write(stamp + "\n")
    shutil.rmtree(out, ignore_errors=True)
    os.rename(tmp, out)
    print(f"gaussian prior: wrote {out}")


def main():
    root = sys.argv[1] if len(sys.argv) > 1 else "."
    models = os.path.join(root, "vendor/models")
    with open(os.path.abspath(__file__), "rb") as f:
        stamp = hashlib.sha256(f.read()).hexdigest()
    install(os.path.join(models, "gaussian-prior"), write_model_dir, stamp)
    # Test-only variant with a ControlNet and SDXL-style inputs.
    install(os.path.join(models, "gaussian-prior-controlnet"), write_controlled_dir, stamp)


if __name__ == "__main__":
    main()
