"""``brdffit.batch.cluster.connect``: a local cluster whose workers cannot start is one
clear error (and exit 2 from the CLI), not distributed's traceback."""

from __future__ import annotations

import distributed
import pytest

from brdffit.batch.cluster import connect
from brdffit.cli import main as cli_main

pytestmark = pytest.mark.unit


class _NoWorkers:
    """Stands for LocalCluster where worker processes cannot start (a container
    without /dev/shm): distributed raises this, chained to the cause."""

    def __init__(self, *args, **kwargs):
        try:
            raise PermissionError(13, "Permission denied", "/dev/shm")
        except PermissionError as e:
            raise RuntimeError("Nanny failed to start.") from e


def test_workers_that_cannot_start_are_one_clear_error(monkeypatch, tmp_path, capsys):
    monkeypatch.setattr(distributed, "LocalCluster", _NoWorkers)
    with pytest.raises(OSError, match=r"cannot start 2 local Dask worker process\(es\): "
                                      r"PermissionError: .*--workers 0"):
        with connect(workers=2):
            pass
    table = tmp_path / "t.binary"
    table.write_bytes(b"not a table")  # never read: the cluster fails first
    code = cli_main(["batch", str(table), "--models", "lambert", "--out",
                     str(tmp_path / "r.h5"), "--workers", "2", "--quiet"])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and "Traceback" not in err, err
    assert err.startswith("brdffit: error: cannot start 2 local Dask worker process(es)")
