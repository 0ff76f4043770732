"""CIELAB and CIEDE2000 (brdffit.fitting.colour): the figures the verdict reads."""

from __future__ import annotations

import math

import pytest

from brdffit.fitting import colour

pytestmark = pytest.mark.unit

#: Pairs from Sharma, Wu and Dalal (2005), Table 1: (Lab 1, Lab 2, CIEDE2000), chosen
#: to cover the hue-angle wrap-arounds and the neutral axis the formula special-cases.
SHARMA = [
    ((50.0, 2.6772, -79.7751), (50.0, 0.0, -82.7485), 2.0425),
    ((50.0, 3.1571, -77.2803), (50.0, 0.0, -82.7485), 2.8615),
    ((50.0, 2.8361, -74.0200), (50.0, 0.0, -82.7485), 3.4412),
    ((50.0, 0.0, 0.0), (50.0, -1.0, 2.0), 2.3669),
    ((50.0, 2.49, -0.001), (50.0, -2.49, 0.0009), 7.1792),
    ((50.0, 2.5, 0.0), (50.0, 0.0, -2.5), 4.3065),
    ((50.0, 2.5, 0.0), (73.0, 25.0, -18.0), 27.1492),
    ((60.2574, -34.0099, 36.2677), (60.4626, -34.1751, 39.4387), 1.2644),
]


@pytest.mark.parametrize(("lab1", "lab2", "want"), SHARMA)
def test_ciede2000_matches_sharma_wu_dalal(lab1, lab2, want):
    assert colour.ciede2000(lab1, lab2) == pytest.approx(want, abs=1e-4)
    assert colour.ciede2000(lab2, lab1) == pytest.approx(want, abs=1e-4)  # symmetric


def test_white_is_l100_and_grey_is_neutral():
    assert colour.rgb_to_lab([1, 1, 1]) == pytest.approx([100, 0, 0], abs=1e-3)
    lightness, a, b = colour.rgb_to_lab([0.18, 0.18, 0.18])
    assert lightness == pytest.approx(49.5, abs=0.1) and abs(a) < 1e-3 and abs(b) < 1e-3


def test_brightness_is_in_stops_and_leaves_the_colour_alone():
    stops, de = colour.brightness_and_colour([0.4, 0.3, 0.2], [0.2, 0.15, 0.1])
    assert stops == pytest.approx(1.0) and de == pytest.approx(0.0, abs=1e-9)


def test_colour_shift_weighs_channels_as_the_eye_does():
    """+74% of a saturated yellow's tiny blue channel is hardly visible; +10% of one
    channel of a grey is."""
    yellow, bluer = [0.9, 0.55, 0.02], [0.9, 0.55, 0.0348]
    _, de_yellow = colour.brightness_and_colour(bluer, yellow)
    _, de_grey = colour.brightness_and_colour([0.55, 0.5, 0.5], [0.5, 0.5, 0.5])
    assert de_yellow < 1.5 < 3.0 < de_grey


def test_black_spheres():
    assert colour.brightness_and_colour([0, 0, 0], [0, 0, 0]) == (0.0, 0.0)
    assert colour.brightness_and_colour([0.1, 0.1, 0.1], [0, 0, 0]) == (None, None)
    assert colour.brightness_and_colour([0, 0, 0], [0.1, 0.1, 0.1]) == (None, None)
    assert colour.brightness_and_colour([math.nan, 0, 0], [0.1, 0.1, 0.1]) == (None, None)
