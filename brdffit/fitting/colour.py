"""Colour differences as people see them: CIELAB and CIEDE2000 of linear RGB.

A fit's colour is judged on the mean radiance of its lit sphere against the table's
(``brdffit.fitting.sphere.sphere_colour``), split in two figures a person reads apart:

- ``brightness_stops``: ``log2(Y_fit / Y_table)`` of the mean luminance (Rec. 709
  weights); +1 is twice as bright, the unit a photographer or a look-development
  artist adjusts exposure in;
- ``colour_delta_e``: CIEDE2000 (Sharma, Wu and Dalal 2005) between the two mean
  colours at *equal* luminance, both displayed at :data:`DISPLAY_Y` (L* ~ 57, a
  mid-tone on screen): hue and saturation alone, brightness being the figure above.

Why not each channel's relative error: a saturated yellow's blue channel is a few
per cent of its red and green, so +74% of it is a difference nobody sees, and a
grey's 10% in one channel is plain to everyone. CIELAB weighs channels as the eye
does. The table's RGB is taken as linear Rec. 709 / sRGB primaries with a D65 white
(the MERL tables' RGB, as every renderer reading the exports takes it).
"""

from __future__ import annotations

import math

import numpy as np

#: Linear Rec. 709 (sRGB primaries, D65) to CIE XYZ (IEC 61966-2-1).
RGB_TO_XYZ = np.array([
    [0.4124564, 0.3575761, 0.1804375],
    [0.2126729, 0.7151522, 0.0721750],
    [0.0193339, 0.1191920, 0.9503041],
])
#: The D65 white point, Y = 1.
WHITE_D65 = RGB_TO_XYZ @ np.ones(3)
#: The luminance both colours are shown at for ``colour_delta_e`` (L* = 56.8).
DISPLAY_Y = 0.25
#: Below this mean luminance a sphere is black: it has no colour to compare.
BLACK_Y = 1e-12


def luminance(rgb) -> float:
    """Y of linear RGB (Rec. 709)."""
    return float(RGB_TO_XYZ[1] @ np.asarray(rgb, np.float64))


def rgb_to_lab(rgb) -> np.ndarray:
    """CIELAB (L*, a*, b*) of linear RGB (the last axis), relative to the D65 white of
    Y = 1: one colour, or an image's pixels."""
    xyz = np.maximum(np.asarray(rgb, np.float64), 0.0) @ RGB_TO_XYZ.T
    t = xyz / WHITE_D65
    eps = (6.0 / 29.0) ** 3
    f = np.where(t > eps, np.cbrt(t), t / (3 * (6.0 / 29.0) ** 2) + 4.0 / 29.0)
    return np.stack([116.0 * f[..., 1] - 16.0, 500.0 * (f[..., 0] - f[..., 1]),
                     200.0 * (f[..., 1] - f[..., 2])], axis=-1)


def ciede2000(lab1, lab2) -> float:
    """CIEDE2000 colour difference (kL = kC = kH = 1), as Sharma, Wu and Dalal (2005)
    give it, hue-angle conventions included (their test data: tests/test_colour.py)."""
    return float(ciede2000_of(np.asarray(lab1, np.float64), np.asarray(lab2, np.float64)))


def ciede2000_of(lab1: np.ndarray, lab2: np.ndarray) -> np.ndarray:
    """:func:`ciede2000` of each pair of CIELAB colours (the last axis; an image's
    pixels, or one colour)."""
    l1, a1, b1 = np.moveaxis(np.asarray(lab1, np.float64), -1, 0)
    l2, a2, b2 = np.moveaxis(np.asarray(lab2, np.float64), -1, 0)
    c_bar = (np.hypot(a1, b1) + np.hypot(a2, b2)) / 2.0
    g = 0.5 * (1.0 - np.sqrt(c_bar**7 / (c_bar**7 + 25.0**7)))
    a1p, a2p = (1.0 + g) * a1, (1.0 + g) * a2
    c1p, c2p = np.hypot(a1p, b1), np.hypot(a2p, b2)
    h1p = np.where(c1p > 0, np.degrees(np.arctan2(b1, a1p)) % 360.0, 0.0)
    h2p = np.where(c2p > 0, np.degrees(np.arctan2(b2, a2p)) % 360.0, 0.0)
    dl = l2 - l1
    dc = c2p - c1p
    achromatic = c1p * c2p == 0
    dh = h2p - h1p
    dh = np.where(dh > 180.0, dh - 360.0, np.where(dh < -180.0, dh + 360.0, dh))
    dh = np.where(achromatic, 0.0, dh)
    d_big_h = 2.0 * np.sqrt(c1p * c2p) * np.sin(np.radians(dh) / 2.0)
    l_bar = (l1 + l2) / 2.0
    cp_bar = (c1p + c2p) / 2.0
    hp_bar = np.where(achromatic, h1p + h2p,
                      np.where(np.abs(h1p - h2p) <= 180.0, (h1p + h2p) / 2.0,
                               np.where(h1p + h2p < 360.0, (h1p + h2p + 360.0) / 2.0,
                                        (h1p + h2p - 360.0) / 2.0)))
    t = (1.0 - 0.17 * np.cos(np.radians(hp_bar - 30.0))
         + 0.24 * np.cos(np.radians(2.0 * hp_bar))
         + 0.32 * np.cos(np.radians(3.0 * hp_bar + 6.0))
         - 0.20 * np.cos(np.radians(4.0 * hp_bar - 63.0)))
    d_theta = 30.0 * np.exp(-(((hp_bar - 275.0) / 25.0) ** 2))
    r_c = 2.0 * np.sqrt(cp_bar**7 / (cp_bar**7 + 25.0**7))
    s_l = 1.0 + 0.015 * (l_bar - 50.0) ** 2 / np.sqrt(20.0 + (l_bar - 50.0) ** 2)
    s_c = 1.0 + 0.045 * cp_bar
    s_h = 1.0 + 0.015 * cp_bar * t
    r_t = -np.sin(np.radians(2.0 * d_theta)) * r_c
    return np.sqrt((dl / s_l) ** 2 + (dc / s_c) ** 2 + (d_big_h / s_h) ** 2
                   + r_t * (dc / s_c) * (d_big_h / s_h))


def brightness_and_colour(fit_rgb, table_rgb) -> tuple[float | None, float | None]:
    """(brightness in stops, CIEDE2000 at equal luminance) of the mean colour
    ``fit_rgb`` against ``table_rgb`` (linear RGB, any common scale). None where the
    table's colour is black and the fit's is not (no ratio to take); (0, 0) where
    both are black."""
    y_fit, y_table = luminance(fit_rgb), luminance(table_rgb)
    if not (math.isfinite(y_fit) and math.isfinite(y_table)):
        return None, None
    if y_table <= BLACK_Y:
        return (0.0, 0.0) if y_fit <= BLACK_Y else (None, None)
    if y_fit <= BLACK_Y:  # the fit renders black where the table does not
        return None, None
    stops = math.log2(y_fit / y_table)
    shown_fit = np.asarray(fit_rgb, np.float64) * (DISPLAY_Y / y_fit)
    shown_table = np.asarray(table_rgb, np.float64) * (DISPLAY_Y / y_table)
    return stops, ciede2000(rgb_to_lab(shown_fit), rgb_to_lab(shown_table))
