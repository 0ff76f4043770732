"""A Python client for the brdffit service (``brdffit serve``), over httpx.

    from brdffit.client import Client

    with Client("http://127.0.0.1:8000") as c:
        job = c.fit(c.upload("gold-metallic-paint.binary"), "ggx", samples=8192)
        result = c.result(c.wait(job, timeout=300))   # a brdffit.FitResult
        print(result.params, result.log_rmse)
        open("spheres.png", "wb").write(c.plot(job, "spheres"))

Every error the server reports arrives as :class:`ApiError` with the server's
message (``.detail``) and status; a fit that failed raises :class:`FitFailed`
with its reason (:class:`FitCancelled` if it was cancelled); a wait that runs out
raises ``TimeoutError``.

Before queueing, :meth:`Client.estimate` says what a fit would cost on the server
and whether it would take it. Job control: :meth:`Client.fits` and
:meth:`Client.tables` walk the server's paged listings (filtered),
:meth:`Client.cancel` stops a queued or running job, :meth:`Client.delete_fit` and
:meth:`Client.delete_table` remove finished ones.
"""

from __future__ import annotations

import dataclasses
import math
import numbers
import os
import re
import time
import urllib.parse
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from datetime import datetime

from brdffit import extras
from brdffit.errors import BrdffitError
from brdffit.export import Export  # plain data, as FitResult
from brdffit.fitting.options import DEFAULT_MODEL
from brdffit.fitting.result import FitResult  # plain data: a client process imports no JAX
from brdffit.request import FitRequest  # checked here as the server checks it; no JAX

try:
    import httpx
except ModuleNotFoundError:
    raise extras.MissingExtraError("brdffit.client", "client", ("httpx",)) from None

DEFAULT_URL = "http://127.0.0.1:8000"


def _fit_body(table_id: str, model, keywords: dict) -> dict:
    """A fit's body (``POST /v1/fits``): the request checked here, by the library the
    server runs, and sent in its one form (``FitRequest.to_dict()``)."""
    _table_id(table_id)
    if isinstance(model, FitRequest):
        if keywords:
            raise TypeError("give a FitRequest or keywords, not both")
        request = model
    else:
        try:
            request = FitRequest.of(DEFAULT_MODEL if model is None else model, **keywords)
        except BrdffitError as e:  # the library's own check, as the server makes it
            raise InvalidRequest(str(e)) from None
    return {"table_id": table_id, **request.to_dict()}


class ClientError(BrdffitError):
    """Base of what :class:`Client` raises (besides ``TimeoutError``): a
    :class:`brdffit.errors.BrdffitError`, as the library's own errors are."""


class ApiError(ClientError):
    """The server answered with an error: ``status_code`` and its ``detail``."""

    def __init__(self, status_code: int, detail: str, method: str = "", url: str = ""):
        self.status_code = status_code
        self.detail = detail
        self.method = method
        self.url = url
        super().__init__(f"{status_code} from {method} {url}: {detail}".replace("  ", " "))


class InvalidRequest(ClientError, ValueError):
    """A request the library refuses before it is sent (an unknown model, a bad option),
    with the message the server would answer with."""


class UnreadableFile(ClientError, OSError):
    """A file to upload that cannot be opened here (missing, a directory, no
    permission): said in one line, before anything is sent."""


class InvalidSetting(ClientError, ValueError):
    """A :class:`Client` made with a URL or a timeout it cannot use, or a :meth:`Client.
    wait` given a timeout or a poll interval it cannot use: said at once, not as
    httpx's or ``time.sleep``'s own error (or a wait that never ends, for a NaN)."""


class Unreachable(ClientError):
    """No brdffit server answered at the client's URL (refused, unknown host, a URL
    that is no http(s) one): the request never reached the service."""


class NoAnswer(ClientError):
    """The request was sent, and the connection ended before an answer (the server
    restarted, a proxy dropped it): it may have been carried out. A fit started so may
    be queued: look for it (``fits()``) before starting it again."""


class FitFailed(ClientError):
    """The fit job ended in ``failed``; ``reason`` is the server's explanation."""

    def __init__(self, job: FitJob):
        self.job = job
        self.reason = job.reason or "no reason given"
        super().__init__(f"fit job {job.id} {job.status}: {self.reason}")


class FitCancelled(FitFailed):
    """The fit job was cancelled (``Client.cancel``) before it finished."""


@dataclass(frozen=True)
class TableInfo:
    """An uploaded table (``GET /v1/tables/{id}``)."""

    id: str
    name: str
    size_bytes: int
    created_at: datetime
    summary: dict

    @classmethod
    def from_json(cls, d: dict) -> TableInfo:
        return cls(d["id"], d["name"], d["size_bytes"],
                   datetime.fromisoformat(d["created_at"].replace("Z", "+00:00")), d["summary"])


@dataclass(frozen=True)
class FitEstimate:
    """What a fit would cost on the server (``POST /v1/fits/estimate``, before queueing)."""

    table_id: str
    models: list[str]
    seconds: float  # the job's worker, with the server's machine_factor
    memory_mib: float  # the job's worker's peak
    machine_factor: float  # how much slower the server's recent jobs ran (1: not slower)
    accepted: bool  # whether the server takes it now, within its limits
    over_limits: str | None  # why not: by how much, and what to ask for instead
    limits: dict  # {"seconds": ..., "memory_mib": ...}
    detail: str  # how the figures came about

    @classmethod
    def from_json(cls, d: dict) -> FitEstimate:
        return cls(**{f.name: d[f.name] for f in dataclasses.fields(cls)})


@dataclass(frozen=True)
class FitJob:
    """A fit job as the server last described it (``GET /v1/fits/{id}``)."""

    id: str
    status: str  # queued, running, done, failed, cancelled
    table_id: str
    models: list[str]
    request: FitRequest  # as it was posted
    attempts: int
    reason: str | None
    note: str | None
    result: FitResult | None  # the best fit, once done
    results: list[FitResult]  # every model's fit, once done
    #: While running: ``{"stage": "fitting ggx (2 of 3)", "fraction": 0.33}``
    #: (the fraction counts finished models); else None.
    progress: dict | None = None
    #: Seconds the server's worker spent on it, once done (None where it compiled first).
    run_seconds: float | None = None

    @property
    def finished(self) -> bool:
        return self.status in ("done", "failed", "cancelled")

    @property
    def selection(self) -> dict | None:
        """For a ``model="auto"`` job once done: the ranking, the choice and its reason
        (``brdffit.selection.Selection.summary()``); else None."""
        return self.result.selection if self.result else None

    @classmethod
    def from_json(cls, d: dict) -> FitJob:
        return cls(
            id=d["id"], status=d["status"], table_id=d["table_id"], models=d["models"],
            request=FitRequest.from_dict(d["request"]), attempts=d["attempts"],
            reason=d.get("reason"),
            note=d.get("note"),
            result=FitResult.from_dict(d["result"]) if d.get("result") else None,
            results=[FitResult.from_dict(r) for r in d.get("results") or []],
            progress=d.get("progress"), run_seconds=d.get("run_seconds"),
        )


JobRef = FitJob | str


def _check_timeout(timeout) -> None:
    """Refuses a timeout in seconds that is not > 0 and finite (httpx took -1 and then
    raised "Timeout value out of range" at the first request). None (wait forever) and
    an ``httpx.Timeout`` are httpx's own, and so is its 4-tuple, whose parts are checked
    as one timeout each."""
    if timeout is None or isinstance(timeout, httpx.Timeout):
        return
    # httpx's own (connect, read, write, pool) tuple: each a timeout of its own
    parts = timeout if isinstance(timeout, tuple) and len(timeout) == 4 else (timeout,)
    for part in parts:
        if part is not None and (isinstance(part, bool) or not isinstance(part, numbers.Real)
                                 or not math.isfinite(part) or part <= 0):
            raise InvalidSetting(f"timeout must be a number of seconds > 0 (or None: no "
                                 f"limit), or httpx's (connect, read, write, pool) of them, "
                                 f"got {timeout!r}")


#: The ids the service gives (``api/routes``): a job's, a table's (its file's sha256).
JOB_ID = re.compile(r"[0-9a-f]{32}")
TABLE_ID = re.compile(r"[0-9a-f]{64}")


def _job_id(job: JobRef) -> str:
    """A job's id, checked: it goes into a URL's path, where "../tables/<id>" made
    ``delete_fit`` delete a table, and "" was answered by a redirect."""
    job_id = job.id if isinstance(job, FitJob) else job
    if not (isinstance(job_id, str) and JOB_ID.fullmatch(job_id)):
        raise InvalidRequest(f"a fit job is a FitJob or its id, the 32 hex digits POST "
                             f"/v1/fits gave (FitJob.id), not {job_id!r}")
    return job_id


def _table_id(table_id: str) -> str:
    """A table's id, checked as :func:`_job_id` checks a job's."""
    if not (isinstance(table_id, str) and TABLE_ID.fullmatch(table_id)):
        raise InvalidRequest(f"a table id is the 64 hex digits upload() gave (the file's "
                             f"sha256), not {table_id!r}")
    return table_id


def _segment(name: str) -> str:
    """A name (a plot's kind, an export's target) as one URL path segment: the server
    names what it has; a "/" or "?" in it reaches no other route."""
    return urllib.parse.quote(str(name), safe="")


def _check_wait(timeout, poll) -> None:
    """:meth:`Client.wait`'s timeout (seconds > 0, or None: no limit) and poll interval
    (seconds > 0): a NaN timeout never ran out, and a poll of 0 sent hundreds of
    requests a second."""
    for name, value, none in (("timeout", timeout, True), ("poll", poll, False)):
        if value is None and none:
            continue
        if (isinstance(value, bool) or not isinstance(value, numbers.Real)
                or not math.isfinite(value) or value <= 0):
            raise InvalidSetting(f"wait's {name} must be a number of seconds > 0"
                                 f"{' (or None: no limit)' if none else ''}, got {value!r}")


#: The longest a plot or an export may take to come back (s): the service renders one
#: in a worker for at most 300 s (its PLOT_LIMIT_S and EXPORT_LIMIT_S), then answers 503;
#: a client that gave up at its own 120 s read a slow render as no answer at all.
RENDER_WAIT_S = 330.0


class Client:
    """Talk to one brdffit server. ``token``: its ``BRDFFIT_API_TOKEN``, if any
    (default: the ``BRDFFIT_API_TOKEN`` environment variable)."""

    def __init__(self, base_url: str = DEFAULT_URL, *, token: str | None = None,
                 timeout: float = 120.0, transport: httpx.BaseTransport | None = None):
        token = token if token is not None else os.environ.get("BRDFFIT_API_TOKEN") or None
        if token and not (token.isascii() and token.isprintable()):
            # a header holds ASCII alone: said here, not as httpx's error at the first
            # request (a UnicodeEncodeError, or "cannot reach the server" for a newline)
            raise InvalidSetting("the token must be printable ASCII text (the service's "
                                 "BRDFFIT_API_TOKEN, as it was set)")
        headers = {"Authorization": f"Bearer {token}"} if token else {}
        _check_timeout(timeout)
        if not isinstance(base_url, str):
            raise InvalidSetting(f"the server's URL is text, as {DEFAULT_URL}; got "
                                 f"{type(base_url).__name__}")
        if base_url.rstrip("/").endswith("/v1"):  # every path is /v1/...: /v1/v1/fits, a 404
            raise InvalidSetting(f"{base_url!r}: give the server's own URL, without /v1 "
                                 f"(as {DEFAULT_URL}); the client adds the API's paths")
        try:
            self._http = httpx.Client(base_url=base_url.rstrip("/"), headers=headers,
                                      timeout=timeout, transport=transport)
        except httpx.InvalidURL as e:  # "http://[::1": a bracket or a port left open
            raise InvalidSetting(f"{base_url!r} is not a URL ({e}): give the server's, as "
                                 f"{DEFAULT_URL}") from None

    def __enter__(self) -> Client:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        self._http.close()

    # -- plumbing ---------------------------------------------------------------------

    def _render_timeout(self) -> httpx.Timeout:
        """The client's timeout, its read part at least :data:`RENDER_WAIT_S` (a plot or
        an export renders on the server first)."""
        t = self._http.timeout
        read = None if t.read is None else max(t.read, RENDER_WAIT_S)
        return httpx.Timeout(connect=t.connect, read=read, write=t.write, pool=t.pool)

    def _request(self, method: str, url: str, expect: str | None = "application/json",
                 **kw) -> httpx.Response:
        """The service's answer to ``method url``, of media type ``expect`` (None: any,
        a DELETE's empty one); what is not the service's answer is an :class:`ApiError`
        (another server's HTML page, a redirect: they were a ``JSONDecodeError``, or HTML
        returned by :meth:`plot` as if it were a PNG)."""
        base = str(self._http.base_url).rstrip("/")
        try:
            response = self._http.request(method, url, **kw)
        except httpx.TimeoutException as e:
            sent = "" if isinstance(e, httpx.ConnectTimeout | httpx.PoolTimeout) else (
                "; the request may have been carried out"
                + ("; look for the fit (Client.fits()) before starting it again"
                   if method == "POST" and url == "/v1/fits" else ""))
            raise TimeoutError(f"{method} {base}{url}: no answer within the client's "
                               f"timeout ({type(e).__name__}){sent}") from None
        except httpx.UnsupportedProtocol:
            raise Unreachable(f"{base}: not an http:// or https:// URL") from None
        except (httpx.RemoteProtocolError, httpx.ReadError, httpx.WriteError) as e:
            # sent, or partly: "never reached the service" made a user start a queued
            # fit again, and it ran twice
            raise NoAnswer(f"{method} {base}{url}: the connection ended before an answer "
                           f"({' '.join(str(e).split()) or type(e).__name__}); the request "
                           "may have been carried out"
                           + ("; look for the fit (Client.fits()) before starting it again"
                              if method == "POST" and url == "/v1/fits" else "")) from None
        except RuntimeError as e:  # httpx's, on a closed client
            raise ClientError(f"{method} {base}{url}: {e}") from None
        except httpx.TransportError as e:
            raise Unreachable(f"cannot reach the brdffit server at {base} "
                              f"({' '.join(str(e).split()) or type(e).__name__})") from None
        except httpx.DecodingError as e:  # a body its Content-Encoding does not decode
            raise ApiError(0, f"an answer that does not decode ({e}): is {base} a brdffit "
                              "server?", method, f"{base}{url}") from None
        if response.is_error:
            raise ApiError(response.status_code, _detail(response), method,
                           str(response.request.url))
        if response.is_redirect:
            raise ApiError(response.status_code, f"redirected to "
                           f"{response.headers.get('location', 'nowhere')}: give the client "
                           "the server's own URL", method, str(response.request.url))
        media = response.headers.get("content-type", "").split(";")[0].strip().lower()
        if expect is not None and media != expect:
            raise ApiError(response.status_code, f"answered in {media or 'no content type'}, "
                           f"not {expect}: is {base} a brdffit server?", method,
                           str(response.request.url))
        return response

    def _json(self, method: str, url: str, make=None, **kw):
        """The service's JSON answer to ``method url``, made into what ``make`` makes of
        it; JSON of another shape (another server, another version: a KeyError or a
        TypeError deep in a constructor) is an :class:`ApiError` saying so."""
        response = self._request(method, url, **kw)
        try:
            body = response.json()
            return body if make is None else make(body)
        except (KeyError, IndexError, TypeError, ValueError, AttributeError) as e:
            raise ApiError(response.status_code, f"an answer of another shape than the brdffit "
                           f"service's ({type(e).__name__}: {e}): is {self._http.base_url} "
                           "a brdffit server of this version?", method,
                           str(response.request.url)) from None

    # -- the service ------------------------------------------------------------------

    def health(self) -> dict:
        return self._json("GET", "/healthz")

    def models(self) -> list[dict]:
        """The models the server fits, with their parameters (``GET /v1/models``)."""
        return self._json("GET", "/v1/models")

    def upload(self, path: str | os.PathLike, sheet: str | None = None) -> str:
        """Upload a measured file (a MERL ``.binary`` table, or samples: docs/measurements.md);
        returns its table id (its sha256).

        Streams the file; the same bytes uploaded twice give the same id. ``sheet``: an
        Excel workbook's sheet of samples to store (default: its first), refused for any
        other file; each sheet of a workbook gets an id of its own.
        """
        return self.upload_table(path, sheet).id

    def upload_table(self, path: str | os.PathLike, sheet: str | None = None) -> TableInfo:
        """As :meth:`upload`, returning the table's summary too."""
        params = {"name": os.path.basename(os.fspath(path))}
        if sheet is not None:
            params["sheet"] = sheet
        try:
            f = open(path, "rb")  # noqa: SIM115 - closed below; httpx streams it in chunks
        except OSError as e:
            raise UnreadableFile(f"cannot upload {os.fspath(path)!r}: "
                                 f"{e.strerror or e}") from None
        with f:
            return self._json(
                "POST", "/v1/tables", TableInfo.from_json, content=f, params=params,
                headers={"Content-Type": "application/octet-stream"},
            )

    def table(self, table_id: str) -> TableInfo:
        return self._json("GET", f"/v1/tables/{_table_id(table_id)}", TableInfo.from_json)

    def fit(self, table_id: str, model: str | list[str] | FitRequest | None = None,
            **keywords) -> FitJob:
        """Queue a fit; returns at once: see :meth:`wait`.

        ``model``: a name, a list of names, ``"auto"`` (the cheapest good enough is
        chosen, ``brdffit.selection``), or a whole :class:`~brdffit.request.FitRequest`.
        ``keywords`` are ``FitRequest.of``'s: the fit's options (``samples``,
        ``starts``, ``loss``, ``physical``, ...), ``scene`` (a ``Scene`` or a scene's
        JSON object, docs/selection.md) and, with auto, the rule's (``tolerance``,
        ``budget``, ``candidates``, ``mono_ks``). The request is checked here, by the
        library the server runs, and sent in its one form (``FitRequest.to_dict()``)."""
        return self._json("POST", "/v1/fits", FitJob.from_json,
                          json=_fit_body(table_id, model, keywords))

    def estimate(self, table_id: str, model: str | list[str] | FitRequest | None = None,
                 **keywords) -> FitEstimate:
        """What :meth:`fit` with the same arguments would cost on the server, and whether
        it would take it (``accepted``; ``over_limits`` says why not); nothing is
        queued."""
        return self._json("POST", "/v1/fits/estimate", FitEstimate.from_json,
                          json=_fit_body(table_id, model, keywords))

    def job(self, job: JobRef) -> FitJob:
        """The job's current state."""
        return self._json("GET", f"/v1/fits/{_job_id(job)}", FitJob.from_json)

    def wait(self, job: JobRef, timeout: float | None = 600.0, *,
             poll: float = 0.25, on_update: Callable[[FitJob], None] | None = None) -> FitJob:
        """Poll until the job is done or failed; returns it either way.

        Raises ``TimeoutError`` after ``timeout`` seconds (None: no limit); ``poll``:
        the longest pause between two polls, in seconds (the first ones are quicker).
        A server that restarts or is briefly unavailable meanwhile (refused, no answer,
        503) is asked again until the deadline: its jobs survive a restart.
        ``on_update(job)`` is called with the job each time its status or its
        ``progress`` changes (the first poll's included): a long ``auto`` fit says
        which model it is fitting, e.g.
        ``on_update=lambda j: print(j.status, (j.progress or {}).get("stage", ""))``.
        """
        _check_wait(timeout, poll)
        if on_update is not None and not callable(on_update):
            raise InvalidSetting(f"on_update must be callable (it is called with the job), "
                                 f"got {type(on_update).__name__}")
        deadline = math.inf if timeout is None else time.monotonic() + timeout
        delay = min(poll, 0.1)
        said = None  # what on_update was last told: (status, progress)
        while True:
            try:
                current = self.job(job)
            except (Unreachable, NoAnswer, TimeoutError, ApiError) as e:
                if isinstance(e, ApiError) and e.status_code not in (502, 503, 504):
                    raise
                if time.monotonic() >= deadline:
                    raise TimeoutError(f"fit job {_job_id(job)}: the server did not answer "
                                       f"before the wait's {timeout:g} s were up ({e})") from None
                time.sleep(min(max(poll, 0.5), max(deadline - time.monotonic(), 0.0)))
                continue
            if on_update is not None and (current.status, current.progress) != said:
                said = (current.status, current.progress)
                on_update(current)
            if current.finished:
                return current
            left = deadline - time.monotonic()
            if left <= 0:
                raise TimeoutError(f"fit job {current.id} still {current.status} "
                                   f"after {timeout:g} s")
            time.sleep(min(delay, left))
            delay = min(delay * 1.5, poll)  # quick at first, then every poll seconds

    def result(self, job: JobRef, model: str | None = None) -> FitResult:
        """The fit of a finished job: the best one, or ``model``'s.

        Raises :class:`FitFailed` if the job failed (:class:`FitCancelled` if it was
        cancelled), :class:`ClientError` if it is not finished yet (call :meth:`wait`).
        """
        current = job if isinstance(job, FitJob) and job.finished else self.job(job)
        if current.status == "cancelled":
            raise FitCancelled(current)
        if current.status == "failed":
            raise FitFailed(current)
        if current.status != "done":
            raise ClientError(f"fit job {current.id} is {current.status}; wait() for it first")
        if model is None:
            return current.result
        for r in current.results:
            if r.model == model:
                return r
        raise ClientError(f"fit job {current.id} has no {model!r} fit; it has "
                          f"{[r.model for r in current.results]}")

    # -- job control --------------------------------------------------------------------

    def _pages(self, url: str, params: dict, page_size: int, make) -> Iterator:
        params = {k: v for k, v in params.items() if v is not None} | {"limit": page_size}
        while True:
            items, cursor = self._json("GET", url, lambda page: (
                [make(d) for d in page["items"]], page["next_cursor"]), params=params)
            yield from items
            if cursor is None:
                return
            params["cursor"] = cursor

    def fits(self, *, status: str | None = None, table_id: str | None = None,
             model: str | None = None, page_size: int = 200) -> Iterator[FitJob]:
        """Every fit job the server has, newest first (``GET /v1/fits``, fetched
        ``page_size`` at a time as the iteration goes), filtered by ``status``
        (queued, running, done, failed, cancelled), ``table_id`` and ``model``."""
        params = {"status": status, "table_id": table_id, "model": model}
        return self._pages("/v1/fits", params, page_size, FitJob.from_json)

    def tables(self, *, name: str | None = None, page_size: int = 200) -> Iterator[TableInfo]:
        """Every uploaded table, newest first; ``name``: those whose name contains it."""
        return self._pages("/v1/tables", {"name": name}, page_size, TableInfo.from_json)

    def cancel(self, job: JobRef) -> FitJob:
        """Cancel a queued or running job; returns it (``cancelled`` once its worker
        is stopped, within a second or two; still ``running`` where the answer came
        first: :meth:`wait` for it). A job that finished first, before or while it was
        asked: ApiError 409."""
        return self._json("POST", f"/v1/fits/{_job_id(job)}/cancel", FitJob.from_json)

    def delete_fit(self, job: JobRef) -> None:
        """Delete a finished job with its results and plots (a queued or running one:
        ApiError 409, cancel it first)."""
        self._request("DELETE", f"/v1/fits/{_job_id(job)}", expect=None)

    def delete_table(self, table_id: str, *, with_fits: bool = False) -> None:
        """Delete a table; ``with_fits``: its finished fit jobs too (without it, a
        table that has fit jobs is an ApiError 409)."""
        self._request("DELETE", f"/v1/tables/{_table_id(table_id)}", expect=None,
                      params={"with_fits": "true"} if with_fits else None)

    def plot(self, job: JobRef, kind: str, model: str | None = None,
             exposure_ev: float = 0.0) -> bytes:
        """A plot of a finished fit as PNG bytes: ``slices``, ``error_map``,
        ``spheres``, ``polar`` or ``report`` (see ``brdffit.view.plots``), and for a
        sample list's fit ``samples`` (``brdffit.view.sample_plot``), for auto's
        chosen fit ``ranking`` (every candidate, and why the chosen one);
        ``exposure_ev`` (stops, multiples of 0.25) brightens the sphere renders of
        ``spheres`` and ``report``."""
        params = {"model": model} if model else {}
        if exposure_ev:
            params["exposure_ev"] = exposure_ev
        return self._request("GET", f"/v1/fits/{_job_id(job)}/plots/{_segment(kind)}.png",
                             expect="image/png", params=params,
                             timeout=self._render_timeout()).content

    def export(self, job: JobRef, target: str, model: str | None = None,
               target_model: str | None = None, viewer: str = "spec") -> Export:
        """A finished fit as a renderer's material: ``mitsuba``, ``gltf`` or
        ``materialx`` (``brdffit.export``; its files in ``Export.files``), as
        ``target_model`` (one of the renderer's models; default its first); ``viewer``
        (glTF): ``spec``, ``threejs`` or ``blender``, whose shading the factors are
        fitted for."""
        params = {k: v for k, v in (("model", model), ("target_model", target_model),
                                    ("viewer", None if viewer == "spec" else viewer)) if v}
        params = params or None
        return self._json("GET", f"/v1/fits/{_job_id(job)}/exports/{_segment(target)}",
                          Export.from_dict, params=params, timeout=self._render_timeout())


def _detail(response: httpx.Response) -> str:
    try:
        body = response.json()
    except ValueError:
        # not the service's JSON: another server on that port (an HTML error page)
        kind = response.headers.get("content-type", "no content type").split(";")[0]
        return (f"{response.reason_phrase or 'error'}, answered in {kind}, not the brdffit "
                "service's JSON: is this URL a brdffit server?")
    if isinstance(body, dict) and isinstance(body.get("detail"), str):
        return body["detail"]
    return str(body)[:500]
