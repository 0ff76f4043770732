"""What each model's job costs beyond what ``api.estimate`` counts by its
parameters and steps: its programs' loading and its costlier steps, in seconds.

Written by ``python -m bench.model_costs`` on gold-metallic-paint.binary; do not edit. A
model not here (a plugin's) counts the largest.

AMD EPYC, 2 cores; JAX 0.10.2, brdffit 0.1.0; 2026-12-07T18:26:12+00:00 (load average 1.6 1.4 1.4)
"""

EXTRA_S: dict[str, float] = {
    "lambert": 0.00,
    "oren_nayar": 0.00,
    "blinn_phong": 0.00,
    "phong": 0.00,
    "beckmann": 0.00,
    "beckmann_dielectric": 0.63,
    "ggx": 0.00,
    "ggx_dielectric": 0.01,
    "gltf_pbr": 0.04,
    "gltf_pbr_ior": 0.81,
    "gltf_pbr_dielectric": 0.00,
    "gltf_threejs": 0.16,
    "gltf_blender": 0.17,
    "gltf_clearcoat": 0.36,
    "gltf_sheen": 0.32,
    "gltf_iridescence": 6.11,
    "gltf_threejs_clearcoat": 0.04,
    "gltf_threejs_sheen": 0.33,
    "gltf_threejs_iridescence": 9.77,
    "gltf_blender_clearcoat": 0.00,
    "gltf_blender_sheen": 0.09,
    "rough_conductor": 0.33,
    "rough_plastic": 4.14,
    "principled": 0.00,
    "standard_surface": 1.19,
    "standard_surface_dielectric": 0.34,
    "principled_clearcoat": 0.47,
    "standard_surface_coat": 3.96,
    "standard_surface_sheen": 4.02,
    "generalized_schlick": 0.63,
    "ggx2": 0.00,
    "ggx3": 2.04,
    "ggx4": 0.48,
}

#: The same for a job's peak memory, in MiB: the estimate counts the
#: largest of a job's models'.
EXTRA_MIB: dict[str, int] = {
    "lambert": 0,
    "oren_nayar": 0,
    "blinn_phong": 0,
    "phong": 0,
    "beckmann": 0,
    "beckmann_dielectric": 18,
    "ggx": 0,
    "ggx_dielectric": 0,
    "gltf_pbr": 0,
    "gltf_pbr_ior": 42,
    "gltf_pbr_dielectric": 0,
    "gltf_threejs": 4,
    "gltf_blender": 0,
    "gltf_clearcoat": 36,
    "gltf_sheen": 75,
    "gltf_iridescence": 1963,
    "gltf_threejs_clearcoat": 89,
    "gltf_threejs_sheen": 84,
    "gltf_threejs_iridescence": 1250,
    "gltf_blender_clearcoat": 44,
    "gltf_blender_sheen": 65,
    "rough_conductor": 29,
    "rough_plastic": 621,
    "principled": 9,
    "standard_surface": 189,
    "standard_surface_dielectric": 174,
    "principled_clearcoat": 106,
    "standard_surface_coat": 409,
    "standard_surface_sheen": 341,
    "generalized_schlick": 130,
    "ggx2": 0,
    "ggx3": 76,
    "ggx4": 184,
}
