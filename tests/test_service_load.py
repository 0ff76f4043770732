"""A small run of ``bench/service_load.py``: clients released together against a real
server on 127.0.0.1, every accepted job accounted for, memory within the bounds the
benchmark checks (the full run, 20 clients of full-table ggx2, writes
bench/results/service_load.md)."""

from __future__ import annotations

import pytest

from bench import service_load

pytestmark = pytest.mark.system


def test_a_small_load_run_ends_every_accepted_job():
    args = service_load.parse(["--quick", "--out", ""])
    result = service_load.run(args)
    assert result["problems"] == [], result["problems"]
    assert result["accepted"] == args.clients * args.jobs
    assert result["by_status"] == {"done": result["accepted"]}
    assert result["listing_total"] == result["accepted"] and result["http_5xx"] == 0
    assert result["queue_wait"]["n"] == result["run"]["n"] == result["accepted"]
    assert 0 < result["memory_mib"]["most_workers_at_once"] <= args.workers
    # the sampler saw the server and its workers through the run
    assert result["memory_timeline"] and result["memory_mib"]["worker_peak"] > 0
