"""Half/difference parameterisation and the reference bin lookup (docs/models.md)."""

from __future__ import annotations

import numpy as np
import pytest

from brdffit.io import angles, merl
from brdffit.io.grid import bin_grid

pytestmark = pytest.mark.unit


def test_every_bin_centre_maps_back_to_its_own_bin():
    i_th, i_td, i_pd = np.meshgrid(np.arange(90), np.arange(90), np.arange(180), indexing="ij")
    th, td, pd = angles.bin_centres(i_th, i_td, i_pd)
    j_th, j_td, j_pd = angles.half_diff_to_bins(th, td, pd)
    np.testing.assert_array_equal(j_th, i_th)
    np.testing.assert_array_equal(j_td, i_td)
    np.testing.assert_array_equal(j_pd, i_pd)


def test_bin_centres_round_trip_through_directions():
    """centre -> (wi, wo) -> half/diff angles -> the same bin, for every bin."""
    g = bin_grid()
    th, td, pd = angles.dirs_to_half_diff(g.wi, g.wo)
    bins = angles.half_diff_to_bins(th, td, pd)
    flat = angles.flat_index(*bins)
    np.testing.assert_array_equal(flat, np.arange(flat.size))


def test_directions_round_trip_random():
    rng = np.random.default_rng(0)
    n = 2000
    th = rng.uniform(0, np.pi / 2, n)
    td = rng.uniform(0, np.pi / 2, n)
    pd = rng.uniform(-np.pi, np.pi, n)
    ph = rng.uniform(-np.pi, np.pi, n)
    wi, wo = angles.half_diff_to_dirs(th, td, pd, ph)
    np.testing.assert_allclose(np.linalg.norm(wi, axis=1), 1, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(wo, axis=1), 1, atol=1e-12)
    th2, td2, pd2 = angles.dirs_to_half_diff(wi, wo)
    np.testing.assert_allclose(th2, th, atol=1e-9)
    np.testing.assert_allclose(td2, td, atol=1e-9)
    ok = (td > 1e-6) & (th > 1e-6)  # phi_d undefined at theta_d = 0
    np.testing.assert_allclose(np.angle(np.exp(1j * (pd2 - pd)))[ok], 0, atol=1e-8)


def test_reference_lookup_edges():
    # theta_h <= 0 -> 0; phi_d < 0 folds by +pi; everything clamps to range
    i = angles.half_diff_to_bins(
        np.array([0.0, -0.1, 10.0]), np.array([0.0, 2.0, -1.0]), np.array([-0.001, np.pi, 4.0])
    )
    assert i[0].tolist() == [0, 0, 89]
    assert i[1].tolist() == [0, 89, 0]
    assert i[2].tolist() == [179, 179, 179]


def test_swapping_wi_and_wo_hits_the_same_bin():
    """Reciprocity of the lookup: (wo, wi) is phi_d + pi, folded back."""
    g = bin_grid()
    sel = np.flatnonzero(g.above_horizon)[::997]
    a = angles.half_diff_to_bins(*angles.dirs_to_half_diff(g.wi[sel], g.wo[sel]))
    b = angles.half_diff_to_bins(*angles.dirs_to_half_diff(g.wo[sel], g.wi[sel]))
    assert np.mean(angles.flat_index(*a) == angles.flat_index(*b)) > 0.99


def test_table_from_formula_reads_back_the_formula(tmp_path):
    """A table written from f(theta_h, theta_d, phi_d) gives f at the bin centres."""
    g = bin_grid()
    f = 1.0 + g.theta_h + 2 * g.theta_d + 0.5 * np.cos(g.phi_d)
    table = merl.MerlTable.from_values(np.stack([f, 2 * f, 3 * f]))
    merl.write(tmp_path / "f.binary", table)
    back = merl.read(tmp_path / "f.binary")
    rng = np.random.default_rng(3)
    idx = rng.choice(f.size, 500, replace=False)
    vals = back.lookup(g.wi[idx], g.wo[idx])
    np.testing.assert_allclose(vals[:, 0], f[idx], rtol=1e-12)
    np.testing.assert_allclose(vals[:, 2], 3 * f[idx], rtol=1e-12)


@pytest.mark.parametrize("i_th", [0, 1, 45, 89])
def test_solid_angle_weights_are_positive_above_horizon(i_th):
    g = bin_grid()
    rows = slice(i_th * 90 * 180, (i_th + 1) * 90 * 180)
    w, above = g.weight[rows], g.above_horizon[rows]
    assert np.all(w[above] > 0) and np.all(w[~above] == 0)
    assert g.weight.sum() == pytest.approx(1.0)


def test_grid_cache_round_trip(tmp_path, monkeypatch):
    """The on-disk grid equals the computed one; a damaged cache file is recomputed."""
    from brdffit.io import grid

    monkeypatch.setenv("BRDFFIT_CACHE_DIR", str(tmp_path))
    grid.bin_grid.cache_clear()
    try:
        first = grid.bin_grid()  # computes and stores (on another thread)
        grid.wait_until_stored()
        stored = list(tmp_path.glob("merl-grid-*.npz"))
        assert len(stored) == 1
        grid.bin_grid.cache_clear()
        loaded = grid.bin_grid()
        for k in first.__dataclass_fields__:
            np.testing.assert_array_equal(getattr(first, k), getattr(loaded, k))
        stored[0].write_bytes(b"garbage")
        grid.bin_grid.cache_clear()
        again = grid.bin_grid()
        np.testing.assert_array_equal(again.weight, first.weight)
    finally:
        grid.bin_grid.cache_clear()


def test_sphere_integral_cache_round_trip(tmp_path, monkeypatch):
    """A sphere integral read from brdffit's cache equals the one computed, to the bit;
    a damaged file is computed again and replaced; without a cache nothing is kept."""
    from brdffit.fitting import sphere
    from brdffit.io import array_cache

    light = sphere.LIGHTS[0][1]
    monkeypatch.setenv("BRDFFIT_CACHE_DIR", str(tmp_path))
    sphere._sphere_integral.cache_clear()
    try:
        first = sphere.sphere_integral(light)  # computes and stores (on another thread)
        array_cache.wait_until_stored()
        (stored,) = tmp_path.glob("sphere-integral-v*.npz")
        sphere._sphere_integral.cache_clear()
        loaded = sphere.sphere_integral(light)
        for k in ("bins", "weight", "wi", "wo"):
            np.testing.assert_array_equal(getattr(first, k), getattr(loaded, k))
            assert not getattr(loaded, k).flags.writeable
        stored.write_bytes(b"garbage")
        sphere._sphere_integral.cache_clear()
        np.testing.assert_array_equal(sphere.sphere_integral(light).weight, first.weight)
        array_cache.wait_until_stored()
        with np.load(stored) as z:  # replaced by a whole file
            np.testing.assert_array_equal(z["bins"], first.bins)
        monkeypatch.setenv("BRDFFIT_CACHE_DIR", "")
        sphere._sphere_integral.cache_clear()
        np.testing.assert_array_equal(sphere.sphere_integral(light).wi, first.wi)
        assert array_cache._writers == []
    finally:
        sphere._sphere_integral.cache_clear()


def test_the_separable_grid_equals_the_flat_conversion():
    """brdffit.io.grid computes the directions axis by axis; they are what
    half_diff_to_dirs gives for every bin centre, and the weights follow the
    documented measure (cos td sin th sin td, dtheta_h = pi u / 90)."""
    from brdffit.io import grid

    g = grid._compute_grid()
    i_th, i_td, i_pd = np.meshgrid(*(np.arange(n) for n in angles.SHAPE), indexing="ij")
    theta_h, theta_d, phi_d = (a.ravel() for a in angles.bin_centres(i_th, i_td, i_pd))
    np.testing.assert_array_equal(g.theta_h, theta_h)
    np.testing.assert_array_equal(g.theta_d, theta_d)
    np.testing.assert_array_equal(g.phi_d, phi_d)
    wi, wo = angles.half_diff_to_dirs(theta_h, theta_d, phi_d)
    np.testing.assert_allclose(g.wi, wi, rtol=0, atol=1e-15)
    np.testing.assert_allclose(g.wo, wo, rtol=0, atol=1e-15)
    above = (wi[:, 2] > 0) & (wo[:, 2] > 0)
    np.testing.assert_array_equal(g.above_horizon, above)
    u = (i_th.ravel() + 0.5) / angles.N_THETA_H
    w = np.where(above, np.cos(theta_d) * np.sin(theta_h) * np.sin(theta_d) * u, 0.0)
    np.testing.assert_allclose(g.weight, w / w.sum(), rtol=1e-12, atol=0)


def test_the_grids_frame_from_its_axes_is_the_frame_of_its_directions():
    """brdffit.fitting.problem makes the frame of every bin from the grid's axes (the
    half vector and cos theta_d known exactly); it is models.frame.shading_frame of
    the bins' directions to rounding, in float64 and float32."""
    from brdffit import runtime
    from brdffit.fitting.problem import _device_frames
    from brdffit.models.frame import shading_frame

    g = bin_grid()
    expected = shading_frame(g.wi, g.wo, np)
    with runtime.float64():
        for dtype, atol in (("float64", 1e-14), ("float32", 3e-7)):
            made = _device_frames(dtype)
            for name, a, b in zip(made._fields, made, expected, strict=True):
                assert np.asarray(a).dtype == dtype
                np.testing.assert_allclose(np.asarray(a, np.float64), b, rtol=0, atol=atol,
                                           err_msg=name)
