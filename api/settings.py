"""Every setting of the service, read from ``BRDFFIT_*`` environment variables."""

from __future__ import annotations

from pathlib import Path

from pydantic import Field, SecretStr, field_validator
from pydantic_settings import BaseSettings, SettingsConfigDict

MiB = 1024 * 1024


class Settings(BaseSettings):
    """Each field is the ``BRDFFIT_<NAME>`` environment variable (docs/service.md,
    "Settings", lists them all)."""

    model_config = SettingsConfigDict(env_prefix="BRDFFIT_", extra="ignore")

    #: Uploaded tables, the SQLite job database and cached plots live here.
    data_dir: Path = Path(".brdffit-data")
    #: Largest accepted request body on upload. A MERL table is 34,992,012 bytes.
    max_upload_bytes: int = Field(64 * MiB, ge=1024)
    #: Fit worker processes. Each fit already uses several cores through XLA, so
    #: more workers than cores / 2 rarely helps.
    workers: int = Field(1, ge=1, le=64)
    #: ``tcp://HOST:PORT`` of an existing Dask cluster: jobs run there, on the batch
    #: job's runner (``brdffit.batch.cluster.DaskRunner``), instead of in ``workers``
    #: local processes. Its workers must read the data directory at the same path.
    dask_scheduler: str | None = None
    #: When set, every route but /healthz needs ``Authorization: Bearer <token>``.
    api_token: SecretStr | None = None
    #: Runs of a job that a server stop or a worker crash may interrupt before the
    #: job is marked failed (a job that kills its worker must not loop forever).
    max_attempts: int = Field(2, ge=1, le=10)

    # -- bounds: what one request or one job may take --------------------------------
    #: A fit whose estimated peak memory (api.estimate) is over this is refused (422).
    max_job_memory_mib: int = Field(8192, ge=64)
    #: A fit whose estimated run time is over this is refused (422).
    max_job_estimate_s: float = Field(1800.0, gt=0)
    #: A running job is stopped, and failed, after this long.
    job_time_limit_s: float = Field(3600.0, gt=0)
    #: Largest request body on every route but the upload (JSON fit requests).
    max_json_bytes: int = Field(1 * MiB, ge=1024)
    #: A request body that sends nothing for this long is answered 408 and dropped.
    body_read_timeout_s: float = Field(30.0, gt=0)

    # -- supervision -------------------------------------------------------------------
    #: How long the dispatcher retries storing a job's outcome while the storage
    #: fails before it gives up on the job (failed with the reason, if it can write).
    storage_retry_s: float = Field(300.0, ge=0)
    #: /healthz reports not ready when the data dir has less free space than this.
    min_free_mib: int = Field(256, ge=0)

    @field_validator("api_token")
    @classmethod
    def _empty_token_is_none(cls, v: SecretStr | None) -> SecretStr | None:
        # BRDFFIT_API_TOKEN= (empty) in a compose file means "no token", not "".
        return v if v is not None and v.get_secret_value() else None

    @property
    def database(self) -> Path:
        return self.data_dir / "brdffit.sqlite3"
