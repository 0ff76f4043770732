"""brdffit.client.Client against a real server: the whole round trip, errors that
carry the server's message, and twenty clients at once."""

from __future__ import annotations

import io
from concurrent.futures import ThreadPoolExecutor

import httpx
import numpy as np
import pytest
from matplotlib.image import imread

from brdffit import FitResult
from brdffit.client import (
    ApiError,
    Client,
    ClientError,
    FitCancelled,
    FitFailed,
    FitJob,
    InvalidRequest,
)
from brdffit.io import merl
from brdffit.io.grid import bin_grid
from brdffit.view.kinds import KINDS
from tests.api_fixtures import (
    FAST,
    SLOW_JOB,
    TABLES,
    Server,
    scaled_table_bytes,
    table,
    table_bytes,
    write,
)

pytestmark = pytest.mark.system


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    with Server(tmp_path_factory.mktemp("client"), workers=2) as s:
        yield s
        assert '" 500 ' not in s.log() and "Traceback" not in s.log(), s.log()[-5000:]


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("tables")
    return {name: write(d / f"{name}.binary", table_bytes(name)) for name in TABLES}


@pytest.fixture
def client(server):
    with Client(server.url, timeout=60) as c:
        yield c


def test_upload_fit_wait_result_plot(client, files):
    table_id = client.upload(files["ggx"])
    assert client.upload(files["ggx"]) == table_id  # idempotent
    info = client.table(table_id)
    assert info.name == "ggx.binary" and info.summary["measured_bins"] == table("ggx").n_measured

    job = client.fit(table_id, ["ggx", "lambert"], **FAST)
    assert isinstance(job, FitJob) and job.status in ("queued", "running")
    done = client.wait(job, timeout=240)
    assert done.status == "done" and done.attempts == 1
    assert done.run_seconds > 0  # compiling included, where its worker compiled first

    best = client.result(job)
    assert isinstance(best, FitResult) and best.model == "ggx"
    truth = TABLES["ggx"][1]
    assert best.params["alpha"] == pytest.approx(truth["alpha"], rel=0.02)
    assert best.params["kd"] == pytest.approx(truth["kd"], rel=0.02)
    assert client.result(job, model="lambert").log_rmse > best.log_rmse
    assert [r.model for r in done.results] == ["ggx", "lambert"]

    for kind in KINDS:
        png = client.plot(job, kind)
        image = imread(io.BytesIO(png), format="png")
        h, w = image.shape[:2]
        assert 300 <= h <= 2200 and 500 <= w <= 2000, (kind, h, w)  # report: one tall page
        assert 10_000 < len(png) < 2_000_000
    assert client.plot(job, "spheres") == client.plot(job, "spheres")  # served from the cache
    assert client.plot(job.id, "polar", model="lambert")[:4] == b"\x89PNG"


def test_errors_carry_the_servers_message(client, files, tmp_path):
    table_id = client.upload(files["lambert"])
    with pytest.raises(ApiError) as e:
        client.fit("0" * 64, "ggx")
    assert e.value.status_code == 404 and "no table" in e.value.detail
    # the request is the library's, checked here as the server checks it: nothing sent,
    # and what is refused is a ClientError as the docs say (it was the library's own)
    with pytest.raises(InvalidRequest, match="unknown model 'torrance'") as refused:
        client.fit(table_id, "torrance")
    assert isinstance(refused.value, ClientError) and isinstance(refused.value, ValueError)
    with pytest.raises(InvalidRequest, match="starts must be an integer in 1 .. 32"):
        client.fit(table_id, "lambert", starts=0)
    with pytest.raises(InvalidRequest, match="unknown fit options"):
        client.fit(table_id, "lambert", bin_weight=[1.0])
    # what only the server knows comes back in its words: its cost limits, which an
    # estimate tells before anything is queued
    costly = {"samples": 1_000_000, "starts": 32, "max_steps": 10_000, "loss": "render"}
    cost = client.estimate(table_id, "auto", **costly)
    assert not cost.accepted and cost.seconds > cost.limits["seconds"]
    assert cost.models == ["auto"] and cost.machine_factor >= 1.0
    with pytest.raises(ApiError) as e:
        client.fit(table_id, "auto", **costly)
    assert e.value.status_code == 422 and "over the server's limits" in e.value.detail
    assert all("BRDFFIT_MAX_JOB_ESTIMATE_S" in why for why in (cost.over_limits, e.value.detail))
    assert client.estimate(table_id, "lambert", samples=4096).accepted
    with pytest.raises(InvalidRequest, match="starts must be an integer in 1 .. 32"):
        client.estimate(table_id, "lambert", starts=0)
    text = tmp_path / "notes.binary"
    text.write_text("not a table\n" * 20)
    with pytest.raises(ApiError) as e:
        client.upload(text)
    assert e.value.status_code == 422 and "notes.binary: looks like a text file" in e.value.detail
    with pytest.raises(ApiError) as e:
        client.plot("f" * 32, "slices")
    assert e.value.status_code == 404
    assert "404" in str(e.value) and "no fit job" in str(e.value)


def test_failed_fit_raises_with_its_reason(client, tmp_path):
    """A table the reader accepts but no fit can use (every measured bin below
    the horizon) fails as a job, with the fit's own explanation."""
    t = table("lambert")
    below = ~bin_grid().above_horizon.reshape(t.mask.shape)
    rgb = np.where(below, 0.1, t.rgb)
    path = write(tmp_path / "below.binary",
                 merl.to_bytes(merl.MerlTable.from_values(rgb, below, source="below")))
    job = client.wait(client.fit(client.upload(path), "lambert", **FAST), timeout=120)
    assert job.status == "failed" and "usable bins" in job.reason
    with pytest.raises(FitFailed, match="usable bins") as e:
        client.result(job)
    assert e.value.job.id == job.id
    with pytest.raises(ApiError) as e:
        client.plot(job, "slices")
    assert e.value.status_code == 409 and "failed" in e.value.detail


def test_wait_times_out_and_result_wants_a_finished_job(client, files):
    table_id = client.upload(files["lambert"])
    # Reading the table alone takes longer than this test's first two requests.
    job = client.fit(table_id, "lambert", seed=7, **FAST)
    with pytest.raises(ClientError, match="wait"):
        client.result(job)
    with pytest.raises(TimeoutError, match=job.id):
        client.wait(job, timeout=0.001)
    assert client.wait(job, timeout=240).status == "done"


def test_wait_outlasts_a_server_briefly_gone_and_polls_as_it_says(client, files,
                                                                  monkeypatch):
    """wait() gave up at the first refused connection while the server restarted (its
    jobs survive a restart); its pauses grew to 2 s whatever ``poll`` said."""
    import time

    from brdffit.client import NoAnswer, Unreachable

    table_id = client.upload(files["lambert"])
    job = client.fit(table_id, "lambert", seed=5, **FAST)
    real, calls, pauses = client.job, [], []
    sleep = time.sleep

    def flaky(ref):
        calls.append(ref)
        if len(calls) == 1:
            raise Unreachable("cannot reach the brdffit server (a restart)")
        if len(calls) == 2:
            raise NoAnswer("the connection ended before an answer")
        if len(calls) == 3:
            raise ApiError(503, "storage unavailable", "GET", "/v1/fits/x")
        return real(ref)

    monkeypatch.setattr(client, "job", flaky)
    monkeypatch.setattr(time, "sleep", lambda s: (pauses.append(s), sleep(s)))
    assert client.wait(job, timeout=240, poll=0.3).status == "done"
    assert len(calls) >= 4 and max(pauses[3:] or [0.3]) <= 0.3 + 1e-9
    # any other error is the caller's at once
    monkeypatch.setattr(client, "job", lambda ref: (_ for _ in ()).throw(
        ApiError(404, "no such fit job", "GET", "/v1/fits/x")))
    with pytest.raises(ApiError, match="404"):
        client.wait(job, timeout=240)


def test_wait_tells_on_update_each_change_of_status_and_progress(monkeypatch):
    """A long fit said nothing until it ended; ``on_update`` is told each new status
    or progress once, the last one included, and a poll that changes nothing is not
    told again."""
    import time
    from types import SimpleNamespace

    from brdffit.client import InvalidSetting

    def state(status, stage=None):
        return SimpleNamespace(id="0" * 32, status=status, finished=status == "done",
                               progress=None if stage is None else {"stage": stage})

    polls = iter([state("queued"), state("queued"), state("running", "fitting ggx (1 of 2)"),
                  state("running", "fitting ggx (1 of 2)"),
                  state("running", "fitting ggx2 (2 of 2)"), state("done")])
    told = []
    with Client("http://brdffit.test", token="",
                transport=httpx.MockTransport(lambda r: httpx.Response(500))) as c:
        monkeypatch.setattr(c, "job", lambda ref: next(polls))
        monkeypatch.setattr(time, "sleep", lambda s: None)
        done = c.wait("0" * 32, on_update=lambda j: told.append(
            (j.status, (j.progress or {}).get("stage"))))
        assert done.status == "done"
        assert told == [("queued", None), ("running", "fitting ggx (1 of 2)"),
                        ("running", "fitting ggx2 (2 of 2)"), ("done", None)]
        with pytest.raises(InvalidSetting, match="on_update must be callable"):
            c.wait("0" * 32, on_update="print")


def test_a_request_sent_without_an_answer_says_it_may_have_been_carried_out():
    """A connection dropped after POST /v1/fits was "cannot reach the server ... the
    request never reached the service": a user started the fit again, and it ran twice."""
    from brdffit.client import InvalidSetting, NoAnswer

    def dropped(request):
        raise httpx.RemoteProtocolError("Server disconnected without sending a response.",
                                        request=request)

    with Client("http://brdffit.test", token="", transport=httpx.MockTransport(dropped)) as c:
        with pytest.raises(NoAnswer, match=r"POST http://brdffit.test/v1/fits: the connection "
                                           r"ended before an answer .*may have been carried "
                                           r"out; look for the fit \(Client.fits\(\)\)"):
            c._request("POST", "/v1/fits", json={})
    assert issubclass(NoAnswer, ClientError)
    from brdffit.errors import BrdffitError

    assert issubclass(ClientError, BrdffitError)  # caught as the library's own errors
    with pytest.raises(InvalidSetting, match="the server's URL is text"):
        Client(None)
    c = Client("http://brdffit.test", token="", transport=httpx.MockTransport(dropped))
    c.close()
    with pytest.raises(ClientError, match="closed"):
        c.health()


def test_list_cancel_and_delete(client, files):
    table_id = client.upload(files["lambert"])
    # Queued behind nothing but cancelled at once, or running and stopped: either
    # way it ends cancelled, and result() says so.
    job = client.fit(table_id, SLOW_JOB["model"])
    cancelled = client.cancel(job)
    assert cancelled.status == "cancelled" and cancelled.reason, cancelled
    with pytest.raises(FitCancelled):
        client.result(cancelled)
    with pytest.raises(ApiError) as e:
        client.cancel(job)
    assert e.value.status_code == 409
    done = client.wait(client.fit(table_id, "lambert", seed=11, **FAST), timeout=240)
    listed = list(client.fits(table_id=table_id, page_size=1))  # one request per job
    assert [j.id for j in listed][:2] == [done.id, job.id]
    assert [j.id for j in client.fits(status="cancelled", table_id=table_id)] == [job.id]
    assert table_id in [t.id for t in client.tables(name="lambert")]
    with pytest.raises(ApiError) as e:
        client.delete_table(table_id)
    assert e.value.status_code == 409 and "with_fits" in e.value.detail
    client.delete_fit(job)
    with pytest.raises(ApiError) as e:
        client.job(job)
    assert e.value.status_code == 404
    client.delete_table(table_id, with_fits=True)
    assert table_id not in [t.id for t in client.tables()]


def test_a_file_that_cannot_be_read_is_said_in_one_line(tmp_path):
    """Before anything is sent: a missing file or a directory is the client's own error,
    one line (it was Python's FileNotFoundError / IsADirectoryError)."""
    from brdffit.client import UnreadableFile

    with Client("http://127.0.0.1:9") as client:  # nothing listens: nothing is sent
        for path, words in ((tmp_path / "absent.binary", "No such file"),
                            (tmp_path, "Is a directory")):
            with pytest.raises(UnreadableFile, match=f"cannot upload .*: {words}") as e:
                client.upload(path)
            assert isinstance(e.value, ClientError) and "\n" not in str(e.value)


def test_token_is_sent_and_a_401_explained():
    """The header the server checks (its own 401s: test_api.py), without a server."""
    seen = []

    def handler(request: httpx.Request) -> httpx.Response:
        seen.append(request.headers.get("authorization"))
        if request.headers.get("authorization") != "Bearer tok":
            return httpx.Response(401, json={"detail": "wrong bearer token"})
        return httpx.Response(200, json=[{"name": "ggx"}])

    with Client("http://brdffit.test", token="tok", transport=httpx.MockTransport(handler)) as c:
        assert c.models() == [{"name": "ggx"}]
    with Client("http://brdffit.test", token="nope", transport=httpx.MockTransport(handler)) as c:
        with pytest.raises(ApiError) as e:
            c.models()
    assert e.value.status_code == 401 and e.value.detail == "wrong bearer token"
    assert seen == ["Bearer tok", "Bearer nope"]


def test_non_json_errors_are_still_explained():
    transport = httpx.MockTransport(lambda r: httpx.Response(502, text="<h1>Bad Gateway</h1>"))
    with Client("http://brdffit.test", token="", transport=transport) as c:
        with pytest.raises(ApiError) as e:
            c.health()
    assert e.value.status_code == 502 and "Bad Gateway" in e.value.detail


def test_no_server_and_another_server_are_one_line_each():
    """Nothing listening, a URL that is no http one, a request that times out, and an
    HTML page from another server: one ClientError line each, naming the URL."""
    import socket

    from brdffit.client import Unreachable

    with socket.socket() as s:  # a free port on loopback, closed again: nothing listens
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    with Client(f"http://127.0.0.1:{port}", token="") as c:
        with pytest.raises(Unreachable, match=f"cannot reach the brdffit server at "
                                              f"http://127.0.0.1:{port}"):
            c.health()
    with Client("127.0.0.1:8000", token="") as c:
        with pytest.raises(Unreachable, match="not an http:// or https:// URL"):
            c.models()

    def slow(request):
        raise httpx.ReadTimeout("timed out", request=request)

    with Client("http://brdffit.test", token="", transport=httpx.MockTransport(slow)) as c:
        with pytest.raises(TimeoutError, match="GET http://brdffit.test/v1/models: no answer"):
            c.models()
    page = httpx.MockTransport(lambda r: httpx.Response(
        404, text="<!DOCTYPE HTML>\n<html>\n<body>\n<h1>Error response</h1>\n</body>\n</html>\n",
        headers={"content-type": "text/html;charset=utf-8"}))
    with Client("http://127.0.0.1:9", token="", transport=page) as c:
        with pytest.raises(ApiError) as e:
            c.models()
    assert isinstance(e.value, ClientError) and "\n" not in str(e.value)
    assert "answered in text/html, not the brdffit service's JSON" in str(e.value)


def test_an_answer_that_is_not_the_services_is_an_api_error():
    """Another server's 200 HTML page was a JSONDecodeError (and HTML bytes returned by
    plot() as a PNG), a redirect a JSONDecodeError, a body its encoding does not decode
    an httpx.DecodingError, JSON of another shape a KeyError; a token a header cannot
    carry failed at the first request (a newline as "cannot reach the server")."""
    from brdffit.client import InvalidSetting

    html = httpx.MockTransport(lambda r: httpx.Response(
        200, text="<html>welcome</html>", headers={"content-type": "text/html"}))
    moved = httpx.MockTransport(lambda r: httpx.Response(
        302, headers={"location": "https://brdffit.test/v1/models"}))
    garbled = httpx.MockTransport(lambda r: httpx.Response(
        200, content=b"not gzip", headers={"content-type": "application/json",
                                           "content-encoding": "gzip"}))
    for transport, says in ((html, "answered in text/html, not application/json"),
                            (moved, "redirected to https://brdffit.test/v1/models"),
                            (garbled, "an answer that does not decode")):
        with Client("http://brdffit.test", token="", transport=transport) as c:
            with pytest.raises(ApiError, match=says):
                c.models()
    with Client("http://brdffit.test", token="", transport=html) as c:
        with pytest.raises(ApiError, match="answered in text/html, not image/png"):
            c.plot("0" * 32, "spheres")
    # JSON of another shape (another version, another server): was a KeyError
    shaped = httpx.MockTransport(lambda r: httpx.Response(200, json={"x": 1}))
    with Client("http://brdffit.test", token="", transport=shaped) as c:
        for call in (lambda: c.table("0" * 64), lambda: c.job("0" * 32),
                     lambda: list(c.fits()), lambda: c.export("0" * 32, "gltf")):
            with pytest.raises(ApiError, match="an answer of another shape than the brdffit "
                                               "service's"):
                call()
    for token in ("tökén", "line\nbreak"):
        with pytest.raises(InvalidSetting, match="the token must be printable ASCII"):
            Client("http://brdffit.test", token=token)


def test_a_plot_or_export_is_waited_for_as_long_as_the_server_renders_it():
    """The service renders a plot or an export for up to 300 s; the client's 120 s
    read timeout ended such a request as no answer. Those two wait RENDER_WAIT_S;
    every other request keeps the client's timeout."""
    from brdffit.client import RENDER_WAIT_S

    reads = {}

    def handler(request):
        reads[request.url.path.split("/")[-2]] = request.extensions["timeout"]["read"]
        if request.url.path.endswith(".png"):
            return httpx.Response(200, content=b"\x89PNG", headers={"content-type": "image/png"})
        return httpx.Response(200, json={"status": "ok"})

    job = "0" * 32
    with Client("http://brdffit.test", token="", timeout=10,
                transport=httpx.MockTransport(handler)) as c:
        c.plot(job, "slices")
        with pytest.raises(ApiError):  # the handler's JSON is no export: asked all the same
            c.export(job, "gltf")
        c.health()
    assert RENDER_WAIT_S > 300
    assert reads == {"plots": RENDER_WAIT_S, "exports": RENDER_WAIT_S, "": 10}, reads
    with Client("http://brdffit.test", token="", timeout=None,
                transport=httpx.MockTransport(handler)) as c:
        c.plot(job, "slices")
    assert reads["plots"] is None  # no limit stays none


def test_a_url_or_timeout_the_client_cannot_use_is_its_own_error_when_made():
    """``http://[::1`` (a bracket left open) raised httpx.InvalidURL, and a timeout of
    -1 a bare ValueError at the first request: the client's own error, when it is made,
    saying what it wants. A seed from numpy (np.int64) is sent as the integer it is."""
    import math

    from brdffit.client import InvalidSetting

    with pytest.raises(InvalidSetting, match=r"'http://\[::1' is not a URL \(.*\): give the "
                                             r"server's, as http://127.0.0.1:8000"):
        Client("http://[::1", token="")
    for timeout in (-1, 0, math.nan, math.inf, True, "10", (5, -1, 5, 5), (5, 5)):
        with pytest.raises(InvalidSetting, match=r"timeout must be a number of seconds > 0 "
                                                 r"\(or None: no limit\), or httpx's "
                                                 r"\(connect, read, write, pool\) of them, got "):
            Client("http://brdffit.test", token="", timeout=timeout)
    assert issubclass(InvalidSetting, ClientError) and issubclass(InvalidSetting, ValueError)
    with pytest.raises(InvalidSetting, match="without /v1"):  # it was a bare 404 later
        Client("http://brdffit.test/v1/", token="")
    Client("http://brdffit.test", token="", timeout=None).close()  # no limit: httpx's own
    # httpx's (connect, read, write, pool), None in a part: no limit on that one
    Client("http://brdffit.test", token="", timeout=(5, None, 5, 2.5)).close()
    sent = []

    def answer(request):
        sent.append(request.read())
        return httpx.Response(422, json={"detail": "no such table"})

    with Client("http://brdffit.test", token="", transport=httpx.MockTransport(answer)) as c:
        with pytest.raises(ApiError):
            c.fit("0" * 64, "ggx", seed=np.int64(3))
    assert b'"seed": 3' in sent[0] or b'"seed":3' in sent[0], sent



def test_ids_go_into_a_path_checked_and_waits_refuse_what_they_cannot_do():
    """``delete_fit("../tables/<id>")`` deleted a table, ``job("")`` was answered by a
    redirect; ``wait(timeout=None)`` was a TypeError, ``timeout=nan`` never returned
    and ``poll=0`` polled hundreds of times a second."""
    import math

    from brdffit.client import InvalidRequest, InvalidSetting

    sent = []

    def answer(request):
        sent.append((request.method, request.url.raw_path))
        return httpx.Response(404, json={"detail": "no such job"})

    table = "ab" * 32
    with Client("http://brdffit.test", token="", transport=httpx.MockTransport(answer)) as c:
        for call, what in ((lambda: c.delete_fit(f"../tables/{table}"), "a fit job"),
                           (lambda: c.job(""), "a fit job"),
                           (lambda: c.cancel("x?y"), "a fit job"),
                           (lambda: c.wait(None), "a fit job"),
                           (lambda: c.table(table[:-1]), "a table id"),
                           (lambda: c.delete_table("../fits"), "a table id"),
                           (lambda: c.fit(table.upper(), "ggx"), "a table id")):
            with pytest.raises(InvalidRequest, match=what):
                call()
        assert sent == []  # refused before anything was sent
        for timeout, poll in ((math.nan, 0.25), (-1, 0.25), ("10", 0.25), (10, 0),
                              (10, -1), (10, math.nan), (10, None)):
            with pytest.raises(InvalidSetting, match=r"wait's (timeout|poll) must be a "
                                                     r"number of seconds > 0"):
                c.wait("0" * 32, timeout=timeout, poll=poll)
        assert sent == []
        # a kind or a target is one path segment: the server names what it has
        for call in (lambda: c.plot("0" * 32, "../../tables"),
                     lambda: c.export("0" * 32, "gltf/../x")):
            with pytest.raises(ApiError):
                call()
        assert [p for _, p in sent] == [b"/v1/fits/" + b"0" * 32 + b"/plots/..%2F..%2Ftables.png",
                                        b"/v1/fits/" + b"0" * 32 + b"/exports/gltf%2F..%2Fx"]
        with pytest.raises(ApiError, match="no such job"):  # no limit: it asks the server
            c.wait("0" * 32, timeout=None)


N_CLIENTS = 20
N_TABLES = 5


def test_twenty_concurrent_clients(server, tmp_path):
    """Twenty clients, each uploading (five distinct tables, so uploads of the
    same bytes race too) and fitting at once: every one gets its own table's answer."""
    kd = np.array(TABLES["lambert"][1]["kd"])
    scales = [0.5 + 0.25 * i for i in range(N_TABLES)]
    paths = [write(tmp_path / f"lambert-{i}.binary", scaled_table_bytes("lambert", s))
             for i, s in enumerate(scales)]

    def one(i: int):
        with Client(server.url, timeout=120) as c:
            table_id = c.upload(paths[i % N_TABLES])
            job = c.wait(c.fit(table_id, "lambert", **FAST), timeout=240)
            return table_id, job.id, c.result(job)

    with ThreadPoolExecutor(N_CLIENTS) as pool:
        futures = [pool.submit(one, i) for i in range(N_CLIENTS)]
        outcomes = [f.result(timeout=300) for f in futures]

    assert len({job_id for _, job_id, _ in outcomes}) == N_CLIENTS
    assert len({table_id for table_id, _, _ in outcomes}) == N_TABLES
    for i, (_, _, result) in enumerate(outcomes):
        assert result.model == "lambert" and result.converged
        np.testing.assert_allclose(result.params["kd"], scales[i % N_TABLES] * kd, rtol=1e-3)
