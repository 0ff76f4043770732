"""Ground-truth parameters for the recovery tests: each model's own example."""

from brdffit.models import BUILTIN

#: Each built-in model's own ``example_params`` (brdffit/models/): a model that gives
#: them is recovered, evaluated and checked by every test parametrised over TRUTH.
TRUTH = {m.name: m.example_params for m in BUILTIN if m.example_params is not None}


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
