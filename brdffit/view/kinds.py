"""The plots there are and what each accepts, as names and ranges only.

:mod:`brdffit.view.plots` draws them (matplotlib and JAX); the shells that only
offer or check a plot request read this module instead, so the service's front
starts without either (tests/test_api.py checks the running server).
"""

from __future__ import annotations

#: Every plot of a fit, in the order a person reads them.
KINDS = ("slices", "error_map", "spheres", "polar", "report")

#: The plots of a sample list's fit alone (brdffit.view.sample_plot): every sample, fitted
#: against measured. A table's fit has none.
SAMPLE_KINDS = ("samples",)

#: The plots of auto's choice alone (brdffit.view.plots.ranking): every candidate's error
#: and look, and why the chosen one. A fit of one named model has none.
SELECTION_KINDS = ("ranking",)

#: The plots that show sphere renders, so take an ``exposure_ev``.
EXPOSED_KINDS = ("spheres", "report")

#: Exposure changes (stops, EV) a sphere plot accepts: down to a mirror's highlight, and
#: up to where the verdict judges the darkest glossy materials (each light at the
#: table's typical lit pixel: over +6 EV on 24 of the 100 MERL materials, black-obsidian
#: +11.2, black-phenolic +8.7; the plots' rows say so), so every verdict's picture can
#: be drawn.
EXPOSURE_EV_RANGE = (-6.0, 12.0)


def check_exposure_ev(exposure_ev: float) -> float:
    """``exposure_ev`` as a float, or ValueError naming the accepted range."""
    lo, hi = EXPOSURE_EV_RANGE
    try:
        ev = float(exposure_ev)
    except (TypeError, ValueError):
        raise ValueError(f"exposure_ev must be a number of stops, got {exposure_ev!r}") from None
    if not lo <= ev <= hi:  # NaN fails this too
        raise ValueError(f"exposure_ev must be within {lo:g}..{hi:+g} stops, got {exposure_ev!r}")
    return ev


def exposure_refused(kind: str, exposure_ev: float) -> str | None:
    """Why plot ``kind`` cannot take ``exposure_ev`` (a plot without sphere renders
    and a non-zero exposure), or None: the service refuses the request with it."""
    if exposure_ev and kind not in EXPOSED_KINDS:
        return (f"the {kind} plot has no sphere renders to expose; "
                f"exposure_ev applies to {', '.join(EXPOSED_KINDS)}")
    return None
