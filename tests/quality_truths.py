"""Noise-free truths of every registry model for the verdict's calibration test
(tests/test_quality.py): five parameter sets per model: its example, a saturated
colour, a dark material, a near-mirror lobe (alpha 0.002-0.01, or the model's
narrowest) and a grazing-heavy lobe (broad, with a strong Fresnel rise). A fit of
each by its own model must look ``good``."""

from __future__ import annotations

SATURATED = [0.9, 0.55, 0.03]  # a yellow whose blue is a few per cent of the rest
DARK = [0.012, 0.01, 0.008]

#: A dielectric-Fresnel lobe's (beckmann_dielectric, ggx_dielectric) five sets.
DIELECTRIC_LOBE = [
    ("example", {"kd": [0.2, 0.1, 0.05], "ks": [8.0] * 3, "alpha": 0.15, "eta": 1.5}),
    ("saturated", {"kd": SATURATED, "ks": [6.0] * 3, "alpha": 0.2, "eta": 1.5}),
    ("dark", {"kd": DARK, "ks": [2.0] * 3, "alpha": 0.1, "eta": 1.4}),
    ("near-mirror", {"kd": [0.02] * 3, "ks": [10.0] * 3, "alpha": 0.005, "eta": 1.6}),
    ("grazing-heavy", {"kd": [0.2] * 3, "ks": [10.0] * 3, "alpha": 0.5, "eta": 1.2}),
]
#: The glTF factors' five sets (gltf_pbr, gltf_threejs; gltf_pbr_ior adds an ior).
GLTF = [
    ("example", {"base_color": [0.8, 0.5, 0.3], "metallic": 0.3, "roughness": 0.4}),
    ("saturated", {"base_color": SATURATED, "metallic": 0.0, "roughness": 0.5}),
    ("dark", {"base_color": [0.03, 0.025, 0.02], "metallic": 0.0, "roughness": 0.3}),
    ("near-mirror", {"base_color": [0.95, 0.93, 0.9], "metallic": 1.0, "roughness": 0.06}),
    ("grazing-heavy", {"base_color": [0.3, 0.3, 0.3], "metallic": 0.0, "roughness": 0.9}),
]

#: standard_surface's five sets (standard_surface_dielectric takes its dielectric ones).
STANDARD_SURFACE = [
    ("example", {"base_color": [0.8, 0.5, 0.3], "metalness": 0.3,
                 "specular_color": [1.0, 1.0, 1.0], "specular_roughness": 0.4,
                 "specular_IOR": 1.5}),
    ("saturated", {"base_color": SATURATED, "metalness": 0.0,
                   "specular_color": [1.0, 1.0, 1.0], "specular_roughness": 0.5,
                   "specular_IOR": 1.5}),
    ("dark", {"base_color": [0.03, 0.025, 0.02], "metalness": 0.0,
              "specular_color": [0.5, 0.5, 0.5], "specular_roughness": 0.3,
              "specular_IOR": 1.45}),
    ("near-mirror", {"base_color": [0.95, 0.93, 0.9], "metalness": 1.0,
                     "specular_color": [1.0, 1.0, 1.0], "specular_roughness": 0.06,
                     "specular_IOR": 1.5}),
    ("grazing-heavy", {"base_color": [0.3, 0.3, 0.3], "metalness": 0.0,
                       "specular_color": [1.0, 1.0, 1.0], "specular_roughness": 0.9,
                       "specular_IOR": 1.2}),
]

#: model -> [(label, params), ...]
QUALITY_TRUTHS: dict[str, list[tuple[str, dict]]] = {
    "lambert": [
        ("example", {"kd": [0.5, 0.35, 0.2]}),
        ("saturated", {"kd": SATURATED}),
        ("dark", {"kd": DARK}),
        ("white", {"kd": [0.95, 0.95, 0.95]}),
        ("blue", {"kd": [0.02, 0.05, 0.6]}),
    ],
    "oren_nayar": [
        ("example", {"kd": [0.5, 0.35, 0.2], "sigma": 0.5}),
        ("saturated", {"kd": SATURATED, "sigma": 0.3}),
        ("dark", {"kd": DARK, "sigma": 0.4}),
        ("smooth", {"kd": [0.4, 0.4, 0.4], "sigma": 0.05}),
        ("grazing-heavy", {"kd": [0.6, 0.3, 0.3], "sigma": 1.4}),
    ],
    "blinn_phong": [
        ("example", {"kd": [0.2, 0.15, 0.1], "ks": [0.4, 0.3, 0.2], "n": 120.0}),
        ("saturated", {"kd": SATURATED, "ks": [0.3, 0.3, 0.3], "n": 60.0}),
        ("dark", {"kd": DARK, "ks": [0.05, 0.05, 0.05], "n": 200.0}),
        ("near-mirror", {"kd": [0.02, 0.02, 0.02], "ks": [1.0, 1.0, 1.0], "n": 20000.0}),
        ("grazing-heavy", {"kd": [0.3, 0.2, 0.1], "ks": [0.5, 0.5, 0.5], "n": 3.0}),
    ],
    "phong": [
        ("example", {"kd": [0.2, 0.15, 0.1], "ks": [0.4, 0.3, 0.2], "n": 80.0}),
        ("saturated", {"kd": SATURATED, "ks": [0.3, 0.3, 0.3], "n": 40.0}),
        ("dark", {"kd": DARK, "ks": [0.05, 0.05, 0.05], "n": 150.0}),
        ("near-mirror", {"kd": [0.02, 0.02, 0.02], "ks": [1.0, 1.0, 1.0], "n": 20000.0}),
        ("grazing-heavy", {"kd": [0.3, 0.2, 0.1], "ks": [0.5, 0.5, 0.5], "n": 2.0}),
    ],
    "beckmann": [
        ("example", {"kd": [0.15, 0.1, 0.3], "ks": [0.5, 0.6, 0.7], "alpha": 0.25, "f0": 0.4}),
        ("saturated", {"kd": SATURATED, "ks": [0.6, 0.6, 0.6], "alpha": 0.2, "f0": 0.05}),
        ("dark", {"kd": DARK, "ks": [0.1, 0.1, 0.1], "alpha": 0.1, "f0": 0.05}),
        ("near-mirror", {"kd": [0.01, 0.01, 0.01], "ks": [1, 1, 1], "alpha": 0.004, "f0": 0.95}),
        ("grazing-heavy", {"kd": [0.2, 0.2, 0.2], "ks": [1, 1, 1], "alpha": 0.6, "f0": 0.03}),
    ],
    "beckmann_dielectric": DIELECTRIC_LOBE,
    "ggx": [
        ("example", {"kd": [0.2, 0.1, 0.05], "ks": [0.8, 0.7, 0.6], "alpha": 0.15, "f0": 0.6}),
        ("saturated", {"kd": SATURATED, "ks": [0.6, 0.6, 0.6], "alpha": 0.2, "f0": 0.05}),
        ("dark", {"kd": DARK, "ks": [0.1, 0.1, 0.1], "alpha": 0.1, "f0": 0.05}),
        ("near-mirror", {"kd": [0.01, 0.01, 0.01], "ks": [1, 1, 1], "alpha": 0.003, "f0": 0.95}),
        ("grazing-heavy", {"kd": [0.2, 0.2, 0.2], "ks": [1, 1, 1], "alpha": 0.6, "f0": 0.03}),
    ],
    "ggx_dielectric": DIELECTRIC_LOBE,
    "gltf_pbr": GLTF,
    "gltf_pbr_ior": [(label, {**p, "ior": ior}) for (label, p), ior in
                     zip(GLTF, (1.5, 1.6, 1.45, 1.5, 1.2), strict=True)],
    "gltf_threejs": GLTF,
    "gltf_blender": GLTF,
    "gltf_pbr_dielectric": [(label, {k: v for k, v in p.items() if k != "metallic"})
                            for label, p in GLTF],
    "rough_conductor": [
        ("example", {"eta": [0.2, 0.9, 1.1], "k": [3.9, 2.4, 2.2], "alpha": 0.2,
                     "kd": [0.05, 0.04, 0.03], "weight": 0.9}),
        ("saturated", {"eta": [0.15, 0.5, 1.4], "k": [3.6, 2.5, 1.9], "alpha": 0.3,
                       "kd": SATURATED, "weight": 0.5}),
        ("dark", {"eta": [1.5, 1.5, 1.5], "k": [0.5, 0.5, 0.5], "alpha": 0.1,
                  "kd": [0.01, 0.01, 0.01], "weight": 0.3}),
        ("near-mirror", {"eta": [1.6, 1.0, 0.8], "k": [3.2, 3.0, 2.8], "alpha": 0.004,
                         "kd": [0.005, 0.005, 0.005], "weight": 1.0}),
        ("grazing-heavy", {"eta": [1.2, 1.2, 1.2], "k": [0.2, 0.2, 0.2], "alpha": 0.6,
                           "kd": [0.3, 0.3, 0.3], "weight": 0.6}),
    ],
    "standard_surface": STANDARD_SURFACE,
    "standard_surface_dielectric": [
        (label, {k: v for k, v in p.items() if k != "metalness"})
        for label, p in (
            ("example", {"base_color": [0.8, 0.5, 0.3], "specular_color": [1.0, 1.0, 1.0],
                         "specular_roughness": 0.4, "specular_IOR": 1.5}),
            *[(label, p) for label, p in STANDARD_SURFACE[1:3]],
            ("near-mirror", {"base_color": [0.05, 0.05, 0.05], "specular_color": [1.0] * 3,
                             "specular_roughness": 0.06, "specular_IOR": 1.6}),
            STANDARD_SURFACE[4],
        )
    ],
    # a lacquer over a rough plastic (a coated car paint's build), and a sharp coat over
    # a dark broad metal
    "standard_surface_coat": [
        ("example", {"base_color": [0.6, 0.1, 0.05], "metalness": 0.0,
                     "specular_color": [1.0, 1.0, 1.0], "specular_roughness": 0.5,
                     "specular_IOR": 1.5, "coat": 1.0, "coat_roughness": 0.1}),
        ("near-mirror", {"base_color": [0.3, 0.3, 0.35], "metalness": 1.0,
                         "specular_color": [0.8, 0.8, 0.9], "specular_roughness": 0.45,
                         "specular_IOR": 1.5, "coat": 0.8, "coat_roughness": 0.06}),
    ],
    # a velvet (a broad tinted sheen over a rough dark base) and a satin (a sharp faint one)
    "standard_surface_sheen": [
        ("example", {"base_color": [0.3, 0.05, 0.08], "metalness": 0.0,
                     "specular_color": [1.0, 1.0, 1.0], "specular_roughness": 0.8,
                     "specular_IOR": 1.5, "sheen": 1.0, "sheen_color": [0.9, 0.5, 0.6],
                     "sheen_roughness": 0.3}),
        ("grazing-heavy", {"base_color": [0.5, 0.45, 0.4], "metalness": 0.0,
                           "specular_color": [1.0, 1.0, 1.0], "specular_roughness": 0.5,
                           "specular_IOR": 1.5, "sheen": 0.5, "sheen_color": [1.0, 1.0, 1.0],
                           "sheen_roughness": 0.08}),
    ],
    # a lobe whose colour turns with the angle: a red that turns blue-green, a paint's
    # saturated body under a white-rimmed lobe, a dark one, a near-mirror, a broad one
    # whose colour turns late (Schlick's exponent)
    "generalized_schlick": [
        ("example", {"kd": [0.3, 0.15, 0.08], "color0": [0.6, 0.3, 0.2],
                     "color90": [0.3, 0.6, 0.7], "exponent": 1.5, "alpha": 0.15}),
        ("saturated", {"kd": SATURATED, "color0": [0.05, 0.05, 0.05],
                       "color90": [0.8, 0.8, 0.8], "exponent": 3.0, "alpha": 0.3}),
        ("dark", {"kd": DARK, "color0": [0.03, 0.02, 0.04], "color90": [0.02, 0.05, 0.02],
                  "exponent": 1.0, "alpha": 0.1}),
        ("near-mirror", {"kd": [0.02, 0.02, 0.02], "color0": [0.8, 0.5, 0.3],
                         "color90": [0.5, 0.6, 0.9], "exponent": 2.0, "alpha": 0.005}),
        ("grazing-heavy", {"kd": [0.2, 0.2, 0.2], "color0": [0.04, 0.04, 0.04],
                           "color90": [1.0, 1.0, 1.0], "exponent": 5.0, "alpha": 0.6}),
    ],
    "principled": [
        ("example", {"base_color": [0.5, 0.2, 0.1], "roughness": 0.45, "specular": 0.5,
                     "sheen": 0.3, "sheen_tint": 0.5}),
        ("saturated", {"base_color": SATURATED, "roughness": 0.55, "specular": 0.5,
                       "sheen": 0.0, "sheen_tint": 0.0}),
        ("dark", {"base_color": DARK, "roughness": 0.3, "specular": 0.3, "sheen": 0.1,
                  "sheen_tint": 0.0}),
        ("near-mirror", {"base_color": [0.02] * 3, "roughness": 0.06, "specular": 0.8,
                         "sheen": 0.0, "sheen_tint": 0.0}),
        ("grazing-heavy", {"base_color": [0.2] * 3, "roughness": 0.9, "specular": 0.5,
                           "sheen": 1.0, "sheen_tint": 0.3}),
    ],
    # the layered models: a coat over a base set, and a sharp coat
    # (two sets each: the full suite's time; their bases' five are above)
    "gltf_clearcoat": [
        (label, {**params, "clearcoat": coat, "clearcoat_roughness": rough})
        for (label, params), coat, rough in zip(
            (GLTF[0], GLTF[3]), (0.8, 0.7), (0.1, 0.04), strict=True)],
    # the same coats as three.js shades them (the sharp one above its roughness floor,
    # 0.045: below it the coat does not change, and a fit there ends anywhere)
    "gltf_threejs_clearcoat": [
        (label, {**params, "clearcoat": coat, "clearcoat_roughness": rough})
        for (label, params), coat, rough in zip(
            (GLTF[0], GLTF[3]), (0.8, 0.7), (0.1, 0.08), strict=True)],
    # the same coats as Blender shades them (Disney's GTR1 coat at a quarter weight)
    "gltf_blender_clearcoat": [
        (label, {**params, "clearcoat": coat, "clearcoat_roughness": rough})
        for (label, params), coat, rough in zip(
            (GLTF[0], GLTF[3]), (0.8, 0.7), (0.1, 0.08), strict=True)],
    # a sheen over a broad base (velvet) and a faint sharp one (satin)
    "gltf_sheen": [
        ("example", {**GLTF[4][1], "base_color": [0.3, 0.05, 0.08], "sheen_color": [0.9, 0.5, 0.6],
                     "sheen_roughness": 0.5}),
        ("grazing-heavy", {**GLTF[1][1], "sheen_color": [0.3, 0.3, 0.3],
                           "sheen_roughness": 0.2}),
    ],
    # the same sheen files as three.js shades them
    "gltf_threejs_sheen": [
        ("example", {**GLTF[4][1], "base_color": [0.3, 0.05, 0.08], "sheen_color": [0.9, 0.5, 0.6],
                     "sheen_roughness": 0.5}),
        ("grazing-heavy", {**GLTF[1][1], "sheen_color": [0.3, 0.3, 0.3],
                           "sheen_roughness": 0.2}),
    ],
    # the same sheen files as Blender shades them (a Velvet BSDF added)
    "gltf_blender_sheen": [
        ("example", {**GLTF[4][1], "base_color": [0.3, 0.05, 0.08], "sheen_color": [0.9, 0.5, 0.6],
                     "sheen_roughness": 0.5}),
        ("grazing-heavy", {**GLTF[1][1], "sheen_color": [0.3, 0.3, 0.3],
                           "sheen_roughness": 0.2}),
    ],
    # a film over a grey metal (a soap-bubble hue): one set, as its fit costs 4 starts
    # (tests/test_layered_models.py recovers a faint film over a dark base)
    "gltf_iridescence": [
        ("example", {**GLTF[0][1], "base_color": [0.5, 0.5, 0.5], "metallic": 1.0,
                     "iridescence": 1.0, "iridescence_ior": 1.5, "iridescence_thickness": 400.0}),
    ],
    # the same film as three.js shades it
    "gltf_threejs_iridescence": [
        ("example", {**GLTF[0][1], "base_color": [0.5, 0.5, 0.5], "metallic": 1.0,
                     "iridescence": 1.0, "iridescence_ior": 1.5, "iridescence_thickness": 400.0}),
    ],
    "principled_clearcoat": [
        ("example", {"base_color": [0.5, 0.2, 0.1], "roughness": 0.45, "specular": 0.5,
                     "sheen": 0.3, "sheen_tint": 0.5, "clearcoat": 0.8,
                     "clearcoat_gloss": 0.8}),
        ("near-mirror", {"base_color": [0.02] * 3, "roughness": 0.5, "specular": 0.8,
                         "sheen": 0.0, "sheen_tint": 0.0, "clearcoat": 1.0,
                         "clearcoat_gloss": 0.95}),
    ],
    "rough_plastic": [
        ("example", {"kd": [0.5, 0.2, 0.1], "alpha": 0.2, "eta": 1.5, "ks": [1.0] * 3}),
        ("saturated", {"kd": SATURATED, "alpha": 0.3, "eta": 1.49, "ks": [1.0] * 3}),
        ("dark", {"kd": DARK, "alpha": 0.1, "eta": 1.4, "ks": [0.8] * 3}),
        ("near-mirror", {"kd": [0.02] * 3, "alpha": 0.004, "eta": 1.6, "ks": [1.0] * 3}),
        ("grazing-heavy", {"kd": [0.2] * 3, "alpha": 0.6, "eta": 2.2, "ks": [1.0] * 3}),
    ],
    "ggx2": [
        ("example", {"kd": [0.1, 0.08, 0.05], "ks1": [0.5] * 3, "alpha1": 0.03,
                     "ks2": [0.4] * 3, "alpha2": 0.3, "f0": 0.8}),
        ("saturated", {"kd": SATURATED, "ks1": [0.3] * 3, "alpha1": 0.05,
                       "ks2": [0.3, 0.2, 0.01], "alpha2": 0.4, "f0": 0.1}),
        ("dark", {"kd": DARK, "ks1": [0.1] * 3, "alpha1": 0.05, "ks2": [0.05] * 3,
                  "alpha2": 0.3, "f0": 0.1}),
        ("near-mirror", {"kd": [0.01] * 3, "ks1": [1.0] * 3, "alpha1": 0.004,
                         "ks2": [0.2] * 3, "alpha2": 0.1, "f0": 0.9}),
        ("grazing-heavy", {"kd": [0.2] * 3, "ks1": [0.5] * 3, "alpha1": 0.2,
                           "ks2": [0.8] * 3, "alpha2": 0.8, "f0": 0.03}),
    ],
    "ggx3": [
        ("example", {"kd": [0.02, 0.015, 0.01], "ks1": [0.2, 0.15, 0.12], "alpha1": 0.01,
                     "ks2": [0.1] * 3, "alpha2": 0.06, "ks3": [0.05, 0.06, 0.08],
                     "alpha3": 0.4, "f0": 0.7}),
        ("near-mirror", {"kd": [0.01] * 3, "ks1": [1.0] * 3, "alpha1": 0.003,
                         "ks2": [0.2] * 3, "alpha2": 0.02, "ks3": [0.05] * 3, "alpha3": 0.2,
                         "f0": 0.9}),
        ("grazing-heavy", {"kd": [0.2] * 3, "ks1": [0.3] * 3, "alpha1": 0.1,
                           "ks2": [0.5] * 3, "alpha2": 0.4, "ks3": [0.8] * 3, "alpha3": 1.2,
                           "f0": 0.03}),
    ],
    "ggx4": [
        ("near-mirror", {"kd": [0.01] * 3, "ks1": [1.0] * 3, "alpha1": 0.003,
                         "ks2": [0.2] * 3, "alpha2": 0.02, "ks3": [0.05] * 3, "alpha3": 0.1,
                         "ks4": [0.03] * 3, "alpha4": 0.5, "f0": 0.9}),
    ],
}
