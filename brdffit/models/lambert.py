"""Lambert: f = kd / pi.

| name | range   | meaning                  |
|------|---------|--------------------------|
| kd   | [0, inf)| diffuse albedo, RGB      |
"""

from __future__ import annotations

import jax.numpy as jnp

from .base import KD, AbstractBRDFModel


class Lambert(AbstractBRDFModel):
    name = "lambert"
    auto_candidate = True
    example_params = {"kd": [0.5, 0.35, 0.2]}
    param_specs = (KD,)

    def eval_channels(self, params, frame):
        kd = params["kd"] / jnp.pi
        return jnp.broadcast_to(
            kd.reshape((3,) + (1,) * frame.cos_i.ndim), (3,) + frame.cos_i.shape
        ).astype(frame.cos_i.dtype)

    def eval_frame(self, params, frame):
        return jnp.broadcast_to(params["kd"] / jnp.pi, frame.cos_i.shape + (3,)).astype(
            frame.cos_i.dtype
        )
