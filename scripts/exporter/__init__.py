"""The parts of `scripts/export_models.py` (the exporter's command line and `main` are
there): `models` (the diffusers pipelines, real and tiny random), `routing`
(IP-Adapter routed per layer and per batch row), `wrappers` (the graphs' I/O as
nn.Modules), `graphs` (ONNX export, tokenizers, pre-embedded text) and `reference`
(the eager-diffusers outputs `--tiny` writes for the Rust tests)."""
