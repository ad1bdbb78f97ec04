"""The device a benchmark ran on, named for its tables: the JAX device and, on an accelerator, its
model (e.g. "cuda:0 (NVIDIA H200)"); on the CPU the device alone ("TFRT_CPU_0")."""

from __future__ import annotations


def describe(device=None) -> str:
    import jax

    d = jax.devices()[0] if device is None else device
    return str(d) if d.platform == "cpu" else f"{d} ({d.device_kind})"
