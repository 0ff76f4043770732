"""Every setting of the service, read from ``BRDFFIT_*`` environment variables."""

from __future__ import annotations

from pathlib import Path

from pydantic import Field, SecretStr, field_validator
from pydantic_settings import BaseSettings, SettingsConfigDict

MiB = 1024 * 1024


class Settings(BaseSettings):
    """``BRDFFIT_DATA_DIR``, ``BRDFFIT_MAX_UPLOAD_BYTES``, ``BRDFFIT_WORKERS``,
    ``BRDFFIT_API_TOKEN``, ``BRDFFIT_MAX_ATTEMPTS``."""

    model_config = SettingsConfigDict(env_prefix="BRDFFIT_", extra="ignore")

    #: Uploaded tables, the SQLite job database and cached plots live here.
    data_dir: Path = Path(".brdffit-data")
    #: Largest accepted request body on upload. A MERL table is 34,992,012 bytes.
    max_upload_bytes: int = Field(64 * MiB, ge=1024)
    #: Fit worker processes. Each fit already uses several cores through XLA, so
    #: more workers than cores / 2 rarely helps.
    workers: int = Field(1, ge=1, le=64)
    #: When set, every route but /healthz needs ``Authorization: Bearer <token>``.
    api_token: SecretStr | None = None
    #: Runs of a job that a server stop or a worker crash may interrupt before the
    #: job is marked failed (a job that kills its worker must not loop forever).
    max_attempts: int = Field(2, ge=1, le=10)

    @field_validator("api_token")
    @classmethod
    def _empty_token_is_none(cls, v: SecretStr | None) -> SecretStr | None:
        # BRDFFIT_API_TOKEN= (empty) in a compose file means "no token", not "".
        return v if v is not None and v.get_secret_value() else None

    @property
    def database(self) -> Path:
        return self.data_dir / "brdffit.sqlite3"
