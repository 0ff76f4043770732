"""What a fit returns: :class:`FitResult`, plain Python values and no JAX.

Kept apart from ``brdffit.fitting`` so that a process that only reads results
(``brdffit.client``, a batch report) need not import JAX to hold one.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

from . import jsonout


@dataclass
class FitResult:
    """The outcome of one fit, failed or not, as plain Python values.

    ``params`` uses the MODELS.md names: RGB parameters are lists of 3 floats,
    shape parameters floats. ``error`` holds ``log_rmse`` (see ``brdffit.loss``)
    and friends, on the full table. ``result`` says how the solve ended
    (``brdffit.solvers.STATUS_NAMES``): ``"successful"`` only where the optimality
    test holds at the returned point, else ``"nonlinear_max_steps_reached"``,
    ``"stalled"`` or ``"nonfinite"``; ``converged`` is True only for
    ``"successful"``.
    """

    model: str
    params: dict[str, float | list[float]]
    error: dict[str, float]
    converged: bool
    result: str
    steps: int
    time_s: float
    samples: dict[str, int | dict[str, int]]
    solver: str = "lm"
    precision: str = "float64"
    starts: int = 1
    table: str | None = None
    extra: dict = field(default_factory=dict)

    @property
    def log_rmse(self) -> float:
        return self.error["log_rmse"]

    def to_dict(self) -> dict:
        return asdict(self)

    def to_json(self, **kw) -> str:
        """Strict JSON (``brdffit.jsonout``): a metric that is NaN or inf here is null."""
        return jsonout.dumps(self.to_dict(), **kw)

    @classmethod
    def from_dict(cls, d: dict) -> FitResult:
        return cls(**d)

    def param_arrays(self) -> dict:
        """Params as numpy arrays (``dict[str, np.ndarray]``), ready for
        ``model(params, wi, wo)``."""
        import numpy as np

        return {k: np.asarray(v, dtype=np.float64) for k, v in self.params.items()}
