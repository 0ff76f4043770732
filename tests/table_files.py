"""Synthetic MERL table files for the tests that need files on disk (batch, cluster)."""

from __future__ import annotations

from pathlib import Path


def write_tables(directory: Path, spec: dict) -> Path:
    """``directory/<name>.binary`` for each ``name: (model, params)`` of ``spec``, each
    with its truth beside it (``data_synth``); returns ``directory``."""
    from data_synth import make_table
    from data_synth.synth import write_table

    for name, (model, params) in spec.items():
        table, truth = make_table(model, params, source=name)
        write_table(str(directory / f"{name}.binary"), table, truth)
    return directory


def write_astm(path: Path, model: str, params: dict, n: int = 20_000, seed: int = 5) -> Path:
    """An ASTM E1392 file as Cornell's gonioreflectometer writes one (radians, RGB) of
    ``n`` samples of ``model``: the light on three rings in one azimuth, the view
    anywhere above the horizon."""
    import jax.numpy as jnp
    import numpy as np

    from brdffit import models
    from brdffit.io.measurements import direction

    rng = np.random.default_rng(seed)
    theta_i = rng.choice(np.radians([15.0, 35.0, 55.0]), n)
    phi_i = np.zeros(n)
    theta_o = np.arccos(rng.uniform(0.1, 1.0, n))
    phi_o = rng.uniform(0.0, 2 * np.pi, n)
    m = models.get(model)
    p = {k: jnp.asarray(v) for k, v in m.check_params(params).items()}
    f = np.asarray(m(p, jnp.asarray(direction(theta_i, phi_i)),
                     jnp.asarray(direction(theta_o, phi_o))))
    rows = np.column_stack([theta_i, phi_i, theta_o, phi_o, f])
    path.write_text(f"SOURCE brdffit-test\nNUM_POINTS {n}\n"
                    "VARS theta_i,phi_i,theta_s,phi_s,R,G,B\n"
                    + "\n".join(",".join(f"{x:.9g}" for x in r) for r in rows) + "\n")
    return path


#: A CSV whose second row is below the horizon: one line, exit 2 / 422 / a failed table.
def write_workbook(path: Path, sheets: dict[str, list[float]], n: int = 300,
                   seed: int = 4) -> Path:
    """An Excel workbook of one sheet of ``n`` Lambertian samples per ``name: kd`` of
    ``sheets``, in that order, each at the same directions (degrees, as a lab's
    spreadsheet holds them)."""
    import numpy as np
    import openpyxl

    rng = np.random.default_rng(seed)
    angles = np.column_stack([rng.choice([10.0, 30.0, 50.0, 70.0], n), np.zeros(n),
                              np.degrees(np.arccos(rng.uniform(0.1, 1.0, n))),
                              rng.uniform(0.0, 360.0, n)])
    wb = openpyxl.Workbook()
    wb.remove(wb.active)
    for name, kd in sheets.items():
        sheet = wb.create_sheet(name)
        sheet.append(["theta_i_deg", "phi_i_deg", "theta_o_deg", "phi_o_deg", "r", "g", "b"])
        for a in angles:
            sheet.append([float(x) for x in (*a, *(np.asarray(kd) / np.pi))])
    wb.save(path)
    return path


BAD_CSV = "theta_i_deg,phi_i_deg,theta_o_deg,phi_o_deg,r,g,b\n10,0,120,0,1,1,1\n"
#: The GGX material of the sample files.
SAMPLED = {"kd": [0.2, 0.3, 0.4], "ks": [0.6, 0.6, 0.6], "alpha": 0.2, "f0": 0.2}
