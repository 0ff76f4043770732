"""Batch fitting: a real Dask LocalCluster, bad tables, the HDF5 layout, kill and resume.

Tables are made once per module (about 1 s each plus 35 MB on disk). Fits use
small options (4096 samples, one start) so the file runs in a few minutes on
two cores; noise-free tables fitted with their own model still recover their
parameters to well under 2 %.
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import signal
import subprocess
import sys
import threading
import time

import numpy as np
import pytest

from brdffit import models
from brdffit.batch.cluster import SCHEDULER_ENV, DaskRunner, local_cluster_options
from brdffit.batch.job import BatchInputError, find_tables, run_batch
from brdffit.batch.report import format_ranking, plot_summary, rank, summary_figure
from brdffit.batch.store import BatchFileError, BatchStore, read_results
from brdffit.batch.tasks import TableReadRecord
from brdffit.cli import main as cli_main
from brdffit.fitting.options import FitOptions
from brdffit.request import FitRequest
from tests.api_fixtures import free_port
from tests.dask_fixtures import separate_cluster
from tests.table_files import write_tables

pytestmark = pytest.mark.system

MODELS = ["ggx", "beckmann", "lambert"]
OPTIONS = FitOptions(samples=4096, starts=1)
CLI_OPTIONS = ["--samples", "4096", "--starts", "1"]
TRUTHS = {
    "a_ggx": ("ggx", {"kd": [0.2, 0.1, 0.05], "ks": [0.8, 0.7, 0.6], "alpha": 0.2, "f0": 0.6}),
    "b_beckmann": ("beckmann", {"kd": [0.1, 0.15, 0.2], "ks": [0.6, 0.6, 0.5], "alpha": 0.15,
                                "f0": 0.8}),
    "c_lambert": ("lambert", {"kd": [0.5, 0.35, 0.2]}),
}
BAD = {"d_truncated": "truncated", "e_text": "text file", "f_dims": "not the MERL grid"}
REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


@pytest.fixture(scope="module")
def table_dir(tmp_path_factory):
    d = write_tables(tmp_path_factory.mktemp("tables"), TRUTHS)
    good = (d / "a_ggx.binary").read_bytes()
    (d / "d_truncated.binary").write_bytes(good[: len(good) // 3])
    (d / "e_text.binary").write_text("# not a table\n0.1 0.2 0.3\n")
    dims = np.asarray([90, 90, 90], "<i4").tobytes()
    (d / "f_dims.binary").write_bytes(dims + good[12: 12 + 3 * 8 * 90 * 90 * 90])
    return d


@pytest.fixture(scope="module")
def cluster():
    from distributed import LocalCluster

    c = LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                     dashboard_address="127.0.0.1:0", **local_cluster_options(2))
    try:
        yield c
    finally:
        c.close(timeout=30)


@pytest.fixture(scope="module")
def cluster_batch(table_dir, cluster, tmp_path_factory):
    """One batch of every table x 3 models on the LocalCluster, uninterrupted."""
    out = tmp_path_factory.mktemp("out") / "results.h5"
    summary = run_batch([str(table_dir)], FitRequest(tuple(MODELS), OPTIONS), out,
                        scheduler=cluster.scheduler_address, progress=False, timeout_s=600)
    return out, summary


def _tables(out) -> dict[str, dict]:
    return {t["name"]: t for t in read_results(out)["tables"]}


def _close(fit_value, true_value, rtol):
    return np.allclose(np.asarray(fit_value), np.asarray(true_value), rtol=rtol, atol=1e-4)


# -- the cluster batch ---------------------------------------------------------------------


def test_cluster_batch_records_every_table_and_model(cluster_batch, table_dir):
    out, summary = cluster_batch
    assert summary.tables == 6 and summary.skipped == 0
    assert summary.fits == 3 * len(MODELS)
    assert sorted(os.path.basename(p) for p, _ in summary.failed_tables) == [
        f"{n}.binary" for n in sorted(BAD)]
    assert not summary.failed_fits and not summary.ok

    results = read_results(out)
    attrs = results["attrs"]
    assert attrs["format"] == "brdffit-batch" and attrs["format_version"] == 1
    assert json.loads(attrs["models"]) == MODELS
    assert json.loads(attrs["options"]) == json.loads(OPTIONS.key())  # the resume key
    assert attrs["n_tables"] == 6 and attrs["n_tables_failed"] == 3
    assert attrs["n_fits"] == 9 and attrs["n_fits_failed"] == 0
    assert not os.path.exists(str(out) + ".journal"), "a clean finish removes the journal"

    tables = _tables(out)
    assert sorted(tables) == sorted([*TRUTHS, *BAD])
    workers = set()
    for name, (true_model, _) in TRUTHS.items():
        t = tables[name]
        path = str(table_dir / f"{name}.binary")
        assert t["path"] == path and t["status"] == "ok" and t["message"] == ""
        assert t["sha256"] == _sha256(path)
        assert t["measured_bins"] > 0 and t["size_bytes"] == 34_992_012
        assert t["worker"] and t["worker"] != f"{os.uname().nodename}:{os.getpid()}"
        workers.add(t["worker"])
        truth = json.loads((table_dir / f"{name}.binary.json").read_text())
        assert truth["model"] == true_model
        assert sorted(t["fits"]) == sorted(MODELS)
        for model, f in t["fits"].items():
            assert f["status"] == "ok" and f["message"] == ""
            assert f["sha256"] == t["sha256"]
            assert json.loads(f["options"]) == json.loads(OPTIONS.key())
            assert f["samples"] == 4096 and f["starts"] == 1 and f["solver"] == "lm"
            assert f["result"] and f["steps"] >= 0 and f["time_s"] > 0
            assert isinstance(f["converged"], bool)
            assert set(f["error"]) >= {"log_rmse", "rmse_cos", "rel_peak_error", "sample_log_rmse"}
            assert all(np.isfinite(v) for v in f["error"].values())
            spec = {s.name: s.size for s in models.get(model).param_specs}
            assert {k: np.size(v) for k, v in f["params"].items()} == spec
            assert all(np.all(np.isfinite(v)) for v in f["params"].values())
            if model == true_model:
                assert f["converged"], (name, f["result"])
                for p, v in truth["params"].items():
                    assert _close(f["params"][p], v, 0.02), (name, p, f["params"][p], v)
                assert f["error"]["log_rmse"] < 1e-3
            else:  # another model cannot beat a table's own (it may tie: GGX with ks=0)
                own = t["fits"][true_model]["error"]["log_rmse"]
                assert f["error"]["log_rmse"] >= own - 1e-9
    for name, words in BAD.items():
        t = tables[name]
        assert t["status"] == "failed" and words in t["message"], t["message"]
        assert t["fits"] == {}
    assert len(workers) >= 1


def test_rerun_skips_everything_finished(cluster_batch, table_dir, cluster):
    out, _ = cluster_batch
    before = _tables(out)
    summary = run_batch([str(table_dir)], FitRequest(tuple(MODELS), OPTIONS), out,
                        scheduler=cluster.scheduler_address, progress=False, timeout_s=300)
    assert summary.skipped == 3 and summary.fits == 0
    assert len(summary.failed_tables) == 3  # bad tables are tried again: they may be fixed
    after = _tables(out)
    for name in TRUTHS:
        for model in MODELS:
            assert after[name]["fits"][model]["finished_at"] == \
                before[name]["fits"][model]["finished_at"]


def test_report_ranks_each_table_own_model_first(cluster_batch, tmp_path):
    out, _ = cluster_batch
    r = rank(out)
    best = {t.name: t.best for t in r.tables}
    for name, (model, _) in TRUTHS.items():
        assert best[name] == model  # a tie (GGX, ks=0, on Lambert) goes to fewer params
    assert {t.name for t in r.failed_tables} == set(BAD)
    by_model = {s.model: s for s in r.summary}
    assert all(by_model[m].fitted == 3 and by_model[m].wins == 1 for m in MODELS)
    text = format_ranking(r, "results.h5")
    assert "a_ggx" in text and "FAILED" in text and "mean log_rmse" in text
    # every fit that ran has its verdict counted, as its stored result says
    for s in r.summary:
        assert sum(s.looks.values()) == s.fitted
    assert "looks good/visible/poor" in text
    png = plot_summary(r, tmp_path / "summary.png")
    assert open(png, "rb").read(8) == b"\x89PNG\r\n\x1a\n"
    # the count of tables each model wins is ticked in whole tables
    err_axis, wins_axis = summary_figure(r).axes[:2]
    assert all(float(t).is_integer() for t in wins_axis.get_yticks())
    # each model's wins stacked by how the winning fit looks, and each fit's dot in its
    # look's colour (the figure had neither: only the text said how fits look)
    from matplotlib.colors import to_rgba

    from brdffit.batch.report import LOOK_COLOURS

    stacked = {}
    for bar in wins_axis.patches:
        x = round(bar.get_x() + bar.get_width() / 2)
        stacked[x] = stacked.get(x, 0) + bar.get_height()
    order = [t.get_text() for t in wins_axis.get_xticklabels()]
    assert {order[x - 1]: n for x, n in stacked.items() if n} == {
        s.model: s.wins for s in r.summary if s.wins}
    dots = [tuple(c) for coll in err_axis.collections for c in coll.get_facecolors()]
    looks = [t.looks[m]["verdict"] for t in r.tables for m in t.looks]
    for look in set(looks):
        want = to_rgba(LOOK_COLOURS[look], 0.75)
        assert sum(np.allclose(d, want) for d in dots) == looks.count(look), look


def test_report_cli(cluster_batch, tmp_path, capsys):
    out, _ = cluster_batch
    png = tmp_path / "s.png"
    assert cli_main(["batch-report", str(out), "--png", str(png)]) == 0
    text = capsys.readouterr().out
    assert "beckmann" in text and "wins" in text
    assert png.stat().st_size > 1000


# -- the service runner ---------------------------------------------------------------------


def test_dask_runner_runs_a_call_on_the_cluster(cluster, table_dir):
    """What the service's job runner uses (api.runner): any importable function, its
    value back (the service's tasks return an Outcome rather than raise)."""
    from api import tasks

    with DaskRunner(cluster.scheduler_address) as runner:
        assert runner.submit_call(os.path.getsize, str(table_dir / "e_text.binary")).result(
            timeout=60) == (table_dir / "e_text.binary").stat().st_size
        path = str(table_dir / "c_lambert.binary")
        out = runner.submit_call(tasks.fit_models, path, "c.binary",
                                 FitRequest.of("lambert", samples=4096, starts=1).to_dict()
                                 ).result(timeout=300)
        assert out.ok and _close(out.value[0]["params"]["kd"], TRUTHS["c_lambert"][1]["kd"],
                                 0.02)
        bad = runner.submit_call(tasks.fit_models, str(table_dir / "d_truncated.binary"),
                                 "d.binary", {"models": ["lambert"]}).result(timeout=300)
        assert not bad.ok and "truncated" in bad.reason and not bad.internal
    assert DaskRunner.from_env({}) is None
    runner = DaskRunner.from_env({SCHEDULER_ENV: cluster.scheduler_address})
    assert runner is not None and runner.address == cluster.scheduler_address
    runner.close()


def _cores_and_fit_events(path: str) -> tuple[list[int], str, list[tuple[str, str]]]:
    """In a worker: its cores, the key of its compiled programs on disk, and how its
    programs for a fit it has not run before (no other test gives this cluster a
    phong fit) were made ready (``brdffit.executables.events``: loaded or compiled)."""
    from brdffit import executables, fit
    from brdffit.io import merl

    before = len(executables.events)
    fit(merl.read(path), "phong", starts=1)
    return (sorted(os.sched_getaffinity(0)), executables._fingerprint(),
            [(e.how, e.name.rsplit(".", 1)[-1]) for e in executables.events[before:]])


def test_local_workers_take_their_own_cores_and_load_what_others_compiled(cluster, table_dir):
    """Local workers (``brdffit batch --workers N``) split the batch's cores between
    them instead of running single-threaded XLA flags: no two fight over a core, and
    they load the compiled fits that this process (``brdffit warmup``, any fit) keeps
    rather than compiling their own (the flags were part of the programs' key)."""
    from distributed import Client

    from brdffit import executables, fit
    from brdffit.io import merl

    path = str(table_dir / "c_lambert.binary")
    fit(merl.read(path), "phong", starts=1)  # compiled and kept here
    with Client(cluster.scheduler_address, set_as_default=False) as client:
        workers = list(client.scheduler_info()["workers"])
        assert len(workers) == 2
        seen = [client.submit(_cores_and_fit_events, path, workers=[w], pure=False)
                .result(timeout=300) for w in workers]
    mine = sorted(os.sched_getaffinity(0))
    (cores_0, key_0, events_0), (cores_1, key_1, events_1) = seen
    if len(mine) >= 2:
        assert not set(cores_0) & set(cores_1) and sorted(cores_0 + cores_1) == mine, seen
    # the directory of this process's programs is theirs (with the flags it was not:
    # they compiled each program once more between them, and kept it apart)
    assert key_0 == key_1 == executables._fingerprint(), seen
    solves = [how for how, name in events_0 + events_1 if name == "solve_batch"]
    assert solves and set(solves) == {"loaded"}, seen


@pytest.mark.unit
@pytest.mark.parametrize(("workers", "cores", "shares"), [
    (2, [0, 1], [[0], [1]]),
    (2, [0, 1, 2, 3, 4], [[0, 2, 4], [1, 3]]),
    (3, [4, 7], [[4], [7], [4]]),  # more workers than cores: one core each, shared
])
def test_each_local_worker_gets_a_share_of_the_cores(workers, cores, shares):
    from brdffit.batch.local_worker import core_share

    assert [core_share(i, workers, cores) for i in range(workers)] == shares


@pytest.mark.unit
def test_more_workers_than_cores_get_a_line_saying_so():
    from brdffit.cli.batch import workers_note

    assert workers_note(2, 2) is None and workers_note(1, 4) is None
    note = workers_note(3, 2)
    assert note.startswith("brdffit: 3 workers on 2 cores") and "--workers 2" in note
    assert "\n" not in note


@pytest.mark.unit
def test_a_lone_or_foreign_worker_keeps_its_cores(monkeypatch):
    from brdffit.batch import local_worker

    calls = []
    monkeypatch.setattr(os, "sched_setaffinity", lambda pid, cores: calls.append(cores))
    local_worker.take_cores(0, environ={})  # not started by brdffit's local cluster
    local_worker.take_cores(0, environ={"BRDFFIT_LOCAL_WORKERS": "1"})
    local_worker.take_cores("tcp://10.0.0.1:4000", environ={"BRDFFIT_LOCAL_WORKERS": "2"})
    assert calls == []
    local_worker.take_cores(1, environ={"BRDFFIT_LOCAL_WORKERS": "2"})
    assert len(calls) == 1


@pytest.mark.unit
def test_a_local_worker_drops_only_the_heartbeat_to_a_stopped_batch():
    import logging

    from brdffit.batch.local_worker import HeartbeatToStoppedBatch

    def record(msg, level=logging.ERROR):
        return logging.LogRecord("distributed.worker", level, __file__, 1, msg, None, None)

    drop = HeartbeatToStoppedBatch()
    assert not drop.filter(record("Failed to communicate with scheduler during heartbeat."))
    for kept in ("Unexpected exception during heartbeat. Closing worker.",
                 "Compute Failed", "Worker process died unexpectedly"):
        assert drop.filter(record(kept)), kept


def test_dask_runner_reports_a_dead_worker():
    import dask
    from distributed import LocalCluster

    from brdffit.batch.cluster import DaskWorkerLost

    with dask.config.set({"distributed.scheduler.allowed-failures": 0}):
        with LocalCluster(n_workers=1, threads_per_worker=1, processes=True, host="127.0.0.1",
                          dashboard_address="127.0.0.1:0") as c, \
                DaskRunner(c.scheduler_address) as r:
            with pytest.raises(DaskWorkerLost, match="died"):
                r.submit_call(os._exit, 3).result(timeout=120)


# -- kill and resume -------------------------------------------------------------------------


def _batch_cmd(table_dir, out, *extra):
    return [sys.executable, "-m", "brdffit.cli", "batch", str(table_dir), "--models",
            ",".join(MODELS), "--out", str(out), *CLI_OPTIONS, *extra]


def test_sigkill_then_resume_gives_the_same_results(cluster_batch, table_dir, tmp_path):
    """SIGKILL ``brdffit batch`` (default engine: local Dask workers) once some fits
    are done; the file stays readable, the workers go with it, and a second run
    finishes with what an uninterrupted batch gives."""
    reference, _ = cluster_batch
    out = tmp_path / "killed.h5"
    journal = str(out) + ".journal"
    proc = subprocess.Popen(_batch_cmd(table_dir, out, "--workers", "1", "--checkpoint", "0"),
                            cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            start_new_session=True)
    workers: set[int] = set()
    try:
        deadline = time.monotonic() + 240
        while time.monotonic() < deadline and proc.poll() is None:
            workers |= _descendants(proc.pid)
            if len(_fits_recorded(journal, out)) >= len(MODELS):
                break  # the first good table is done: the other two are not
            time.sleep(0.05)
        assert proc.poll() is None, "the batch finished before it could be killed"
        workers |= _descendants(proc.pid)
        os.kill(proc.pid, signal.SIGKILL)  # the batch process alone, as `kill -9` would
        proc.wait(timeout=30)
        assert workers, "the batch ran no worker process"
        deadline = time.monotonic() + 90
        while time.monotonic() < deadline and any(_alive(p) for p in workers):
            time.sleep(0.2)
        assert not any(_alive(p) for p in workers), "worker processes outlived the batch"
    finally:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGKILL)
        proc.wait(timeout=30)
    assert proc.returncode == -signal.SIGKILL

    killed = _tables(out)  # readable: a kill never leaves a half-written file
    done_before = {(n, m) for n, t in killed.items() for m, f in t["fits"].items()
                   if f["status"] == "ok"}
    # journaled or in the file (a kill between a checkpoint's rename and its emptying
    # of the journal leaves the same fits in both: counted once)
    assert len(_fits_recorded(journal, out)) >= len(MODELS)
    assert len(done_before) < 3 * len(MODELS)

    resumed = subprocess.run(_batch_cmd(table_dir, out, "--workers", "0"), cwd=REPO,
                             capture_output=True, text=True, timeout=300)
    assert resumed.returncode == 1, resumed.stderr
    assert "3 of 6 tables failed" in resumed.stderr
    final, ref = _tables(out), _tables(reference)
    assert sorted(final) == sorted(ref)
    for name in TRUTHS:
        for model in MODELS:
            a, b = final[name]["fits"][model], ref[name]["fits"][model]
            assert a["status"] == b["status"] == "ok"
            assert a["result"] == b["result"] and a["sha256"] == b["sha256"]
            for p in b["params"]:
                np.testing.assert_allclose(a["params"][p], b["params"][p], rtol=1e-6)
            np.testing.assert_allclose(a["error"]["log_rmse"], b["error"]["log_rmse"],
                                       rtol=1e-6, atol=1e-12)
    # the fits finished before the kill were kept, not made again
    for name, model in done_before:
        assert final[name]["fits"][model]["finished_at"] == \
            killed[name]["fits"][model]["finished_at"]
    assert not os.path.exists(journal)


def _descendants(pid: int) -> set[int]:
    """Live descendants of ``pid``, from /proc."""
    parent = {}
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                with open(f"/proc/{entry}/stat") as f:
                    parent[int(entry)] = int(f.read().rsplit(")", 1)[1].split()[1])
            except (OSError, ValueError, IndexError):
                continue
    found, frontier = set(), {pid}
    while frontier:
        frontier = {p for p, pp in parent.items() if pp in frontier} - found
        found |= frontier
    return found


def _alive(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


def _fits_recorded(journal: str, out) -> set[tuple[str, str]]:
    """(table path, model) of every fit in the journal (complete lines) or in the HDF5
    file: a checkpoint writes the file before it empties the journal, so a fit can be
    in both at once, and counting each side apart counted it twice."""
    done: set[tuple[str, str]] = set()
    try:
        with open(journal, "rb") as f:
            for line in f:
                if b'"kind":"fit"' in line and line.endswith(b"\n"):
                    r = json.loads(line)
                    done.add((r["path"], r["model"]))
    except FileNotFoundError:
        pass
    try:
        for t in read_results(out)["tables"]:
            done |= {(t["path"], m) for m in t["fits"]}
    except (BatchFileError, OSError, KeyError):
        pass
    return done


_STORE_WRITER = """
import sys, time
from brdffit.batch.store import BatchStore
from brdffit.batch.tasks import FitOptions, FitRecord, TableReadRecord
out, n = sys.argv[1], int(sys.argv[2])
fit = {"model": "lambert", "params": {"kd": [0.5, 0.4, 0.3]}, "error": {"log_rmse": 0.01},
       "converged": True, "result": "successful", "steps": 3, "time_s": 0.1, "starts": 1,
       "samples": {"used": 1, "usable": 1, "measured": 1,
                   "dropped": {"unmeasured": 0, "nonfinite": 0, "below_horizon": 0}}}
with BatchStore(out) as store:
    start = store.counts()["n_tables"]
    print("ready", flush=True)
    for i in range(start, start + n):
        path = f"/tables/t{i:05d}.binary"
        store.add(TableReadRecord(path=path, status="ok", sha256=str(i)),
                  [FitRecord(path=path, model="lambert", sha256=str(i),
                             options=FitOptions().fit_keywords(), status="ok", fit=fit)])
        store.checkpoint({"models": ["lambert"]})
"""


def test_store_survives_sigkill_at_random_moments(tmp_path):
    """Kill a writer that checkpoints after every record, at arbitrary moments:
    the file always opens, and nothing journaled is lost."""
    out = tmp_path / "stress.h5"
    rng = np.random.default_rng(1)
    seen = 0
    for _ in range(4):
        proc = subprocess.Popen([sys.executable, "-c", _STORE_WRITER, str(out), "100000"],
                                stdout=subprocess.PIPE, start_new_session=True)
        try:
            assert proc.stdout.readline().strip() == b"ready"
            time.sleep(rng.uniform(0.2, 1.0))
        finally:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait(timeout=30)
        n_file = read_results(out)["attrs"]["n_tables"]  # opens: never half-written
        assert n_file >= seen
        with BatchStore(out) as store:  # the journal tops up what the file lacks
            n_all = store.counts()["n_tables"]
            assert n_all >= n_file and n_all >= seen
            store.checkpoint()
        seen = n_all
        assert read_results(out)["attrs"]["n_tables"] == seen
        assert not os.path.exists(str(out) + ".journal")
    assert seen > 0


def test_torn_journal_line_is_dropped(tmp_path):
    out = tmp_path / "torn.h5"
    rec = {"kind": "table", **TableReadRecord(path="/x.binary", status="ok", sha256="1").__dict__}
    with open(str(out) + ".journal", "w") as f:
        f.write(json.dumps(rec) + "\n" + json.dumps(rec)[:17])
    with BatchStore(out) as store:
        assert store.recovered == 1
        store.add(TableReadRecord(path="/y.binary", status="ok", sha256="2"), [])
        with open(str(out) + ".journal") as f:
            assert [json.loads(line)["path"] for line in f] == ["/x.binary", "/y.binary"]
        store.checkpoint()
    assert sorted(t["path"] for t in read_results(out)["tables"]) == ["/x.binary", "/y.binary"]


def test_a_second_writer_is_refused(tmp_path):
    out = tmp_path / "locked.h5"
    with BatchStore(out):
        with pytest.raises(BatchFileError, match="another batch"):
            BatchStore(out).open()


def test_a_refused_out_leaves_no_journal_and_a_damaged_file_is_one_error(tmp_path, monkeypatch):
    """--out a folder, a text file or a foreign HDF5 file: refused, and the journal the
    lock made (empty) is gone. A damaged results file (an attribute not as written,
    a group h5py cannot open) is one BatchFileError naming it, reading or writing;
    where a run's results were journaled, they are kept there and the message says so."""
    import h5py

    from brdffit.batch.store import read_looks

    folder = tmp_path / "out"
    folder.mkdir()
    text = tmp_path / "notes.txt"
    text.write_text("not hdf5")
    foreign = tmp_path / "foreign.h5"
    with h5py.File(foreign, "w") as f:
        f["x"] = 1
    for out, says in ((folder, "a directory"),
                      (text, "a text file, not HDF5 .by its first bytes.; a batch results"),
                      (foreign, "not a brdffit batch results file")):
        with pytest.raises(BatchFileError, match=says):
            BatchStore(out).open()
        assert not os.path.exists(str(out) + ".journal"), out
    out = tmp_path / "r.h5"
    with BatchStore(out) as store:
        store.add(TableReadRecord(path="/x.binary", status="ok", sha256="1"), [])
        store.checkpoint()
    with h5py.File(out, "r+") as f:
        f["tables"]["x"].create_group("ggx").attrs["fit_json"] = "null"
    with pytest.raises(BatchFileError, match=r"r.h5: a damaged batch results file \(Attribute"):
        read_looks(out)
    # a table's group that is a dataset; a version that is no number
    from brdffit.batch.store import read_fit

    with h5py.File(out, "r+") as f:
        del f["tables"]["x"]
        f["tables"]["x"] = [1]
    with pytest.raises(BatchFileError, match=r"r.h5: a damaged batch results file \(Index"):
        read_fit(out, "x")
    with h5py.File(out, "r+") as f:
        version, f.attrs["format_version"] = f.attrs["format_version"], "abc"
    with pytest.raises(BatchFileError, match=r"damaged .*\(format_version 'abc', not a number"):
        read_looks(out)
    with h5py.File(out, "r+") as f:
        f.attrs["format_version"] = version
        del f["tables"]["x"]

    def unreadable(self, group, record):
        raise KeyError("Unable to synchronously open object (incorrect metadata checksum)")

    monkeypatch.setattr(BatchStore, "_write_table", unreadable)
    with BatchStore(out) as store:
        store.add(TableReadRecord(path="/y.binary", status="ok", sha256="2"), [])
        with pytest.raises(BatchFileError, match="damaged .* kept in .*r.h5.journal"):
            store.checkpoint()
    with open(str(out) + ".journal") as f:
        assert [json.loads(line)["path"] for line in f] == ["/y.binary"]

    # a full disk: HDF5's own words carry no errno ("file write failed: time = ..."),
    # and were the whole message; the file is whole, the fits in the journal
    def full(self, group, record):
        raise OSError("Can't close file (file write failed: time = Sat Dec  5, filename = "
                      "'r.h5.part-1', file descriptor = 7, errno = 28, error message = 'No "
                      "space left on device', buf = 0x55a8)")

    monkeypatch.setattr(BatchStore, "_write_table", full)
    with BatchStore(out) as store:
        store.add(TableReadRecord(path="/z.binary", status="ok", sha256="3"), [])
        with pytest.raises(BatchFileError, match=r"r.h5: could not write the results file "
                                                 r"\(a write failed; a full disk\?\); this "
                                                 r"run's finished fits are kept in .*journal"):
            store.checkpoint()


def _two_lambert_tables(tmp_path):
    """A folder of two small Lambert tables, m0 and m1, and fast options."""
    from brdffit.io import merl
    from data_synth import make_table

    d = tmp_path / "t"
    d.mkdir()
    for i, kd in enumerate(([0.5, 0.3, 0.2], [0.2, 0.3, 0.4])):
        merl.write(d / f"m{i}.binary", make_table("lambert", {"kd": kd})[0])
    return d, FitOptions(samples=1024, starts=1)


def test_a_table_named_with_dots_alone_gets_a_group_of_its_own(tmp_path):
    """"..binary" was the group "." (HDF5's name for /tables itself): its attributes went
    on /tables, its fit beside the tables, and the report read a table "lambert"."""
    d, opts = _two_lambert_tables(tmp_path)
    os.rename(d / "m0.binary", d / "..binary")
    out = tmp_path / "r.h5"
    # named: a folder's scan leaves dot files out, as a shell's * does
    assert run_batch([str(d / "..binary"), str(d / "m1.binary")], FitRequest(("lambert",), opts),
                     out, workers=0, progress=False).ok
    tables = _tables(out)
    assert sorted(tables) == ["_", "m1"]
    assert tables["_"]["path"].endswith("/..binary") and "lambert" in tables["_"]["fits"]


def test_a_folder_reached_through_a_link_resumes_its_fits(tmp_path, capsys):
    """The folder a first run fitted, given again through a symbolic link: its tables are
    the recorded ones (nothing fitted again, one entry each); given both ways in one
    run, each table is fitted once. A link that reaches another folder since is new."""
    d, opts = _two_lambert_tables(tmp_path)
    link = tmp_path / "link"
    link.symlink_to(d, target_is_directory=True)
    out = tmp_path / "r.h5"
    request = FitRequest(("lambert",), opts)
    assert run_batch([str(d)], request, out, workers=0, progress=False).fits == 2
    again = run_batch([str(link)], request, out, workers=0, progress=False)
    assert (again.fits, again.skipped, again.tables) == (0, 2, 2)
    both = run_batch([str(link / "m0.binary"), str(d)], request, out, workers=0,
                     progress=False)
    assert (both.fits, both.skipped, both.tables) == (0, 2, 2)
    tables = _tables(out)
    assert sorted(tables) == ["m0", "m1"]
    assert tables["m0"]["path"] == str(d / "m0.binary")
    # the link now reaches another folder (of the same content): its tables are new
    (tmp_path / "other").mkdir()
    other, _ = _two_lambert_tables(tmp_path / "other")
    link.unlink()
    link.symlink_to(other, target_is_directory=True)
    moved = run_batch([str(link)], request, out, workers=0, progress=False)
    assert moved.fits == 2
    # their names are the first tables' groups: stored as m0~2, m1~2, and said so
    assert [group for _, group in moved.renamed] == ["m0~2", "m1~2"]
    assert both.renamed == again.renamed == []
    (tmp_path / "third").mkdir()
    third, _ = _two_lambert_tables(tmp_path / "third")
    capsys.readouterr()
    assert cli_main(["batch", str(third), "--models", "lambert", "--samples", "1024",
                     "--starts", "1", "--out", str(out), "--quiet"]) == 0
    err = capsys.readouterr().err
    assert f"stored as group 'm0~3': {third / 'm0.binary'} (another table has its name)" in err


def test_changed_table_is_refitted_and_stale_fits_dropped(tmp_path):
    from brdffit.io import merl
    from data_synth import make_table

    d, opts = _two_lambert_tables(tmp_path)
    out = tmp_path / "r.h5"
    first = run_batch([str(d)], FitRequest(("lambert",), opts), out, workers=0,
                      progress=False)
    assert first.ok and first.fits == 2
    merl.write(d / "m1.binary", make_table("lambert", {"kd": [0.1, 0.1, 0.1]})[0])
    second = run_batch([str(d)], FitRequest(("lambert",), opts), out, workers=0,
                      progress=False)
    assert second.skipped == 1 and second.fits == 1
    assert (second.replaced_changed, second.replaced_options) == (1, 0)  # said, not "none"
    t = _tables(out)["m1"]
    assert t["sha256"] == _sha256(str(d / "m1.binary"))
    assert _close(t["fits"]["lambert"]["params"]["kd"], [0.1, 0.1, 0.1], 0.02)
    # other options are another fit; --refit makes them again regardless
    third = run_batch([str(d)], FitRequest.of("lambert", samples=2048, starts=1), out,
                      workers=0, progress=False)
    assert third.fits == 2 and third.replaced_options == 2 and third.replaced_changed == 0
    fourth = run_batch([str(d)], FitRequest.of("lambert", samples=2048, starts=1), out,
                       workers=0, progress=False, refit=True)
    assert fourth.fits == 2 and fourth.skipped == 0  # as asked: not counted as replaced
    assert (fourth.replaced_options, fourth.replaced_changed) == (0, 0)
    # a scene weights other directions: another fit, which a rerun then resumes
    from brdffit.fitting.scene import Scene

    in_scene = FitRequest.of("lambert", samples=2048, starts=1,
                             scene=Scene.preset("camera-normal"))
    fifth = run_batch([str(d)], in_scene, out, workers=0, progress=False)
    assert fifth.fits == 2 and fifth.skipped == 0 and fifth.replaced_options == 2
    sixth = run_batch([str(d)], in_scene, out, workers=0, progress=False)
    assert sixth.fits == 0 and sixth.skipped == 2
    assert json.loads(read_results(out)["attrs"]["request"])["scene"]["name"] == "camera-normal"


def test_a_fit_whose_stored_result_is_damaged_is_fitted_again(tmp_path, capsys):
    """A fit the index calls done but whose stored result does not read back (a disk
    error, a bit flipped) is fitted again on resume, and said so; it was kept as done,
    and every report of the file then failed on it."""
    import h5py

    d, opts = _two_lambert_tables(tmp_path)
    out = tmp_path / "r.h5"
    first = run_batch([str(d)], FitRequest(("lambert",), opts), out, workers=0,
                      progress=False)
    assert first.ok and first.fits == 2
    with h5py.File(out, "r+") as f:
        f["tables/m1/lambert"].attrs["fit_json"] = '{"model": "lambert", "par'
    with pytest.raises(BatchFileError, match="damaged"):
        read_results(out)
    second = run_batch([str(d)], FitRequest(("lambert",), opts), out, workers=0,
                       progress=False)
    assert second.fits == 1 and second.skipped == 1 and second.damaged == 1
    assert all(t["fits"]["lambert"]["fit"]["model"] == "lambert"
               for t in read_results(out)["tables"])
    with h5py.File(out, "r+") as f:
        del f["tables/m0/lambert"].attrs["fit_json"]
    capsys.readouterr()
    assert cli_main(["batch", str(d), "--models", "lambert", "--samples", "1024", "--starts",
                     "1", "--out", str(out), "--quiet"]) == 0
    assert "fitted again: 1 fit whose stored result did not read back" in capsys.readouterr().err


def test_a_lost_interrupt_still_stops_the_batch(tmp_path, capsys):
    """brdffit batch's SIGINT/SIGTERM handler sets ``job.stop_requested`` beside the
    KeyboardInterrupt it raises. Python drops that exception where it cannot raise it
    (a weakref callback, a ``__del__``: a CI run's Ctrl-C landed there, and the batch
    ran to its end and exited 0); the batch then stops at its next result, and the
    dropped exception is not printed."""
    from brdffit.batch import job
    from brdffit.cli import batch as batch_cli

    class RaisesWhenCollected:
        def __del__(self):
            raise KeyboardInterrupt  # unraisable: Python prints it and goes on

    def drop_one() -> str:
        hook, sys.unraisablehook = sys.unraisablehook, batch_cli._quiet_lost_interrupt
        try:
            RaisesWhenCollected()
        finally:
            sys.unraisablehook = hook
        return capsys.readouterr().err

    d, opts = _two_lambert_tables(tmp_path)
    out = tmp_path / "r.h5"
    job.stop_requested.set()
    try:
        with pytest.raises(KeyboardInterrupt):
            run_batch([str(d)], FitRequest(("lambert",), opts), out, workers=0,
                      progress=False)
        assert drop_one() == ""
    finally:
        job.stop_requested.clear()
    # the one result that came in was kept; nothing after it was fitted, and a rerun
    # fits the other table only
    kept = _tables(out)
    assert sum(len(t["fits"]) for t in kept.values()) == 1
    again = run_batch([str(d)], FitRequest(("lambert",), opts), out, workers=0,
                      progress=False)
    assert again.ok and again.fits == 1 and again.skipped == 1
    # without a stop asked for, an unraisable KeyboardInterrupt is reported as usual
    assert "KeyboardInterrupt" in drop_one()


# -- arguments, exit codes ---------------------------------------------------------------------


def test_find_tables(table_dir, tmp_path, monkeypatch):
    every = find_tables([str(table_dir)])
    assert [os.path.basename(p) for p in every] == sorted(
        f"{n}.binary" for n in [*TRUTHS, *BAD])  # sidecars (.json) are not tables
    # a lab's mixed folder: sample lists by suffix beside tables; notes and the
    # batch's own results file are not taken
    mixed = tmp_path / "lab"
    (mixed / "deep").mkdir(parents=True)
    for name in ("a.binary", "deep/b.astm", "c.csv", "d.h5", "notes.txt", "results.h5"):
        (mixed / name).write_bytes(b"x")
    got = find_tables([str(mixed)], exclude=[mixed / "results.h5"])
    assert sorted(os.path.relpath(p, mixed) for p in got) == [
        "a.binary", "c.csv", "d.h5", "deep/b.astm"]
    # a link to a table that is gone is taken, to fail as a table with its reason
    # (it was skipped unsaid); a folder named like a table is not
    os.symlink(tmp_path / "moved.binary", mixed / "gone.binary")
    (mixed / "dir.binary").mkdir()
    taken = {os.path.basename(p) for p in find_tables([str(mixed)])}
    assert "gone.binary" in taken and "dir.binary" not in taken
    from brdffit.batch.tasks import read_table

    _, record = read_table(str(mixed / "gone.binary"))
    assert record.message.endswith(f"cannot read: a link to {tmp_path / 'moved.binary'}, "
                                   "which does not exist")
    os.symlink(mixed / "loop2.binary", mixed / "loop1.binary")  # each to the other
    os.symlink(mixed / "loop1.binary", mixed / "loop2.binary")
    _, record = read_table(str(mixed / "loop1.binary"))
    assert record.message.endswith("which leads back round to itself (a loop)"), record.message
    assert find_tables([str(table_dir / "a_*.binary"), str(table_dir / "a_ggx.binary")]) == [
        str(table_dir / "a_ggx.binary")]
    with pytest.raises(BatchInputError, match="no such file"):
        find_tables([str(table_dir / "nope.binary")])
    with pytest.raises(BatchInputError, match="no file matches"):
        find_tables([str(table_dir / "zz*.binary")])
    # a folder below that cannot be read (chmod 000; simulated: the tests may run as
    # root, whom permissions do not stop): its files were left out unsaid
    real_walk = os.walk

    def walk_denied(top, onerror=None, **kw):
        yield from real_walk(top, onerror=onerror, **kw)
        onerror(PermissionError(13, "Permission denied", str(mixed / "locked")))

    monkeypatch.setattr(os, "walk", walk_denied)
    with pytest.raises(BatchInputError, match=r"locked: cannot be read \(Permission denied\): "
                                              "its files would be left out"):
        find_tables([str(mixed)])
    monkeypatch.setattr(os, "walk", real_walk)
    # a folder whose one file is the results file: said, not "holds no measured file"
    alone = tmp_path / "alone"
    alone.mkdir()
    (alone / "r.h5").write_bytes(b"x")
    with pytest.raises(BatchInputError, match="holds no measured file but .*r.h5, the "
                                              "batch's own results file"):
        find_tables([str(alone)], exclude=[alone / "r.h5"])
    # a quoted pattern matching the results file (and a crash's journal beside it) leaves
    # them out: on every run after the first it took the results file in as a table
    (alone / "t.binary").write_bytes(b"x")
    (alone / "r.h5.journal").write_bytes(b"x")
    assert find_tables([str(alone / "*")], exclude=[alone / "r.h5"]) == [
        str(alone / "t.binary")]
    with pytest.raises(BatchInputError, match="matches the batch's own results file"):
        find_tables([str(alone / "r.*")], exclude=[alone / "r.h5"])
    with pytest.raises(BatchInputError, match="r.h5: the batch's own results file"):
        find_tables([str(alone / "r.h5")], exclude=[alone / "r.h5"])
    # a name that is not UTF-8 is named, escaped, before any work (h5py failed on it at
    # the first checkpoint, naming no file)
    odd = os.fsdecode(os.fsencode(str(alone)) + b"/bad\xff.binary")
    with open(os.fsencode(odd), "wb") as f:
        f.write(b"x")
    with pytest.raises(BatchInputError, match=r"bad\\xff.binary: a file name that is not "
                                              "valid UTF-8"):
        find_tables([str(alone)], exclude=[alone / "r.h5"])


@pytest.mark.parametrize("argv, message", [
    (["--models", "ggx,nope"], "unknown model 'nope'"),
    (["--models", "ggx", "--samples", "10"], "samples must be an integer in 64 .."),
    (["--models", "ggx", "--workers", "-1"], "workers must be an integer >= 0"),
    (["--models", "ggx", "--checkpoint", "-5"], "checkpoint must be a number of seconds >= 0"),
    (["--models", "ggx", "--checkpoint", "nan"], "checkpoint must be a number of seconds >= 0"),
    # the cluster is reached before the file is made: it was made, and a resumed file's
    # models and options rewritten, by a run refused for its address
    (["--models", "ggx", "--scheduler", "notaurl"], "missing port number in address"),
    # a port nobody listens on is said after a short grace (the client retried it
    # for 30 s, then said "Timed out")
    (["--models", "ggx", "--scheduler", f"tcp://127.0.0.1:{free_port()}"],
     "nothing listens there (Connection refused for 5 s)"),
])
def test_bad_arguments_exit_2(table_dir, tmp_path, capsys, argv, message):
    code = cli_main(["batch", str(table_dir), "--out", str(tmp_path / "r.h5"), *argv])
    err = capsys.readouterr().err.splitlines()
    # a scheduler not reached within 2 s is said to be waited for, before the error
    waiting = [e for e in err if e.startswith("reaching the Dask scheduler at ")]
    assert code == 2 and message in err[-1] and len(err) == 1 + len(waiting)
    assert not (tmp_path / "r.h5").exists()


@contextlib.contextmanager
def _silent_port():
    """A loopback port that takes connections and never says a word, as another
    service's port or a stuck process does."""
    import socket

    listener = socket.create_server(("127.0.0.1", 0))
    taken, stop = [], threading.Event()

    def accept() -> None:
        listener.settimeout(0.1)
        while not stop.is_set():
            with contextlib.suppress(TimeoutError):
                taken.append(listener.accept()[0])

    thread = threading.Thread(target=accept, daemon=True)
    thread.start()
    try:
        yield f"tcp://127.0.0.1:{listener.getsockname()[1]}"
    finally:
        stop.set()
        thread.join()
        for conn in taken:
            conn.close()
        listener.close()


def test_a_port_that_never_answers_is_no_scheduler():
    """distributed's connect timeout leaves its handshake out: a Client of a port that
    accepts and never answers waited for good. Batch and service alike say so in one
    line after their timeout."""
    from brdffit.batch.cluster import connect

    with _silent_port() as address:
        t0 = time.monotonic()
        for reach in (lambda: connect(scheduler=address, timeout_s=1.0).__enter__(),
                      lambda: DaskRunner(address, timeout_s=1.0)):
            with pytest.raises(OSError, match=(
                    f"cannot reach the Dask scheduler at {address}: something listens there "
                    r"but did not answer as a Dask scheduler within 1 s")):
                reach()
        assert time.monotonic() - t0 < 20  # not the 30-s default, and not for good


def test_a_scheduler_that_keeps_the_batch_waiting_is_said_to(table_dir, tmp_path,
                                                              monkeypatch):
    """A batch given a port that never answers waited 30 s on a blank terminal before
    its one-line refusal: after 2 s it says what it waits for, once; nothing is written."""
    from brdffit.batch import job
    from brdffit.batch.progress import ProgressLine

    monkeypatch.setattr(job, "CONNECT_TIMEOUT_S", 2.0)
    monkeypatch.setattr(job, "SAY_WAITING_AFTER_S", 0.3)
    stream = io.StringIO()
    with _silent_port() as address, pytest.raises(OSError, match="within 2 s"):
        job.run_batch([str(table_dir)], ["lambert"], tmp_path / "r.h5", scheduler=address,
                      progress=ProgressLine(0, stream=stream))
    assert stream.getvalue() == (f"reaching the Dask scheduler at {address} (waiting up to "
                                 "2 s for its answer)\n")
    assert not (tmp_path / "r.h5").exists()


def test_an_address_where_nothing_listens_is_not_said_to_be_waited_for(table_dir, tmp_path,
                                                                     monkeypatch):
    """Nothing listening is tried for a few seconds, then refused; the batch said
    "waiting up to 30 s for its answer" meanwhile, of an answer it never waited for:
    that line is for an address that took the connection."""
    import functools

    from brdffit.batch import cluster, job
    from brdffit.batch.progress import ProgressLine

    monkeypatch.setattr(job, "SAY_WAITING_AFTER_S", 0.3)
    monkeypatch.setattr(cluster, "_refused", functools.partial(cluster._refused, grace_s=1.5))
    address = f"tcp://127.0.0.1:{free_port()}"
    stream = io.StringIO()
    with pytest.raises(OSError, match="nothing listens there .* for 1.5 s"):
        job.run_batch([str(table_dir)], ["lambert"], tmp_path / "r.h5", scheduler=address,
                      progress=ProgressLine(0, stream=stream))
    assert stream.getvalue() == ""
    assert not (tmp_path / "r.h5").exists()


def test_bad_outputs_exit_2(table_dir, tmp_path, capsys):
    assert cli_main(["batch", str(table_dir), "--models", "ggx", "--out",
                     str(tmp_path / "no" / "r.h5")]) == 2
    assert "does not exist" in capsys.readouterr().err
    not_h5 = tmp_path / "notes.h5"
    not_h5.write_text("my notes")
    assert cli_main(["batch", str(table_dir), "--models", "ggx", "--out", str(not_h5)]) == 2
    assert "notes.h5: a text file, not HDF5" in capsys.readouterr().err
    assert not_h5.read_text() == "my notes"


def test_only_bad_tables_exit_1_with_a_count(table_dir, tmp_path, capsys):
    bad = [str(table_dir / f"{n}.binary") for n in BAD]
    code = cli_main(["batch", *bad, "--models", "lambert", "--out", str(tmp_path / "r.h5"),
                     "--workers", "0", "--quiet", *CLI_OPTIONS])
    err = capsys.readouterr().err
    assert code == 1
    assert "3 of 3 tables failed" in err
    assert all(f"{n}.binary" in err for n in BAD)


def _sha256(path: str) -> str:
    import hashlib

    return hashlib.sha256(open(path, "rb").read()).hexdigest()


# -- an existing cluster: scheduler and worker started by hand, as on several machines ----


def test_batch_on_a_separately_started_scheduler_and_worker(table_dir, tmp_path):
    """docs/batch.md, "On a real cluster": `dask scheduler` and `dask worker` run as
    their own processes (as they would on other machines), and `brdffit batch
    --scheduler` submits to them."""
    env = {**os.environ, "PYTHONPATH": REPO}
    # the scheduler is up and its worker joined before the batch starts, as an operator
    # would see them (a refused address is tried for REFUSED_GRACE_S only)
    with separate_cluster(n_workers=1, env=env) as (address, _):
        out = tmp_path / "results.h5"
        r = subprocess.run(
            [sys.executable, "-m", "brdffit.cli", "batch", str(table_dir), "--models",
             "lambert", "--out", str(out), *CLI_OPTIONS, "--scheduler", address],
            cwd=REPO, env=env, capture_output=True, text=True, timeout=600)
    assert r.returncode == 1, r.stderr  # the bad tables are recorded: exit 1
    tables = _tables(out)
    for name in TRUTHS:
        fit = tables[name]["fits"]["lambert"]
        assert fit["status"] == "ok" and fit["fit"]["model"] == "lambert"
        assert fit["worker"].split(":")[0], fit  # the worker process that ran it
    for name in BAD:
        assert tables[name]["status"] == "failed"


@pytest.mark.unit
def test_a_log_gets_the_progress_where_the_batch_ended():
    """In a log (stderr not a terminal) the line is printed at the start, every 30 s and
    at the end: an interrupted batch printed none since its last 30 s; a finished one's
    last line is not printed twice."""
    import io

    from brdffit.batch.progress import ProgressLine

    log = io.StringIO()
    bar = ProgressLine(10, stream=log)
    bar.draw(force=True)
    bar.update(fits=2, failed=False)
    bar.update(fits=2, failed=True)  # within 30 s: not printed
    bar.finish()  # interrupted here
    lines = log.getvalue().splitlines()
    assert len(lines) == 2 and " 0/10 tables" in lines[0] and " 2/10 tables" in lines[1], lines
    assert "1 failed" in lines[1] and "  4 fits stored  " in lines[1]
    # a table's fits counted before the table is (its other fits still running)
    part = io.StringIO()
    bar = ProgressLine(2, stream=part)
    bar.update(fits=1, failed=False, tables=0)
    bar.draw(force=True)
    assert "0/2 tables  1 fit stored  " in part.getvalue(), part.getvalue()
    done = io.StringIO()
    bar = ProgressLine(1, stream=done)
    bar.update(fits=1, failed=False)  # the last table: printed at once
    bar.finish()
    assert len(done.getvalue().splitlines()) == 1, done.getvalue()


@pytest.mark.unit
def test_the_progress_line_moves_while_no_result_comes():
    """A first table that compiles for a minute showed one unchanging line. Within
    ``ticking`` the line is redrawn without results: on a terminal its elapsed time
    moves; in a log a line comes every ``interval_s`` (the batch is seen alive), none
    more often; the ticker stops when the batch does."""
    import io
    import threading

    from brdffit.batch.progress import ProgressLine

    class Terminal(io.StringIO):
        def isatty(self):
            return True

    def within_ticking(bar, stream, split, enough):
        """The parts ``split`` finds in ``stream`` once there are ``enough`` (or 10 s
        passed: a loaded machine delays the ticker, never the assertions), and the
        seconds it ticked."""
        t0 = time.monotonic()
        with bar.ticking(every_s=0.02):
            while len(split(stream.getvalue())) < enough and time.monotonic() - t0 < 10:
                time.sleep(0.02)
        return split(stream.getvalue()), time.monotonic() - t0

    term = Terminal()
    bar = ProgressLine(3, stream=term)
    bar.t0 -= 65.0  # a minute in, nothing done
    # a terminal's line is redrawn at most every 0.2 s
    drawn, _ = within_ticking(bar, term, lambda text: text.split("\r\x1b[2K")[1:], 2)
    assert len(drawn) >= 2 and all("0/3 tables" in d for d in drawn), drawn
    assert "elapsed 1m05s" in drawn[0] and "ETA ?" in drawn[0], drawn[0]
    assert not any(t.name == "brdffit-progress" for t in threading.enumerate())
    log = io.StringIO()
    bar = ProgressLine(3, stream=log, interval_s=0.1)
    bar.draw(force=True)
    lines, ticked = within_ticking(bar, log, str.splitlines, 3)
    # the forced line, then one per interval at most
    assert 3 <= len(lines) <= 2 + ticked / 0.1, (lines, ticked)
    assert all("0/3 tables" in line for line in lines), lines
    quiet = io.StringIO()  # progress off: no thread, nothing drawn
    bar = ProgressLine(3, stream=quiet, enabled=False)
    with bar.ticking(every_s=0.02):
        time.sleep(0.05)
    assert quiet.getvalue() == ""


@pytest.mark.unit
def test_the_summary_line_counts_in_words():
    from brdffit.batch.job import BatchSummary
    from brdffit.cli.batch import summary_line

    one = BatchSummary("out.h5", tables=2, skipped=1, fits=1, elapsed_s=3.1)
    assert summary_line(one) == "out.h5: 1 fit on 1 table in 3s; 1 table was already done"
    many = BatchSummary("out.h5", tables=5, skipped=2, fits=6, elapsed_s=3.1)
    assert summary_line(many).endswith("6 fits on 3 tables in 3s; 2 tables were already done")
    fresh = BatchSummary("out.h5", tables=2, fits=4, elapsed_s=3.1)
    assert summary_line(fresh).endswith("; none was done before")
    # a resume that kept some of a table's fits is not "none was done before"
    partly = BatchSummary("out.h5", tables=2, skipped=1, kept=3, fits=1, elapsed_s=3.1)
    assert summary_line(partly).endswith("; 1 table was already done, 3 fits of the others "
                                         "kept from before")
    partly.skipped = 0
    assert summary_line(partly).endswith("; 3 fits kept from before")
    # a rerun with other options, or of a changed file, replaces fits: not "none"
    other = BatchSummary("out.h5", tables=2, fits=2, replaced_options=2, elapsed_s=3.1)
    assert summary_line(other).endswith("; 2 fits made with other options, replaced")
    other.replaced_changed, other.kept = 1, 1
    assert summary_line(other).endswith("; 1 fit kept from before, 2 fits made with other "
                                        "options, replaced, 1 fit of tables whose file "
                                        "changed since, replaced")


def test_a_file_of_a_newer_format_is_named_so(tmp_path):
    import h5py

    from brdffit.batch.store import read_looks

    out = tmp_path / "r.h5"
    with BatchStore(out) as store:
        store.checkpoint()
    with h5py.File(out, "r+") as f:
        f.attrs["format_version"] = 99
    with pytest.raises(BatchFileError, match=r"r.h5: written by a newer brdffit \(format "
                                              r"version 99; this one reads up to 1\)"):
        read_looks(out)


def test_batch_report_refuses_a_png_it_would_write_elsewhere(tmp_path):
    """matplotlib wrote --png summary as summary.png (and --png DIR as DIR.png) and the
    report said it wrote the name given: refused before the report, in one line."""
    from brdffit.cli.batch_report import _png_path
    from brdffit.errors import BrdffitError

    for path, says in ((tmp_path, "a folder"), (tmp_path / "summary", "name it FILE.png"),
                       (tmp_path / "x.txt", "name it FILE.png"),
                       (tmp_path / "no" / "x.png", "does not exist")):
        with pytest.raises(BrdffitError, match=says):
            _png_path(str(path))
    assert _png_path(str(tmp_path / "s.PNG")) == str(tmp_path / "s.PNG")


def test_a_table_rewritten_during_a_cluster_batch_keeps_every_model(tmp_path, monkeypatch):
    """Each of a table's models is a task that reads the file itself: one rewritten
    while they run gave them different content, and the results file kept the last
    content's fits only (the others were dropped, the batch reported them made).
    Every model must end fitted to what the file holds at the end.

    One worker thread in this process runs the tasks in order, and ggx's task rewrites
    the table before it reads it: the models before it read the old content."""
    from distributed import LocalCluster

    from brdffit.batch import job
    from brdffit.io import merl
    from data_synth import make_table

    d, opts = _two_lambert_tables(tmp_path)
    (d / "m1.binary").unlink()
    table = d / "m0.binary"
    models_ = ("lambert", "oren_nayar", "phong", "ggx", "beckmann")
    real_fit_table = job.fit_table

    def rewriting_fit_table(path, request, item, *args):
        if item == ["ggx"] and not (tmp_path / "rewritten").exists():
            merl.write(path, make_table("lambert", {"kd": [0.1, 0.2, 0.3]})[0])
            (tmp_path / "rewritten").touch()
        return real_fit_table(path, request, item, *args)

    monkeypatch.setattr(job, "fit_table", rewriting_fit_table)
    out = tmp_path / "r.h5"
    with LocalCluster(n_workers=1, threads_per_worker=1, processes=False, protocol="tcp",
                      host="127.0.0.1", dashboard_address="127.0.0.1:0") as c:
        summary = run_batch([str(table)], FitRequest(models_, opts), out,
                            scheduler=c.scheduler_address, progress=False, timeout_s=600)
        assert (tmp_path / "rewritten").exists()
        assert summary.ok, summary
        # the models before ggx read the old content: fitted again (a fit of content
        # gone that returns after the change is not stored, nor counted)
        assert summary.fits > len(models_)
        t = _tables(out)["m0"]
        assert t["sha256"] == _sha256(str(table))
        assert sorted(t["fits"]) == sorted(models_)
        for model in models_:
            assert t["fits"][model]["sha256"] == t["sha256"], model
        assert _close(t["fits"]["lambert"]["params"]["kd"], [0.1, 0.2, 0.3], 0.02)
        # what the file holds is done: a rerun makes nothing
        again = run_batch([str(table)], FitRequest(models_, opts), out,
                          scheduler=c.scheduler_address, progress=False, timeout_s=300)
        assert again.fits == 0 and again.skipped == 1


def test_a_table_rewritten_at_every_read_fails_its_fits_saying_so(tmp_path, monkeypatch):
    """A file written to all the time is not fitted again and again: after
    CONTENT_ROUNDS its models fail, saying why."""
    from distributed import LocalCluster

    from brdffit.batch import job
    from brdffit.io import merl
    from data_synth import make_table

    d, opts = _two_lambert_tables(tmp_path)
    (d / "m1.binary").unlink()
    table = d / "m0.binary"
    real_fit_table = job.fit_table
    reads = tmp_path / "reads"  # a file: the task is a copy of this function
    reads.mkdir()

    def rewriting_fit_table(path, request, item, *args):
        n = len(os.listdir(reads))
        (reads / str(n)).touch()
        merl.write(path, make_table("lambert", {"kd": [0.1 + 0.01 * n] * 3})[0])
        return real_fit_table(path, request, item, *args)

    monkeypatch.setattr(job, "fit_table", rewriting_fit_table)
    with LocalCluster(n_workers=1, threads_per_worker=1, processes=False, protocol="tcp",
                      host="127.0.0.1", dashboard_address="127.0.0.1:0") as c:
        summary = run_batch([str(table)], FitRequest(("lambert", "phong"), opts),
                            tmp_path / "r.h5", scheduler=c.scheduler_address,
                            progress=False, timeout_s=600)
    assert len(os.listdir(reads)) == 2 + job.CONTENT_ROUNDS
    assert not summary.ok and summary.failed_fits
    assert all("the file changed while the batch fitted it" in why
               for _, _, why in summary.failed_fits)


# -- what a review of the batch found (session 39) -------------------------------------


def test_an_interrupted_refit_goes_on_where_it_stopped(tmp_path, capsys):
    """An interrupted --refit told the user to run the same command again, which made
    every fit again (the refit's own finished fits too) and said "none was done
    before". The file now marks a refit until it finishes: run again, it goes on."""
    d, opts = _two_lambert_tables(tmp_path)
    out = tmp_path / "r.h5"
    request = FitRequest(("lambert",), opts)
    assert run_batch([str(d)], request, out, workers=0, progress=False).fits == 2

    def stop_after_one(table, fits):
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        run_batch([str(d)], request, out, workers=0, progress=False, refit=True,
                  on_result=stop_after_one)
    assert "refit_pending" in read_results(out)["attrs"]
    again = run_batch([str(d)], request, out, workers=0, progress=False, refit=True)
    assert (again.fits, again.kept + again.skipped, again.refitted) == (1, 1, 1)
    assert again.resumed_refit is not None
    assert "refit_pending" not in read_results(out)["attrs"], "a finished refit is unmarked"
    # the next --refit is a new one: every fit made again, and said so
    capsys.readouterr()
    assert cli_main(["batch", str(d), "--models", "lambert", "--samples", "1024", "--starts",
                     "1", "--out", str(out), "--quiet", "--refit"]) == 0
    assert "2 fits on 2 tables" in (line := capsys.readouterr().out)
    assert "2 stored fits made again (--refit)" in line and "going on" not in line


def test_a_ctrl_c_once_every_fit_is_stored_is_no_interrupt(tmp_path, monkeypatch, capsys):
    """The local cluster takes 2-3 s to shut down after the last result; a Ctrl-C then
    made a complete batch an interrupted one: exit 130, no summary, and a --refit run's
    mark kept in the file. Every fit is stored: the run is complete."""
    from brdffit.batch import job

    real_connect = job.connect

    @contextlib.contextmanager
    def ctrl_c_at_shutdown(*args, **kwargs):
        with real_connect(*args, **kwargs) as client:
            yield client
            os.kill(os.getpid(), signal.SIGINT)  # as the cluster begins to shut down

    d, _ = _two_lambert_tables(tmp_path)
    out = tmp_path / "r.h5"
    monkeypatch.setattr(job, "connect", ctrl_c_at_shutdown)
    code = cli_main(["batch", str(d), "--models", "lambert", "--samples", "1024", "--starts",
                     "1", "--out", str(out), "--workers", "1", "--quiet", "--refit"])
    std = capsys.readouterr()
    assert code == 0, std.err
    assert "2 fits on 2 tables" in std.out and "interrupted" not in std.err
    assert "refit_pending" not in read_results(out)["attrs"]
    assert not os.path.exists(f"{out}.journal")


def test_what_a_crashed_run_journaled_is_counted_in_fits(tmp_path, capsys):
    """"recovered N results journaled" counted the journal's records, a table's record
    beside each of its fits: 2 for 1 fit, beside a summary that counts fits."""
    d, opts = _two_lambert_tables(tmp_path)
    journal = []

    def keep_the_first(table, fits):
        if not journal:
            journal.append((tmp_path / "a.h5.journal").read_text())

    run_batch([str(d)], FitRequest(("lambert",), opts), tmp_path / "a.h5", workers=0,
              progress=False, checkpoint_s=1000, on_result=keep_the_first)
    (tmp_path / "b.h5.journal").write_text(journal[0])  # a run killed after its first fit
    assert cli_main(["batch", str(d), "--models", "lambert", "--samples", "1024", "--starts",
                     "1", "--out", str(tmp_path / "b.h5"), "--workers", "0", "--quiet"]) == 0
    std = capsys.readouterr()
    assert std.err == "recovered 1 fit journaled by an interrupted run\n"
    assert "1 fit on 1 table" in std.out and "1 table was already done" in std.out


def test_a_symbolic_link_named_as_out_is_written_through(tmp_path):
    """--out a link: the link was replaced by a file of its own, its target kept the
    old results, and the lock was per spelling (two batches could write one file)."""
    d, opts = _two_lambert_tables(tmp_path)
    (tmp_path / "store").mkdir()
    target, link = tmp_path / "store" / "real.h5", tmp_path / "link.h5"
    link.symlink_to(target)
    request = FitRequest(("lambert",), opts)
    assert run_batch([str(d / "m0.binary")], request, link, workers=0, progress=False).ok
    assert link.is_symlink() and os.path.isfile(target)
    assert run_batch([str(d)], request, link, workers=0, progress=False).fits == 1
    assert link.is_symlink() and sorted(_tables(target)) == ["m0", "m1"]
    with BatchStore(target), pytest.raises(BatchFileError, match="another batch"):
        BatchStore(link).open()


def test_a_moved_folder_keeps_its_tables_and_fits(tmp_path, capsys):
    """A fit is identified by its table's content: a folder renamed since the last run
    made every fit again, as new tables beside the old (m0~2)."""
    d, opts = _two_lambert_tables(tmp_path)
    out = tmp_path / "r.h5"
    request = FitRequest(("lambert",), opts)
    assert run_batch([str(d)], request, out, workers=0, progress=False).fits == 2
    moved = tmp_path / "renamed"
    os.rename(d, moved)
    capsys.readouterr()
    assert cli_main(["batch", str(moved), "--models", "lambert", "--samples", "1024",
                     "--starts", "1", "--out", str(out), "--quiet"]) == 0
    line = capsys.readouterr().out
    assert "0 fits on 0 tables" in line and "2 tables found at a new path" in line
    tables = _tables(out)
    assert sorted(tables) == ["m0", "m1"]
    assert tables["m0"]["path"] == str(moved / "m0.binary")
    assert tables["m0"]["fits"]["lambert"]["status"] == "ok"
    # and resumed from the file alone, as a new process reads it
    assert run_batch([str(moved)], request, out, workers=0, progress=False).skipped == 2


def test_results_read_back_as_strict_json(tmp_path):
    """read_results gave NaN for a failed fit's time and for a metric not measured (null
    in the fit's own JSON): json.dumps(..., allow_nan=False) failed on it."""
    from brdffit.io import merl
    from data_synth import make_table

    table = make_table("lambert", {"kd": [0.5, 0.3, 0.2]})[0]
    keep = np.zeros(table.mask.size, bool)
    keep[np.flatnonzero(table.mask.ravel())[::60000]] = True  # ~18 bins: ggx needs 32
    rgb = np.where(keep.reshape(table.mask.shape), table.rgb, -1.0)
    merl.write(tmp_path / "sparse.binary", merl.MerlTable(rgb, keep.reshape(table.mask.shape)))
    out = tmp_path / "r.h5"
    s = run_batch([str(tmp_path / "sparse.binary")], FitRequest.of(["lambert", "ggx"],
                  samples=1024, starts=1), out, workers=0, progress=False)
    assert [m for _, m, _ in s.failed_fits] == ["ggx"]
    results = read_results(out)
    json.dumps(results, allow_nan=False)
    fit = results["tables"][0]["fits"]["ggx"]
    assert fit["status"] == "failed" and fit["time_s"] is None


def test_auto_with_a_candidate_added_says_it_makes_every_candidate_again(tmp_path):
    """auto's candidates are fitted together: with one added, the others are made again,
    and the summary said they were kept."""
    d, opts = _two_lambert_tables(tmp_path)
    out = tmp_path / "r.h5"
    first = run_batch([str(d)], FitRequest.of("auto", candidates=["lambert", "phong"],
                      samples=1024, starts=1), out, workers=0, progress=False)
    assert first.ok and first.fits == 4
    second = run_batch([str(d)], FitRequest.of("auto", candidates=["lambert", "phong",
                       "blinn_phong"], samples=1024, starts=1), out, workers=0, progress=False)
    assert second.fits == 6 and second.kept == 0


def test_results_files_that_cannot_be_journals_and_folders_that_refuse_writes(
        tmp_path, monkeypatch):
    import errno
    import shutil

    d, opts = _two_lambert_tables(tmp_path)
    request = FitRequest(("lambert",), opts)
    first = tmp_path / "r1.h5.journal"
    with pytest.raises(BatchFileError, match="journal; name the results file .h5"):
        run_batch([str(d)], request, first, workers=0, progress=False)
    # a results file left under a journal's name is not taken (and deleted) as one
    assert run_batch([str(d)], request, tmp_path / "other.h5", workers=0, progress=False).ok
    os.rename(tmp_path / "other.h5", tmp_path / "r1.h5.journal")
    with pytest.raises(BatchFileError, match="is an HDF5 file, not this file's journal"):
        run_batch([str(d)], request, tmp_path / "r1.h5", workers=0, progress=False)
    assert os.path.getsize(tmp_path / "r1.h5.journal") > 1000
    # a folder that refuses the write mid-run: the journal keeps the fits, and it says so
    out = tmp_path / "r2.h5"
    calls = {"n": 0}
    copy = shutil.copyfile

    def refused(src, dst, **kw):
        calls["n"] += 1
        if calls["n"] > 1:
            raise PermissionError(errno.EPERM, "Operation not permitted", dst)
        return copy(src, dst, **kw)

    monkeypatch.setattr(shutil, "copyfile", refused)
    with pytest.raises(BatchFileError, match=r"Operation not permitted\); this run's finished "
                       r"fits are kept in .*r2\.h5\.journal: make the folder writable"):
        run_batch([str(d)], request, out, workers=0, progress=False, checkpoint_s=0)
    assert not [f for f in os.listdir(tmp_path) if ".tmp-" in f]
    monkeypatch.setattr(shutil, "copyfile", copy)
    again = run_batch([str(d)], request, out, workers=0, progress=False)
    assert again.recovered >= 1 and again.fits + again.skipped + again.kept >= 1


def test_a_folder_of_hidden_files_alone_says_so(tmp_path):
    d, _ = _two_lambert_tables(tmp_path)
    hidden = tmp_path / "h"
    (hidden / ".cache").mkdir(parents=True)
    os.rename(d / "m0.binary", hidden / ".m0.binary")
    os.rename(d / "m1.binary", hidden / ".cache" / "m1.binary")
    with pytest.raises(BatchInputError, match=r"holds no measured file but .*\.m0\.binary.* "
                       r"hidden \(a name or folder starting with '\.'\)"):
        find_tables([str(hidden)])


def test_another_batchs_results_in_a_folder_are_passed_over_and_an_empty_out_is_new(
        tmp_path, capsys):
    """A folder holding another batch's results file failed it as a table on every run
    (exit 1 for ever); `touch r.h5` then a batch was refused as "not an HDF5 file"."""
    d, opts = _two_lambert_tables(tmp_path)
    request = FitRequest(("lambert",), opts)
    first = tmp_path / "first.h5"
    first.touch()
    assert run_batch([str(d)], request, first, workers=0, progress=False).fits == 2
    os.replace(first, d / "old-results.h5")
    capsys.readouterr()
    assert cli_main(["batch", str(d), "--models", "lambert", "--samples", "1024", "--starts",
                     "1", "--out", str(tmp_path / "second.h5"), "--quiet"]) == 0
    err = capsys.readouterr().err
    assert f"passed over: {d / 'old-results.h5'} (another batch's results file" in err
    # named, it is taken (and fails as a table, saying what it is)
    s = run_batch([str(d / "old-results.h5")], request, tmp_path / "third.h5", workers=0,
                  progress=False)
    assert len(s.failed_tables) == 1
    alone = tmp_path / "alone"
    alone.mkdir()
    os.replace(d / "old-results.h5", alone / "old.h5")
    with pytest.raises(BatchInputError, match=r"holds no measured file but .*old\.h5, "
                                              "another batch's results"):
        find_tables([str(alone)], passed_over=[])


def test_a_report_says_where_fits_of_other_options_stand_side_by_side(tmp_path, capsys):
    """Runs with other options resumed into one file: batch-report ranked a log-loss
    fit beside a render-loss one as the same kind of fit, unsaid."""
    d, opts = _two_lambert_tables(tmp_path)
    out = tmp_path / "r.h5"
    assert run_batch([str(d / "m0.binary")], FitRequest(("lambert",), opts), out, workers=0,
                     progress=False).ok
    assert run_batch([str(d / "m1.binary")], FitRequest.of("lambert", samples=2048, starts=1),
                     out, workers=0, progress=False).ok
    ranking = rank(out)
    assert ranking.mixed_options == {"samples": [1024, 2048]}
    assert ("Fits made with different options side by side (runs of other options resumed "
            "into this file): samples 1024, 2048") in format_ranking(ranking, str(out))
    capsys.readouterr()
    assert cli_main(["batch-report", str(out), "--json", "--no-png"]) == 0
    assert json.loads(capsys.readouterr().out)["mixed_options"] == {"samples": [1024, 2048]}


# -- what a review of the batch found (session 41) -------------------------------------


def test_a_report_of_a_file_with_no_table_yet_says_so(tmp_path, capsys):
    """A results file with no tables yet: the text gave ``nan`` for each model's mean and
    median (--json: null), and the figure a linear axis labelled "log scale", an empty
    legend box and the win counts at its edge."""
    out, png = tmp_path / "empty.h5", tmp_path / "empty.png"
    with BatchStore(out) as store:
        store.checkpoint({"models": ["lambert", "ggx"]})
    assert cli_main(["batch-report", str(out), "--png", str(png)]) == 0
    rows = capsys.readouterr().out.splitlines()[-2:]
    assert [row.split() for row in rows] == [
        [m, "0", "0", "0", "-", "-", "0", "0/0/0"] for m in ("lambert", "ggx")]
    assert png.stat().st_size > 1000
    err_axis, wins_axis = summary_figure(rank(out)).axes[:2]
    assert "log scale" not in err_axis.get_ylabel() and err_axis.get_yscale() == "linear"
    assert err_axis.get_legend() is None and wins_axis.get_legend() is None
    assert [t.get_text() for t in err_axis.texts] == [
        "no successful fit in this file yet: nothing to plot"]
    assert [t.get_text() for t in wins_axis.texts] == ["no table has a best fit yet"]
    assert wins_axis.get_xlim() == err_axis.get_xlim()


def test_the_summary_figure_keeps_its_words_inside_and_off_the_bars():
    """The right title ran off the figure ("... 1 tables wi"), the left axis's label past
    its top, the legend of wins covered a tall bar and its count, and a failed table (no
    fits) put a "not judged" entry without a dot in the left legend."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    from brdffit.batch.report import ModelSummary, Ranking, TableRanking

    poor = {"verdict": "poor"}
    tables = [TableRanking("a", "/a.binary", "ok", "", {"lambert": 0.06, "ggx": 0.02},
                           looks={"lambert": poor, "ggx": poor}),
              TableRanking("b", "/b.binary", "failed", "/b.binary: not a MERL table", {})]
    summary = [ModelSummary("ggx", 1, 0, 1, 0.02, 0.02, 0, {"poor": 1}),
               ModelSummary("lambert", 1, 0, 0, 0.06, 0.06, 0, {"poor": 1})]
    fig = summary_figure(Ranking({}, ["lambert", "ggx"], tables, summary), "r.h5")
    FigureCanvasAgg(fig).draw()
    renderer, inside = fig.canvas.get_renderer(), fig.bbox.padded(1)
    err_axis, wins_axis = fig.axes[:2]
    assert "1 table with failures" in wins_axis.get_title()
    assert [t.get_text() for t in err_axis.get_legend().get_texts()] == ["poor"]
    words = [err_axis.title, wins_axis.title, err_axis.yaxis.label, wins_axis.yaxis.label,
             wins_axis.get_legend(), fig._suptitle]
    for w in words:
        box = w.get_window_extent(renderer)
        assert inside.contains(box.x0, box.y0) and inside.contains(box.x1, box.y1), w
    assert not wins_axis.get_legend().get_window_extent(renderer).overlaps(
        wins_axis.get_window_extent(renderer))


def test_a_broken_npz_in_a_batch_fails_as_the_npz_it_is_not(tmp_path):
    """A folder's .npz that NumPy's zip reader cannot read was read as a CSV of the
    wrong name: "no column for theta_i ... (the header has garbage)", or for a zip cut
    short "a zip archive, not a text sample list" (an .npz is one)."""
    d = tmp_path / "t"
    d.mkdir()
    (d / "text.npz").write_bytes(b"garbage")
    (d / "cut.npz").write_bytes(b"PK\x03\x04garbage")
    s = run_batch([str(d)], ["lambert"], tmp_path / "r.h5", workers=0, progress=False)
    said = "not a readable .npz (NumPy's zip of arrays): "
    assert sorted((os.path.basename(p), m.split(": ", 1)[1]) for p, m in s.failed_tables) == [
        ("cut.npz", said + "a zip archive cut short or damaged (File is not a zip file)"),
        ("text.npz", said + "text, not a zip archive (nor a sample list: no column for "
                            "theta_i, phi_i, theta_o, phi_o (the header has garbage))")]
