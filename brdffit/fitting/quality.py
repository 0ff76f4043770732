"""How a fit looks next to its measurement, and what to try next: the ``quality``
block of every result.

    quality = {"render_psnr_db": ..., "displayed_brightness_stops": ...,
               "brightness_stops": ..., "displayed_colour_shift": ...,
               "colour_shift": ..., "estimate_error": {...}, "grazing": {...},
               "verdict": ..., "reason": ..., "next": [...]}

- ``render_psnr_db``: the PSNR of the fit's tone-mapped sphere renders against the
  table's (``brdffit.fitting.sphere``: key and grazing light, one exposure per
  light; the result's ``error.psnr_db``), the fit read through the table's bins as
  the table is, so that a fit equal to the table bin for bin is 100 dB;
- ``displayed_brightness_stops``: the brightness the verdict judges, of the key-light
  sphere as displayed (``sphere.displayed_stops``: each picture's mean tone-mapped
  luminance read back through the tone curve; +1 = twice as bright);
- ``brightness_stops``: log2 of the fit's mean luminance (radiance) over the table's,
  on the key-light sphere (``sphere.sphere_colour``). A glossy material's mean radiance
  is its highlight's, which the picture shows blown out: on the real MERL materials'
  render-loss fits the two differed by up to 0.85 stops where the pictures looked
  alike (silver-metallic-paint -0.84 in radiance, +0.01 displayed; a broader highlight),
  and agreed within 0.03 where nothing saturates (``bench.verdict_levels``);
- ``displayed_colour_shift``: CIEDE2000 between the two key-light pictures' mean
  displayed colours at equal luminance (``sphere.displayed_colour_shift``: each
  pixel as the screen shows it, a blown-out highlight white, the body as the
  exposure brings it up);
- ``colour_shift``: CIEDE2000 between the two mean colours (radiance) at equal
  luminance, hue and saturation alone (``brdffit.fitting.colour``; ~1 is at the
  threshold of seeing it side by side, 10 is another colour); the verdict judges the
  worse of the two colour figures (:func:`judged_colour`);
- ``estimate_error``: the integral's own error in the radiance figures (their change
  from a coarser quadrature); ``grazing``: the same figures under the grazing light, the
  rim;
- ``verdict``: ``good``, ``visible`` or ``poor``; ``reason``: the figure that decided
  it, in words (the CLI prints both on one line);
- ``next``: for a verdict other than good, what to try, best first, each
  ``{"try": ..., "why": ..., "gain_db": ...}`` (:func:`next_steps`); ``gain_db`` is
  measured on this table where it was cheap to (``auto`` has every candidate's
  PSNR), else null. Empty for a good verdict, but for a solve that did not converge:
  it looks right, and its parameters are still those of a point short of the optimum.

Thresholds (:data:`GOOD`, :data:`POOR`), set by looking at the key-light spheres of
ggx fits to the design half of the real MERL materials at each level of each figure
(``python -m bench.verdict_levels``; docs/img/verdict_levels.png, docs/results.md):
at 28 dB, within 0.15 stops and CIEDE2000 3 the fit and the measurement are hard to
tell apart side by side (specular-white-phenolic -0.15 stops, blue-acrylic 1.0,
red-metallic-paint 2.1); below 20 dB, 0.6 stops (1.5x) off, or beyond CIEDE2000 6
(special-walnut-224's brown rendered grey, 6.3) the difference is plain at a glance;
between, it is visible when looking for it (red-fabric's orange turning pink, 3.5; a
broader highlight at 24 dB).
"""

from __future__ import annotations

import math

import numpy as np

#: (least PSNR in dB, largest |brightness| in stops, largest CIEDE2000) of each verdict.
GOOD = (28.0, 0.15, 3.0)
POOR = (20.0, 0.6, 6.0)
VERDICTS = ("good", "visible", "poor")


def _finite(x) -> bool:
    return x is not None and isinstance(x, int | float) and math.isfinite(x)


#: What the PSNR of each ``basis`` compares, in the verdict's reason.
FIGURES = {"sphere": "sphere render",
           "held_out": "held-out samples' render"}


def verdict(render_psnr_db: float | None, brightness_stops: float | None,
            colour_shift: float | None, basis: str = "sphere",
            colour_where: str = "") -> tuple[str, str]:
    """(verdict, reason) of a PSNR (dB), a brightness error (stops) and a CIEDE2000
    colour shift; None for a figure that could not be measured. ``basis``: what they
    were measured on (:data:`FIGURES`): a sphere rendered from the table, or a sample
    list's held-out predictions (``brdffit.fitting.samples``), with the same thresholds.
    ``colour_where``: which colour figure that is, in words (:func:`judged_colour`)."""
    figure = FIGURES[basis]
    if not _finite(render_psnr_db):
        # judged poor: a look nothing measures is not vouched for
        return "poor", (f"the fit's {figure} could not be compared (no finite PSNR)"
                        + (": the table measures none of the sphere's pixels (its bins lie "
                           "elsewhere), so nothing here judges how the fit looks"
                           if basis == "sphere" else ""))
    if not _finite(brightness_stops):
        return "poor", (f"the fit's {figure} is black where the measurement's is not, or "
                        "the other way round")
    stops = abs(brightness_stops)
    de = colour_shift if _finite(colour_shift) else 0.0
    where = f" {colour_where}" if colour_where else ""
    if render_psnr_db >= GOOD[0] and stops <= GOOD[1] and de <= GOOD[2]:
        return "good", (f"{figure} {render_psnr_db:.1f} dB, displayed "
                        f"brightness {_stops(brightness_stops)}, colour CIEDE2000 "
                        f"{de:.1f}{where} (good: >= {GOOD[0]:g} dB, within "
                        f"{GOOD[1]:g} stops and CIEDE2000 {GOOD[2]:g})")
    # every figure past its good threshold, the worst verdict's first: the reason named
    # the first alone, and red-fabric2's "27.2 dB (good from 28 dB)" left out the colour
    # (CIEDE2000 5.0, near poor) that its picture shows
    off = []
    if render_psnr_db < GOOD[0]:
        poor = render_psnr_db < POOR[0]
        line = POOR[0] if poor else GOOD[0]
        off.append((poor, f"{figure} {_near(render_psnr_db, line, 1)} dB from the measurement "
                          f"({'poor below' if poor else 'good from'} {line:g} dB)"))
    if stops > GOOD[1]:
        poor = stops > POOR[1]
        line = POOR[1] if poor else GOOD[1]
        off.append((poor, f"{_stops(brightness_stops, line)} in displayed brightness "
                          f"({'poor beyond' if poor else 'good within'} {line:g} stops)"))
    if de > GOOD[2]:
        poor = de > POOR[2]
        line = POOR[2] if poor else GOOD[2]
        off.append((poor, f"colour off by CIEDE2000 {_near(de, line, 1, below=False)}{where} "
                          f"({'poor beyond' if poor else 'good within'} {line:g})"))
    off.sort(key=lambda o: not o[0])  # stable: the poor ones first, each in this order
    verdict_word = "poor" if off[0][0] else "visible"
    return verdict_word, "; also ".join(words for _, words in off)


def _near(x: float, line: float, digits: int, below: bool = True) -> str:
    """``x`` to ``digits`` decimals, or more where that would put it on the other side
    of ``line``, the threshold it is judged by (``below``: a figure is off below it, as
    a PSNR; else above it): 19.96 dB read "20.0 dB (poor below 20 dB)"."""
    for d in range(digits, digits + 4):
        text = f"{x:.{d}f}"
        if (float(text) < line if below else float(text) > line) == (
                x < line if below else x > line):
            return text
    return text


def judged_brightness(figures: dict) -> float | None:
    """The brightness figure the verdict judges in a light's ``figures``: the displayed
    one, or, in a result stored before it was reported, the radiance one."""
    if "displayed_brightness_stops" in figures:
        return figures["displayed_brightness_stops"]
    return figures.get("brightness_stops")


def judged_colour(figures: dict) -> tuple[float | None, str]:
    """The colour figure the verdict judges in a light's ``figures``, and which it is in
    words: the worse of the displayed one (``displayed_colour_shift``: the picture at the
    verdict's exposure, where a glossy material's highlight is blown out and its body
    shows) and the radiance one (``colour_shift``: the sphere's mean light, which the
    highlight holds, and whose hue a dimmer exposure shows). Each misses what the other
    sees: black-obsidian's ggx2 fit was CIEDE2000 1.9 off in radiance (a grey highlight
    in both) and 15.6 as displayed (the measured body red, the fit's grey);
    color-changing-paint3's ggx fit 10.8 in radiance (the highlight's hue) and 0.5 as
    displayed. A result stored before the displayed figure was reported: the radiance
    one."""
    radiance = figures.get("colour_shift")
    if "displayed_colour_shift" not in figures:
        return radiance, ""
    both = [(v, words) for v, words in ((figures["displayed_colour_shift"], "as displayed"),
                                         (radiance, "in radiance")) if _finite(v)]
    return max(both, key=lambda b: b[0]) if both else (None, "")


def radiance_verdict(look: dict | None) -> str | None:
    """The verdict a quality block's figures give with the radiance brightness
    (``brightness_stops``) in place of the displayed one: what the lit sphere's
    highlight holds, which a picture at the table's exposure shows blown out but
    another light or exposure shows. ``auto``'s render rule ranks candidates by the
    worse of the two (``brdffit.selection``); None without a block."""
    if not look:
        return None
    return verdict(look.get("render_psnr_db"), look.get("brightness_stops"),
                   look.get("colour_shift"), look.get("basis", "sphere"))[0]


def _stops(s: float, line: float | None = None) -> str:
    """Stops, signed, to two decimals (more where they would round onto ``line``)."""
    size = f"{abs(s):.2f}" if line is None else _near(abs(s), line, 2, below=False)
    return f"{'-' if s < 0 else '+'}{size} stops"


def quality(render_psnr_db: float, colour: dict, *, model, params: dict, loss: str,
            converged: bool, physical: bool = False, gains: list | None = None,
            basis: str = "sphere", rel_peak_error: float | None = None) -> dict:
    """The quality block of a fit of ``model`` (the object) with ``params``:
    ``render_psnr_db`` and ``colour`` as ``SphereReference.psnr_and_colour`` gives
    them (``colour["grazing"]`` None where there is no grazing view: held-out
    samples); the rest describes the fit, for ``next``: its ``loss``, whether it
    ``converged``, whether it was bound to ``physical`` limits, and ``gains``
    measured elsewhere, and the full table's ``rel_peak_error`` (:func:`next_steps`).
    ``basis``: :func:`verdict`'s."""
    psnr = float(render_psnr_db) if _finite(render_psnr_db) else None
    key = colour["key"]
    word, reason = _judged(psnr, key, basis)
    graze = colour.get("grazing")
    reason += _grazing_words(word, psnr, graze, basis)
    highlight = colour.get("highlight")
    word, reason = _highlight_judged(word, reason, highlight, rel_peak_error)
    block = {"render_psnr_db": psnr,
             "displayed_brightness_stops": key.get("displayed_brightness_stops"),
             "brightness_stops": key["brightness_stops"],
             "displayed_colour_shift": key.get("displayed_colour_shift"),
             "colour_shift": key["colour_shift"],
             "estimate_error": key["estimate_error"],
             "grazing": None if graze is None else {
                 k: graze.get(k) for k in ("displayed_brightness_stops", "brightness_stops",
                                           "displayed_colour_shift", "colour_shift",
                                           "measured_colour_turn")},
             "basis": basis,
             "verdict": word, "reason": reason, "next": []}
    if highlight is not None:  # where the table resolves its highlight's shape
        block["highlight"] = highlight
    if word != "good":
        block["next"] = next_steps(block, model=model, params=params, loss=loss,
                                   converged=converged, physical=physical, gains=gains,
                                   rel_peak_error=rel_peak_error)
    elif not converged:  # it looks right, but its parameters are a point short of optimal
        block["next"] = [_CONVERGE]
    return block


#: A fit whose highlight is further off the table than this (stops, the median over the
#: bins where the table resolves its shape: :class:`brdffit.fitting.sphere._HighlightRow`)
#: is not ``good``, whatever its picture: 2 stops is 4x. The sphere's display saturates
#: in a bright highlight and cannot tell a glossy lobe from a spike beside a dark halo
#: (nickel's ggx2 under the render loss: a peak 932x the table's, the halo beside it
#: 4.5 stops off, 32.9 dB). Of the 100 MERL materials' ggx2 fits under the render loss,
#: 10 put a peak over twice the table's with the highlight 2.1-5.1 stops off.
HIGHLIGHT_OFF_STOPS = 2.0
#: How the reason begins to say it (the tests read it).
HIGHLIGHT_OFF = "the highlight's shape is off"


def spike_off_the_table(highlight: dict | None, rel_peak_error: float | None) -> bool:
    """Whether the fit puts a peak above the table's brightest bin (``rel_peak_error``
    over 1: more than twice its value) and its highlight is more than
    :data:`HIGHLIGHT_OFF_STOPS` off the table over the bins that resolve it
    (``highlight``, ``quality.highlight``): a spike the table does not hold, beside a
    halo too dark, which the sphere's saturated display cannot show. The verdict, its
    next steps and the fit's notes each read it here.

    A highlight too dim (single-lobe fits of plastics' sharp coats: the fit at 1-10% of
    the table's peak) is left to the picture: it is the fit's model's reach, and its
    ``next`` steps name richer models already."""
    return (highlight is not None and highlight["off_stops"] > HIGHLIGHT_OFF_STOPS
            and _finite(rel_peak_error) and rel_peak_error > 1.0)


def _highlight_judged(word: str, reason: str, highlight: dict | None,
                      rel_peak_error: float | None) -> tuple[str, str]:
    """The verdict no better than ``visible`` where :func:`spike_off_the_table`; the
    reason says where and by how much."""
    if not spike_off_the_table(highlight, rel_peak_error):
        return word, reason
    lo, hi = highlight["theta_h_deg"]
    least, most = highlight["stops_range"]
    said = (f"{HIGHLIGHT_OFF}: at the table's brightest bin the fit is "
            f"{1.0 + rel_peak_error:.3g}x the table's, and along the highlight (theta_d "
            f"{highlight['theta_d_deg']:.3g} deg), over the {highlight['bins']} bins where "
            f"the table resolves it (theta_h {lo:.2g}-{hi:.2g} deg), the fit is "
            f"{highlight['off_stops']:.1f} stops off the table (the median; from "
            f"{least:+.1f} to {most:+.1f}), "
            f"which the sphere's display, saturated there, does not show (visible beyond "
            f"{HIGHLIGHT_OFF_STOPS:g} stops)")
    if word == "good":
        return "visible", f"{said}; the picture alone: {reason}"
    return word, f"{reason}; also {said}"


def _judged(psnr: float | None, figures: dict, basis: str) -> tuple[str, str]:
    """:func:`verdict` of one light's ``figures``, by the brightness and colour it judges
    (:func:`judged_brightness`, :func:`judged_colour`)."""
    shift, where = judged_colour(figures)
    return verdict(psnr, judged_brightness(figures), shift, basis, where)


def _grazing_words(word: str, psnr: float | None, graze: dict | None, basis: str) -> str:
    """What the reason adds where the grazing light alone reads worse than the verdict
    (judged under the key light, with the PSNR of both): light-brown-fabric's ggx fit
    was good at +0.22 stops under the grazing light, color-changing-paint2's render fit
    visible at CIEDE2000 9.4 there, and nothing said so but the figures' line."""
    if not graze or not _finite(judged_brightness(graze)):
        return ""  # not measured there (a table cut at low theta_d): nothing to judge
    there, why = _judged(psnr, graze, basis)
    if VERDICTS.index(there) <= VERDICTS.index(word):
        return ""
    return f"; the grazing light alone reads {there}: {why}"


#: The verdicts, best first (``brdffit.selection`` ranks candidates by them too).
VERDICTS = ("good", "visible", "poor")


#: The step of a solve that did not converge: flags, as every step to run is (it read
#: "more starts and steps (--starts 8 --max-steps 400)", which a script had to parse).
_CONVERGE = {"try": "--starts 8 --max-steps 400",
             "why": "more starts and steps, as the solve stopped before its optimality "
                    "test held: the figures are those of a point short of the optimum",
             "gain_db": None}


#: A lobe this narrow (GGX or Beckmann alpha, in radians of slope) is resolved by
#: fewer than ~5 of the table's theta_h bins (bin 5 ends at 0.0058 rad): its shape is
#: beyond what the table measured.
NARROW_ALPHA = 0.01
#: The base specular lobe's roughness in the renderers' models, whose GGX alpha is its
#: square: glTF's and Disney's (Mitsuba's principled) ``roughness``, MaterialX's
#: ``specular_roughness`` (``standard_surface.specular_alpha``).
_ROUGHNESS = ("roughness", "specular_roughness")


def specular_lobes(params: dict, phong: bool = False) -> list[tuple[float, float]]:
    """Each specular lobe of a fit as (GGX or Beckmann alpha, its scale: ks, the mean
    over channels, or 1 where a model has none), by the catalogue's parameter names:
    ``alpha`` with ``ks`` (ggx, beckmann, rough_conductor, rough_plastic,
    generalized_schlick), ``alpha1``..``alpha4`` with ``ks1``..``ks4`` (ggx2-4), the
    renderers' ``roughness`` as alpha = roughness^2 (one lobe, their base layer's; a
    coat's or a sheen's roughness is a layer's, not the highlight's), and an exponent
    ``n`` as the Beckmann alpha of a lobe as wide near its peak: Blinn-Phong's
    cos_h^n ~ exp(-n theta_h^2 / 2), alpha = sqrt(2 / (n + 2)); Phong's (``phong``)
    lobe about the mirror direction, whose angle to wo is ~2 theta_h, as Blinn-Phong's
    of exponent 4n."""
    lobes = [(float(params[a]), float(np.mean(params[k])) if k in params else 1.0)
             for a, k in (("alpha", "ks"), ("alpha1", "ks1"), ("alpha2", "ks2"),
                          ("alpha3", "ks3"), ("alpha4", "ks4")) if a in params]
    for name in _ROUGHNESS:
        if name in params:
            lobes.append((float(params[name]) ** 2, 1.0))
    if "n" in params:
        n = float(params["n"]) * (4.0 if phong else 1.0)
        lobes.append((float(np.sqrt(2.0 / (n + 2.0))),
                      float(np.mean(params["ks"])) if "ks" in params else 1.0))
    return lobes


#: A colour that turns by more than this (CIEDE2000) between the key and the grazing
#: view, and that the fit misses there, is a colour that changes with the angle.
TURNING_COLOUR = 6.0
#: A table whose own colour turns by more than this (CIEDE2000, key light to grazing:
#: ``measured_colour_turn``) changes colour with the angle: MERL's colour-changing
#: paints turn by 5.6, 10.4 and 16.6, every other MERL material by 4.5 at most
#: (dark-blue-paint: a white Fresnel rim over a saturated base).
TABLE_TURN = 5.0
#: The model whose colour turns with the angle (brdffit.models.generalized_schlick): what
#: ``next`` advises where the colour turns and the fit misses it.
TURNING_MODEL = "generalized_schlick"


def _colour_turning(look: dict) -> str | None:
    """The evidence, in words, that the material's colour turns with the angle and the
    fit misses it there (else None): the fit's colour far off under the grazing light
    where it is not under the key light; or the table's own colour turning from the
    key light to the grazing one by more than :data:`TABLE_TURN` while the fit's is
    off beyond the good verdict's colour under either. (By the first alone,
    color-changing-paint3's ggx fit, 10.8 off under the key light and 2.3 at grazing,
    was told only to add a coat: it matched the grazing colour, and missed the key.)
    The figures are the sphere's mean colours (in radiance), said so: the verdict's own
    may be the displayed one, another number.)"""
    graze = look.get("grazing") or {}
    key_shift, graze_shift = look.get("colour_shift"), graze.get("colour_shift")
    if (_finite(graze_shift) and graze_shift > TURNING_COLOUR
            and (not _finite(key_shift) or graze_shift > 2 * key_shift)):
        return (f"the colour turns with the angle: at grazing light the fit is CIEDE2000 "
                f"{graze_shift:.0f} off in radiance against "
                f"{key_shift or 0:.1f} under the key light")
    turn = graze.get("measured_colour_turn")
    worst = max((x for x in (key_shift, graze_shift) if _finite(x)), default=None)
    if _finite(turn) and turn > TABLE_TURN and worst is not None and worst > GOOD[2]:
        return (f"the colour turns with the angle: the table's own by CIEDE2000 {turn:.0f} "
                f"from the key light to the grazing one, and the fit's is "
                f"{_maybe(key_shift, '.1f')} off in radiance under the key light, "
                f"{_maybe(graze_shift, '.1f')} at grazing")
    return None


def next_steps(look: dict, *, model, params: dict, loss: str, converged: bool,
               physical: bool = False, gains: list | None = None,
               rel_peak_error: float | None = None) -> list[dict]:
    """What to try after a fit that does not look good, best first.

    ``gains``: ``[(try, why, gain_db), ...]`` measured on this table (``auto`` adds
    the candidates that rendered closer than its choice: :func:`with_measured_gains`);
    they come first, largest gain first. Then what the figures point to, each with
    the reason read off them: a solve that did not converge; a colour that turns
    with the angle (nothing here fits it: said so, and why); a fit far off the
    table's brightest bin (``rel_peak_error``: the render loss, first); a richer
    model of this one's kind; the render loss; a lobe narrower than the bins (nothing
    here fits its shape); the physical bounds. A verdict that is not good always
    gets one step at least (:func:`_last_steps`). ``gain_db`` is null where it was
    not measured.
    """
    steps: list[dict] = []
    tried: set[str] = set()

    def add(t: str, why: str) -> None:
        if t not in tried:
            tried.add(t)
            steps.append({"try": t, "why": why, "gain_db": None})

    if not converged:
        add(_CONVERGE["try"], _CONVERGE["why"])
    if ("render_psnr_db" in look and look["render_psnr_db"] is None
            and look.get("basis", "sphere") == "sphere"):
        # nothing compared: another model or loss would be judged on nothing again (a
        # table measured at grazing alone, fitted exactly, was advised ggx2 and the
        # render loss)
        add(MEASURE_THE_SPHERE,
            "the table measures none of the verdict's sphere pixels, so no fit of it can be "
            "judged by how it looks; its log_rmse is still its error on the bins it has")
        return steps
    turning = _colour_turning(look)
    if turning and model.name != TURNING_MODEL:
        # a Fresnel whose colour turns across the angles a picture sees: on MERL's three
        # colour-changing paints under the render loss each verdict rose one level
        # (poor -> visible twice, visible -> good), docs/models.md
        add(f"--model {TURNING_MODEL} --loss render", (
            f"{turning}: MaterialX's generalized Schlick lobe turns its colour from color0 "
            "to color90 across the angles a picture sees (a Schlick Fresnel holds one colour "
            "until grazing); on MERL's colour-changing paints each verdict rose one level "
            "under the render loss (docs/models.md); gain not measured on this table"))
    elif turning:
        add("nothing here: a colour that turns across the highlight",
            f"{turning}. This lobe turns its colour with the angle between light and view, "
            "but flakes that reflect another colour as they tilt change it across the "
            "highlight itself, which no model here follows; a thin film (--model "
            "gltf_iridescence) gained under 1% of log_rmse on MERL's colour-changing paints "
            "(docs/models.md)")
    peak_far = _finite(rel_peak_error) and rel_peak_error >= PEAK_FAR
    if loss != "render" and model.name not in NO_LOBE:
        # a lobe's look first: on 11 real materials that did not look good under the log
        # loss, the render loss was the best single step on 10 (ggx2 gained 0.0 dB on
        # blue-metallic-paint, whose second lobe collapsed, the render loss 6.1)
        add("--loss render", (
            f"the fit is {rel_peak_error:.0%} off the table's brightest bin (rel_peak_error "
            f"{rel_peak_error:.2f}): the highlight's few peak bins weigh little in the "
            f"{loss} loss, which a broader, dimmer lobe satisfies; the render loss weighs the "
            "light a picture shows (docs/fitting.md); gain not measured on this table")
            if peak_far else RENDER_WHY)
    from brdffit.models.catalogue import MONO_SUFFIX

    name = model.name.removesuffix(MONO_SUFFIX)
    richer = {"lambert": "ggx", "oren_nayar": "ggx", "blinn_phong": "ggx", "phong": "ggx",
              "beckmann": "ggx2", "ggx": "ggx2"}
    why_richer = {
        "ggx": "a specular lobe with microfacet shadowing and a Fresnel rise",
        "ggx2": "a second lobe: a sharp coat over a broad haze, as many paints and "
                "metals have",
    }
    if name in richer:
        add(f"--model {richer[name]}", why_richer[richer[name]])
    elif name in MORE_LOBES and loss != "render":
        add(f"--model {MORE_LOBES[name]}", MORE_LOBES_WHY[name])
    elif "clearcoat" in model.layers:
        add("--model ggx2", COAT_AS_TWO_LOBES)
    elif model.layers:
        # a layer more of the same renderer (principled's sheen, not good, was told
        # nothing here is richer, beside principled_clearcoat)
        for child, added in _layer_more(model):
            add(f"--model {child}", f"{child} adds {' and '.join(added)} to {model.name}'s "
                f"{' and '.join(model.layers)}, in the same renderer; gain not measured on "
                "this table")
    if loss != "render":
        add("--loss render", RENDER_WHY)
    lobes = specular_lobes(params, phong=name == "phong")
    on_samples = look.get("basis") == "held_out"
    # The table is blamed where its bins cannot hold the highlight's shape: the fit's
    # narrowest lobe is its highlight (the larger lobe: chrome-steel's ggx2, alpha1 at
    # 0.001 and ks1 0.28 over ks2 0.07, is 26x the table's brightest bin, which averages
    # it), and the fit is far off that bin, under the render loss. Not where the narrow
    # lobe is a small one beside the highlight (blue-metallic-paint's ggx2: alpha2 at its
    # bound, ks2 0.06 beside ks1 0.41), nor where the render loss meets the peak
    # (color-changing-paint3's ggx2: alpha1 0.0013, its log-loss ggx 0.040), nor under
    # another loss: the render loss comes first (chrome's ggx, alpha 0.007 under the log
    # loss, reads good as ggx2 under the render loss, its lobe as narrow). A sample list
    # has no bins: fitted where it was measured, it resolves a lobe of any width its
    # samples reach (a GGX alpha 0.005 list fits 0.00499, good).
    narrowest = min(lobes, default=None)
    # ... but not where the table resolves its highlight over several bins and the fit's
    # spike misses them (:func:`_highlight_judged`): the table holds that shape
    resolved = spike_off_the_table(look.get("highlight"), rel_peak_error)
    if resolved and model.parent is not None:
        add(f"--model {model.parent}",
            f"{model.name}'s lobe became a spike the table does not hold, above its "
            f"brightest bin; {model.parent}, its parent, has no such lobe to give it (gain "
            "not measured on this table)")
    if (narrowest is not None and narrowest[0] < NARROW_ALPHA and loss == "render"
            and peak_far and narrowest[1] >= max(scale for _, scale in lobes)
            and not on_samples and not resolved):
        add("nothing here: the highlight is narrower than the table's bins",
            f"alpha {narrowest[0]:.3g} is resolved by fewer than ~5 theta_h bins: a measured "
            "bin there averages a lobe that changes across it, which no model read at the "
            "bins' centres matches bin for bin; the table holds the peak's energy, not its "
            "shape (a measurement with finer steps at the peak would)")
    if physical:
        add("without --physical", "the physical bounds are active: the unconstrained fit is "
            "their cost's measure (the result's physical block)")
    if not model.layers:
        # auto ranks by the look under the render loss only (by log_rmse under another):
        # from a log-loss fit the glTF candidates, ranked so, rendered worse than its ggx
        # on 5 of 11 real materials (blue-metallic-paint 20.0 -> 14.6 dB)
        layers = _layers_step(model)
        add(layers["try"] if loss == "render" else f"{layers['try']} --loss render",
            layers["why"])
    if not steps:
        steps = _last_steps(model)
    return with_measured_gains({"verdict": look["verdict"], "basis": look.get("basis"),
                                "next": steps}, gains or [], loss=loss)["next"]


#: A sample list's words for what :func:`next_steps` says of a table.
_SAMPLE_WORDS = (("the table's brightest bin", "the brightest sample"),
                 ("the highlight's few peak bins", "the highlight's few peak samples"),
                 ("on this table", "on these samples"), ("to this table", "to these samples"))


def _worded_for(basis: str | None, steps: list[dict]) -> list[dict]:
    """``steps`` as said of a sample list where ``basis`` is its held-out render (they
    spoke of "the table's brightest bin" and "gain not measured on this table")."""
    if basis != "held_out":
        return steps
    out = []
    for step in steps:
        why = step["why"]
        for table_words, sample_words in _SAMPLE_WORDS:
            why = why.replace(table_words, sample_words)
        out.append({**step, "why": why})
    return out


#: The models without a specular lobe: a peak is theirs to miss.
NO_LOBE = ("lambert", "oren_nayar")


def _layered(name: str) -> bool:
    """Whether the model ``name`` has layers (False for a name that is not a model's)."""
    from brdffit import models

    try:
        return bool(models.get(name.strip()).layers)
    except (KeyError, ValueError):
        return False


#: Why the render loss, where no figure of the fit says more.
RENDER_WHY = ("it fits what a picture of the material shows (docs/fitting.md); gain not "
              "measured on this table")
#: Why two lobes, to a fit with a clear coat that is not good.
COAT_AS_TWO_LOBES = ("two free lobes, a sharp one over a broad one, each of its own colour: "
                     "not a renderer's coat (a fixed white layer of one index), but closer "
                     "where the coat is not one (chrome under the render loss: ggx2 30.2 dB, "
                     "good, gltf_clearcoat 24.4); exported to a renderer's material by a refit")

#: A lobe more, to a multi-lobe GGX fit under a loss other than the render loss, and
#: why (measured under the log loss only; docs/models.md).
MORE_LOBES = {"ggx2": "ggx3", "ggx3": "ggx4"}
MORE_LOBES_WHY = {
    "ggx2": "a third lobe: under the log loss ggx2 spends its broad lobe on the haze and the "
            "grazing bins and leaves the highlight dim; ggx3 keeps a sharp peak, a shoulder "
            "and the haze (MERL's aluminium 17.9 -> 22.6 dB, red-metallic-paint 19.0 -> "
            "25.5); gain not measured on this table",
    "ggx3": "a fourth lobe, for a highlight three lobes still miss under the log loss "
            "(MERL's hematite 19.0 -> 22.7 dB, brass 20.0 -> 20.3); gain not measured on "
            "this table",
}

#: A fit this far off the table's brightest bin (``rel_peak_error``) has lost most of
#: its highlight's peak: chrome's ggx fit is 0.79 off, chrome-steel's 0.89.
PEAK_FAR = 0.5

#: How every layers step begins (:data:`_LAYERS`, :func:`_layers_step`).
_AUTO_OVER = "--model auto --candidates "

#: The last step of a fit without layers that is not good, and of ``auto``'s choice
#: where no candidate rendered closer: the renderers' materials with layers, which
#: auto's default candidates leave out (on blue-fabric, ggx 29.5 dB and ggx2 30.0, where
#: gltf_sheen renders at 33.3 with its sheen identified).
_LAYERS = {"try": f"{_AUTO_OVER}gltf",
           "why": "the glTF materials with their layers (a clear coat over a base: coated "
                  "paints; a sheen: fabrics, velvets), each fitted and ranked by how it "
                  "renders; gain not measured on this table (a thin film is fitted where "
                  "named: --candidates gltf,gltf_iridescence)", "gain_db": None}


#: What the layers of a renderer's own base material add, by its candidate set
#: (``brdffit.models.catalogue.CANDIDATE_SETS``): a fit of MaterialX's standard_surface
#: or of Mitsuba's rough_conductor was told glTF's layers, a file its renderer does not
#: read.
_RENDERER_LAYERS = {
    "materialx": ("MaterialX's materials with their layers (standard_surface with a coat: "
                  "coated paints; with a sheen: fabrics, velvets; generalized_schlick: a "
                  "highlight whose colour turns with the angle), each fitted and ranked by "
                  "how it renders; gain not measured on this table"),
    "mitsuba": ("Mitsuba's materials (principled with a clear coat: coated paints; "
                "rough_conductor, rough_plastic), each fitted and ranked by how it renders; "
                "gain not measured on this table"),
}


def _layers_step(model) -> dict:
    """The step to the renderers' layered materials for a fit without layers: its own
    renderer's set where the model is a renderer's material (not one of auto's own
    analytic candidates, which every set may hold: lambert is Mitsuba's diffuse), else
    glTF's (:data:`_LAYERS`)."""
    from brdffit.models.catalogue import CANDIDATE_SETS, MONO_SUFFIX

    name = model.name.removesuffix(MONO_SUFFIX)
    if not model.auto_candidate:
        for family, why in _RENDERER_LAYERS.items():
            if name in CANDIDATE_SETS.get(family, ()):
                return {"try": f"{_AUTO_OVER}{family}", "why": why,
                        "gain_db": None}
    return dict(_LAYERS)


def _layer_more(model) -> list[tuple[str, tuple[str, ...]]]:
    """The registry's models that start from ``model`` (their ``parent``) and add a
    layer to the ones it has, each with the layers it adds."""
    from brdffit import models

    out = []
    for name in models.REGISTRY:
        child = models.get(name)
        added = tuple(x for x in child.layers if x not in model.layers)
        if child.parent == model.name and added:
            out.append((name, added))
    return out


def without_lobes_on_noise(look: dict | None, model, uncertainty: dict | None) -> dict | None:
    """``look`` without the steps that add a lobe, where the fit's own lobe is absent
    (its shape ``no lobe``: the lobe's scale within 2 standard errors of 0): a lobe
    more cannot gain where the data show none, and the difference the verdict sees is
    another (a noisy diffuse table's ggx fit, ks at 0, read visible at 24.5 dB and was
    told ggx2; its ggx2 and ggx3 fits ended at the same log_rmse, every lobe absent,
    and were told ggx3 and ggx4). Left as it is where a step remains; else one that
    says so."""
    if not look or not look.get("next") or not uncertainty or model.name in NO_LOBE:
        return look
    why = uncertainty.get("why") or {}
    absent = [name for name, reason in why.items() if reason.startswith("no lobe")]
    if not absent:
        return look
    # the steps next_steps adds a lobe by: ggx2 (the richer model of ggx and beckmann)
    # and each MORE_LOBES model
    more = {f"--model {m}" for m in ("ggx2", *MORE_LOBES.values())}
    kept = [step for step in look["next"] if step["try"] not in more]
    if len(kept) == len(look["next"]):
        return look
    if not kept:
        kept = [{"try": "nothing here: the fit's lobe is absent, so no lobe more would gain",
                 "why": f"{', '.join(absent)}: no lobe (its scale within "
                        "2 standard errors of 0); what the verdict sees is not a missing "
                        "lobe: the table's noise, or a shape beyond the analytic models "
                        "here", "gain_db": None}]
    return {**look, "next": kept}


def _last_steps(model) -> list[dict]:
    """What a layered fit that is not good is told where nothing read off its figures
    applies: that nothing here is richer (a verdict that is not good never comes with
    an empty ``next``)."""
    return [{"try": "nothing here: no model here is richer of this kind",
             "why": f"{model.name} is the richest model of its kind here, and its verdict's "
                    "reason says what is off: a material beyond the analytic models here "
                    "(a peak sharper than the table's bins, flakes, a colour that turns with "
                    "the angle)", "gain_db": None}]


#: A table's verdict is good only where this share of its sphere's lit pixels (both
#: lights) are measured: every MERL table's are to 99.2%. A GGX table cut to its bins at
#: theta_h > 40 deg (55% of the pixels measured) had lambert "good" at 34.4 dB, which
#: judged against the whole table is 19.9 dB: the highlight was not compared.
SPHERE_MEASURED = 0.9
#: ... and below this share, none: a few dozen pixels' colour and brightness are the
#: noise of the bins under them, which no verdict can rest on.
SPHERE_COMPARED_MIN = 0.01
#: The step where the table measures none, or too little, of the verdict's sphere.
MEASURE_THE_SPHERE = "a measurement of the directions a picture shows"


def on_part_of_the_sphere(look: dict | None, share: float) -> dict | None:
    """A table fit's quality block with ``sphere_measured``, the share of the verdict's
    sphere pixels whose bin is measured (``SphereReference.measured_share``); below
    :data:`SPHERE_MEASURED` the figures compare only those, which the reason says, and
    a good verdict reads visible: what the fit shows elsewhere was not compared."""
    if look is None:
        return None
    look = {**look, "sphere_measured": round(float(share), 4)}
    if share >= SPHERE_MEASURED or look.get("render_psnr_db") is None:
        return look  # (nothing compared: the reason says so already)
    if share < SPHERE_COMPARED_MIN:
        # a few dozen pixels judged nothing: a GGX table with 99.9% of its bins missing,
        # fitted to its truth, read poor on a colour "6.5" of 0.09% of the sphere, was
        # told its colour turns, and auto passed it over for a ggx2 of absent lobes
        return {**look, "verdict": "poor",
                "reason": f"the fit's look could not be compared: only {share:.2%} of the "
                          "sphere's lit pixels have a measured bin, too few to judge it "
                          f"(it is judged from {SPHERE_COMPARED_MIN:.0%}); its log_rmse is "
                          "its error on the bins the table has",
                "next": [{"try": MEASURE_THE_SPHERE,
                          "why": "the table measures too little of the verdict's sphere for "
                                 "any fit of it to be judged by how it looks",
                          "gain_db": None}]}
    said = (f"only {share:.0%} of the sphere's lit pixels have a measured bin (the rest "
            "are not compared)")
    if look["verdict"] != "good":
        return {**look, "reason": f"{look['reason']}; {said}"}
    step = {"try": "a measurement of the directions the table lacks",
            "why": f"the figures compare {share:.0%} of the sphere, where the table is "
                   "measured: the fit may look otherwise where it is not",
            "gain_db": None}
    return {**look, "verdict": "visible",
            "reason": f"{said}, good needs {SPHERE_MEASURED:.0%}; there: {look['reason']}",
            "next": [step]}


def of_the_whole_sphere(look: dict | None) -> bool:
    """Whether a quality block judged a sphere, every direction (a table's, or a sample
    list's binned table where its samples cover the sphere), not held-out samples (which
    a scene weights as it weights the fit): on a scene fit, a verdict beyond the scene."""
    return bool(look) and look.get("basis", "sphere") == "sphere"


#: A measured gain smaller than this is no step: fits that close render alike to a
#: viewer side by side, as auto's rule under the render loss takes them to
#: (``selection.RENDER_TOLERANCE_DB`` is this figure). red-fabric's lambert was advised
#: oren_nayar for "+0.0 dB".
ALIKE_DB = 0.5


def _worth_a_step(gains: list) -> list[tuple[str, str, float]]:
    """The measured ``gains`` that are steps, largest gain first. A gain is
    ``(try, why, gain_db)``, or ``(try, why, gain_db, n_params, reads_better)``
    with its model's size and whether its fit reads a better verdict than the one
    advised. A step gains at least :data:`ALIKE_DB`, or reads better (a colour or
    brightness the chosen fit misses, at a PSNR within ALIKE_DB of it); and no step of
    no more parameters, reading as well, matches it within ALIKE_DB (or exceeds it at
    the same size), as auto leaves such a candidate out. red-fabric's lambert was
    advised ggx +4.0, ggx2 +4.0, beckmann +3.5, blinn_phong +3.1 and phong +3.0 dB:
    ggx and blinn_phong say all of it."""
    steps = []
    for t, w, g, *rest in gains:
        k, better = (list(rest) + [None, False])[:2]
        if g >= ALIKE_DB or (better and g > -ALIKE_DB):
            steps.append((t, w, float(g), k, bool(better)))
    kept: list[tuple] = []
    # cheapest first, the larger gain first at one size: a step's possible betters
    # (no more parameters) are judged before it, and it is judged against those kept
    for step in sorted(steps, key=lambda s: (s[3] is None, s[3] or 0, -s[2])):
        _, _, g, k, better = step
        outdone = k is not None and any(
            other[3] is not None and other[3] <= k and other[4] >= better
            and other[2] >= g - ALIKE_DB and (other[3] < k or other[2] >= g)
            for other in kept)
        if not outdone:
            kept.append(step)
    return [s[:3] for s in sorted(kept, key=lambda s: -s[2])]


def with_measured_gains(look: dict | None, gains: list, loss: str | None = None) -> dict | None:
    """``look`` (a quality block) with ``gains`` (``[(try, why, gain_db), ...]``, or
    with each model's size and whether it reads better: :func:`_worth_a_step`;
    measured on the same table) first in its
    ``next``, largest first: those :func:`_worth_a_step` keeps. A step that was
    measured replaces the guess of the same ``try``, and one measured without a gain
    worth a step is dropped: ``auto`` does not advise a candidate it saw render no
    closer, or no closer than a cheaper one. A good verdict keeps an empty ``next``.
    ``loss``: the fit's own, which each step of another model then names
    (:func:`_with_the_loss`)."""
    if look is None or look.get("verdict") == "good":
        return look
    own = _own_loss(loss)
    if not gains:
        return {**look, "next": _with_the_loss(
            _worded_for(look.get("basis"), look.get("next", [])), own)}
    measured = [{"try": t, "why": w, "gain_db": round(g, 2)} for t, w, g in _worth_a_step(gains)]

    def bare(t: str) -> str:  # a guess as auto measures it: without the loss it names
        return t.removesuffix(own) if own else t

    names = {t for t, *_ in gains}
    layered = any(_layered(t.removeprefix("--model ")) for t in names)
    # a ranking with layered candidates measured them: theirs is no guess to repeat
    rest = [s for s in look.get("next", []) if bare(s["try"]) not in names
            and not (layered and s["try"].startswith(_AUTO_OVER))]
    if not measured and all(bare(s["try"]).startswith(_AUTO_OVER) for s in rest):
        # every guess was measured, and none rendered closer. The layers step a fit was
        # given stays as given (its own renderer's set, with the render loss: a
        # standard_surface fit was told glTF's set here, a file MaterialX does not read)
        layers = rest or [dict(_LAYERS)]
        rest = [{"try": "nothing here: no candidate rendered closer",
                 "why": "auto fitted each of its candidates to this table and none renders "
                        f"closer than this fit by {ALIKE_DB:g} dB or more; the verdict's "
                        "reason says what is off",
                 "gain_db": None}, *([] if layered else layers)]
    return {**look, "next": _with_the_loss(_worded_for(look.get("basis"), measured + rest),
                                           own)}


def _own_loss(loss: str | None) -> str:
    """`` --loss NAME`` of a fit's own loss where it is not the default, else ""."""
    from brdffit.fitting.options import DEFAULT_LOSS  # here: the API's front imports this

    return f" --loss {loss}" if loss and loss != DEFAULT_LOSS else ""


def _with_the_loss(steps: list[dict], own: str) -> list[dict]:
    """Each step to another model (``--model ggx2``) with the fit's own loss (``own``,
    :func:`_own_loss`) where it names none: a step is what to add to the fit's
    command, but one taken as a whole command left a render-loss fit's loss behind
    (chrome's ggx2: 24.4 dB under the render loss, 18.4 under the default log loss)."""
    if not own:
        return steps
    return [{**s, "try": s["try"] + own}
            if s["try"].startswith("--model ") and "--loss" not in s["try"] else s
            for s in steps]


def describe(look: dict | None, indent: str = "  ") -> list[str]:
    """The quality block as lines of text (the CLI, the export's and the batch's
    reports): the verdict with its reason, the figures, then ``next``, numbered."""
    if not look:
        return []
    lines = [f"{indent}looks {look['verdict']}: {look['reason']}"]
    if "brightness_stops" in look:  # not in results stored before brdffit.fit/2
        figures = [_brightness_words(look), f"{_colour_words(look)} (key light)"]
        graze = look.get("grazing") or {}
        if graze:
            figures.append(f"grazing light {_brightness_words(graze)}, "
                           f"{_colour_words(graze)}")
        lines.append(f"{indent}  " + "; ".join(figures))
    for i, step in enumerate(look.get("next") or [], 1):
        gain = "" if step.get("gain_db") is None else f" ({step['gain_db']:+.1f} dB)"
        lines.append(f"{indent}  next {i}: {step['try']}{gain}: {step['why']}")
    return lines


def figure_words(figures: dict) -> str:
    """A light's brightness and colour figures in words, as the fit's own lines say them
    ("brightness +1.58 stops as displayed (radiance -0.12), colour CIEDE2000 ..."): an
    export's fidelity printed its radiance brightness alone beside a fit that said the
    displayed one, the figure its verdict judged."""
    return f"{_brightness_words(figures)}, {_colour_words(figures)}"


def _brightness_words(figures: dict) -> str:
    """"brightness +0.02 stops as displayed (radiance +0.78)", or the radiance figure
    alone in a result stored before the displayed one was reported."""
    radiance = f"{_maybe(figures.get('brightness_stops'), '+.2f')}"
    if "displayed_brightness_stops" not in figures:
        return f"brightness {radiance} stops"
    return (f"brightness {_maybe(figures['displayed_brightness_stops'], '+.2f')} stops "
            f"as displayed (radiance {radiance})")


def _colour_words(figures: dict) -> str:
    """"colour CIEDE2000 15.6 as displayed (radiance 1.9)", or the radiance figure alone
    in a result stored before the displayed one was reported."""
    radiance = _maybe(figures.get("colour_shift"), ".1f")
    if "displayed_colour_shift" not in figures:
        return f"colour CIEDE2000 {radiance}"
    return (f"colour CIEDE2000 {_maybe(figures['displayed_colour_shift'], '.1f')} as "
            f"displayed (radiance {radiance})")


def _maybe(x, fmt: str) -> str:
    return "n/a" if not _finite(x) else format(x, fmt)
