"""Ground-truth parameters for the recovery tests (one well-posed set per model)."""

TRUTH = {
    "lambert": {"kd": [0.5, 0.35, 0.2]},
    "oren_nayar": {"kd": [0.5, 0.35, 0.2], "sigma": 0.5},
    "phong": {"kd": [0.2, 0.15, 0.1], "ks": [0.4, 0.3, 0.2], "n": 80.0},
    "blinn_phong": {"kd": [0.2, 0.15, 0.1], "ks": [0.4, 0.3, 0.2], "n": 120.0},
    "ggx": {"kd": [0.2, 0.1, 0.05], "ks": [0.8, 0.7, 0.6], "alpha": 0.15, "f0": 0.6},
    "beckmann": {"kd": [0.15, 0.1, 0.3], "ks": [0.5, 0.6, 0.7], "alpha": 0.25, "f0": 0.4},
}


#: The keys of ``brdffit fit --json`` / ``FitResult.to_dict()`` that issue 2 documents.
FIT_JSON_KEYS = ("table", "model", "params", "error", "converged", "result", "steps",
                 "time_s", "samples")


def assert_params_close(got: dict, want: dict, rel: float, abs_small: float = 0.002):
    """Each value within ``rel`` relative, or ``abs_small`` absolute for values < 0.1."""
    import numpy as np

    problems = []
    for name, w in want.items():
        g = np.atleast_1d(np.asarray(got[name], float))
        w = np.atleast_1d(np.asarray(w, float))
        tol = np.where(np.abs(w) < 0.1, abs_small, rel * np.abs(w))
        if not np.all(np.abs(g - w) <= tol):
            problems.append(f"{name}: got {g.tolist()}, want {w.tolist()} (tol {tol.tolist()})")
    assert not problems, "; ".join(problems)
