"""How a fit looks next to its measurement: the ``quality`` block of every result.

    quality = {"render_psnr_db": ..., "colour_shift": [r, g, b], "verdict": ..., "reason": ...}

- ``render_psnr_db``: the PSNR of the fit's tone-mapped sphere renders against the
  table's (``brdffit.fitting.sphere``: key and grazing light, one exposure per
  light; the result's ``error.psnr_db``);
- ``colour_shift``: per channel, the relative error of the mean radiance of the
  key-light sphere (``sphere.sphere_colour_error``; 0.1 = 10% too bright, None for
  a channel the table leaves black);
- ``verdict``: ``good``, ``visible`` or ``poor``, and ``reason``: the figure that
  decided it, in words (the CLI prints both on one line).

The thresholds (:data:`GOOD`, :data:`POOR`) were set by looking at sphere plots
(``brdffit fit --plots``, its spheres.png) of ggx fits to the 100 real MERL materials under
every loss (docs/results.md shows examples at each level): at 28 dB and within 10%
per channel the fit and the measurement are hard to tell apart side by side
(polyethylene, delrin, teflon); below 20 dB, or half a stop off in a channel, the
difference is plain at a glance (gold-metallic-paint under the log loss, a
highlight ~3x too bright; black-soft-plastic, ~1 stop too bright); between, it is
visible when looking for it (a broader highlight, a tint).
"""

from __future__ import annotations

import math

from brdffit.fitting.sphere import sphere_colour_error

#: (least PSNR in dB, largest |colour shift|) for each verdict.
GOOD = (28.0, 0.10)
POOR = (20.0, 0.50)
VERDICTS = ("good", "visible", "poor")


def verdict(render_psnr_db: float | None, colour_shift) -> tuple[str, str]:
    """(verdict, reason) of a PSNR (dB) and per-channel shifts (None: unknown)."""
    shifts = [abs(s) for s in colour_shift if s is not None and math.isfinite(s)]
    worst = max(shifts, default=0.0)
    channel = "RGB"[[abs(s) if s is not None else -1 for s in colour_shift].index(worst)] \
        if shifts else "-"
    psnr_known = render_psnr_db is not None and math.isfinite(render_psnr_db)
    if not psnr_known:
        return "poor", "the fit's sphere render could not be compared (no finite PSNR)"
    if render_psnr_db < POOR[0]:
        return "poor", (f"sphere render {render_psnr_db:.1f} dB from the measurement "
                        f"(poor below {POOR[0]:g} dB)")
    if worst > POOR[1]:
        return "poor", (f"{channel} channel {_percent(colour_shift, channel)} off in mean "
                        f"radiance (poor beyond {POOR[1]:.0%})")
    if render_psnr_db >= GOOD[0] and worst <= GOOD[1]:
        return "good", (f"sphere render {render_psnr_db:.1f} dB, colour within {worst:.0%} "
                        f"(good: >= {GOOD[0]:g} dB and within {GOOD[1]:.0%})")
    if render_psnr_db < GOOD[0]:
        return "visible", (f"sphere render {render_psnr_db:.1f} dB from the measurement "
                           f"(good from {GOOD[0]:g} dB)")
    return "visible", (f"{channel} channel {_percent(colour_shift, channel)} off in mean "
                       f"radiance (good within {GOOD[1]:.0%})")


def _percent(colour_shift, channel: str) -> str:
    return f"{colour_shift['RGB'.index(channel)]:+.0%}"


def quality(table, model, params: dict, render_psnr_db: float, colour_shift=None) -> dict:
    """The quality block of a fit with ``params`` of ``model`` to ``table``;
    ``colour_shift``: its :func:`sphere_colour_error` where the caller has it
    (``SphereReference.psnr_and_colour``)."""
    shift = (sphere_colour_error(table, model, params) if colour_shift is None
             else colour_shift)
    shift = [None if s is None or not math.isfinite(s) else float(s) for s in shift]
    word, reason = verdict(render_psnr_db, shift)
    psnr = float(render_psnr_db) if render_psnr_db is not None else None
    return {"render_psnr_db": psnr if psnr is None or math.isfinite(psnr) else None,
            "colour_shift": shift, "verdict": word, "reason": reason}
