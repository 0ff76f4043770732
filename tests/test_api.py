"""The REST API against a real server on loopback: uploads, bad input, tokens,
restarts, and a bounded schemathesis run. (The client's view: test_client.py.)"""

from __future__ import annotations

import json
import os
import re
import signal
import socket
import subprocess
import sys
from pathlib import Path

import httpx
import numpy as np
import pytest

from api.store import Store
from brdffit import models
from brdffit.io import merl
from brdffit.request import FitRequest
from tests.api_fixtures import FAST, Server, free_port, header, table, table_bytes, wait_status

pytestmark = pytest.mark.system

#: Small enough to test with a body a bit over it, big enough for one table.
CAP = 40_000_000


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    with Server(tmp_path_factory.mktemp("api"), workers=1,
                env={"BRDFFIT_MAX_UPLOAD_BYTES": str(CAP)}) as s:
        yield s
        # After everything this module threw at it: still serving, and no 5xx.
        assert httpx.get(f"{s.url}/healthz", timeout=10).json()["status"] == "ok"
        assert '" 500 ' not in s.log() and "Traceback" not in s.log(), s.log()[-5000:]


@pytest.fixture(scope="module")
def http(server):
    with httpx.Client(base_url=server.url, timeout=120) as c:
        yield c


@pytest.fixture(scope="module")
def table_id(http):
    r = http.post("/v1/tables", content=table_bytes("ggx"), params={"name": "ggx.binary"},
                  headers={"Content-Type": "application/octet-stream"})
    assert r.status_code in (200, 201), r.text
    return r.json()["id"]


#: A stored job's request (``FitRequest.to_dict()``'s form).
LAMBERT = {"schema": "brdffit.request/1", "models": ["lambert"], "options": {}}

def assert_error(r: httpx.Response, status: int, *words: str) -> None:
    assert r.status_code == status, (r.status_code, r.text)
    assert r.headers["content-type"].startswith("application/json")
    detail = r.json()["detail"]
    assert isinstance(detail, str) and detail
    for w in words:
        assert w.lower() in detail.lower(), detail


# -- basics ---------------------------------------------------------------------------


def test_health_models_and_openapi(http):
    assert http.get("/healthz").json()["status"] == "ok"
    names = [m["name"] for m in http.get("/v1/models").json()]
    assert {"lambert", "ggx", "beckmann"} <= set(names)
    doc = http.get("/openapi.json").json()
    for path in ("/v1/tables", "/v1/tables/{table_id}", "/v1/fits", "/v1/fits/{job_id}",
                 "/v1/fits/{job_id}/plots/{kind}.png", "/v1/models", "/healthz"):
        assert path in doc["paths"], path
    page = http.get("/docs").text
    assert "swagger" in page.lower()
    # Offline: every script, stylesheet and icon the page loads is served here.
    urls = re.findall(r'(?:src|href)="([^"]+)"', page)
    assert urls and all(u.startswith("/docs/assets/") for u in urls), urls
    assert "http://" not in page and "https://" not in page
    for url in urls:
        r = http.get(url)
        assert r.status_code == 200 and len(r.content) > 500, url
    assert "SwaggerUIBundle" in http.get("/docs/assets/swagger-ui-bundle.js").text
    assert http.get("/docs/assets/..%2Fmain.py").status_code == 404


def test_upload_is_content_addressed_and_idempotent(http, table_id):
    data = table_bytes("ggx")
    import hashlib

    assert table_id == hashlib.sha256(data).hexdigest()
    again = http.post("/v1/tables", content=data,
                      headers={"Content-Type": "application/octet-stream"})
    assert again.status_code == 200 and again.json()["id"] == table_id
    multipart = http.post("/v1/tables", files={"file": ("again.binary", data)})
    assert multipart.status_code == 200 and multipart.json()["id"] == table_id
    info = http.get(f"/v1/tables/{table_id}").json()
    t = table("ggx")
    assert info["name"] == "ggx.binary" and info["size_bytes"] == len(data)
    assert info["summary"]["measured_bins"] == t.n_measured
    assert info["summary"]["max"] == pytest.approx(t.summary()["max"])


def test_the_same_bytes_uploaded_again_put_back_a_lost_file(server, http):
    """A stored table file gone (deleted by hand, a lost disk): its row answered, every
    fit failed "cannot read", and uploading the bytes again changed nothing."""
    import struct

    data = bytearray(table_bytes("ggx"))
    data[-8:] = struct.pack("<d", 0.123456789)  # bytes of its own: no other test's table
    first = http.post("/v1/tables", content=bytes(data), params={"name": "lost.binary"},
                      headers={"Content-Type": "application/octet-stream"})
    assert first.status_code == 201, first.text
    stored = Store(server.data_dir).table_path(first.json()["id"])
    stored.unlink()
    again = http.post("/v1/tables", content=bytes(data), params={"name": "lost.binary"},
                      headers={"Content-Type": "application/octet-stream"})
    assert again.status_code == 200 and again.json()["id"] == first.json()["id"]
    assert stored.read_bytes() == bytes(data)


# -- malformed tables (every case of the core issue) -------------------------------------

GOOD_HEADER = header((90, 90, 180))


def _body():
    return table_bytes("ggx")[12:]


MALFORMED = {
    "empty": (lambda: b"", "empty"),
    "header only": (lambda: GOOD_HEADER, "truncated"),
    "short": (lambda: b"\x01\x02\x03", "shorter than the 12-byte header"),
    "truncated": (lambda: GOOD_HEADER + _body()[:-800], "truncated"),
    "trailing bytes": (lambda: GOOD_HEADER + _body() + b"\0" * 16, "trailing"),
    "text file": (lambda: b"theta_h theta_d phi_d value\n0 0 0 0.5\n" * 50, "text"),
    "wrong dims": (lambda: header((90, 90, 90)) + _body(), "not the MERL grid"),
    "negative dims": (lambda: header((-90, 90, 180)) + _body(), "not positive"),
    "absurd dims": (lambda: header((2**30, 2**30, 2**30)) + b"\0" * 64, "not the MERL grid"),
    "no measured bin": (lambda: GOOD_HEADER + np.full(3 * 90 * 90 * 180, -1.0).tobytes(),
                        "no measured bin"),
    # Absurd values (docs/fitting.md): beyond the physical bounds, refused at upload.
    "a bin at 1e300": (lambda: GOOD_HEADER + _with_raw(1e300, one_bin=True), "1 bin above 1e+12"),
    "every bin 1e300": (lambda: GOOD_HEADER + _with_raw(1e300), "bins above 1e+12"),
    "every bin denormal": (lambda: GOOD_HEADER + _with_raw(5e-324), "blank table"),
    "every bin zero": (lambda: GOOD_HEADER + _with_raw(0.0), "blank table"),
}


N_BINS = 90 * 90 * 180


def _with_raw(value: float, one_bin: bool = False, rest: float | None = None) -> bytes:
    """The ggx table's body with one measured bin (its three channels), or every
    one, set to ``value``; ``rest`` replaces the other measured values."""
    raw = np.frombuffer(_body(), dtype="<f8").copy()
    measured = raw >= 0
    if rest is not None:
        raw[measured] = rest
    if one_bin:
        b = np.flatnonzero(measured[:N_BINS])[N_BINS // 4]
        raw[[b, b + N_BINS, b + 2 * N_BINS]] = value
    else:
        raw[measured] = value
    return raw.tobytes()


@pytest.mark.parametrize("case", list(MALFORMED))
def test_malformed_tables_are_422_with_a_reason(http, case):
    make, words = MALFORMED[case]
    r = http.post("/v1/tables", content=make(), params={"name": f"{case}.binary"},
                  headers={"Content-Type": "application/octet-stream"})
    assert_error(r, 422, words, f"{case}.binary")


def test_malformed_multipart_upload(http):
    r = http.post("/v1/tables", files={"file": ("bad.binary", b"this is a text file\n" * 9)})
    assert_error(r, 422, "bad.binary", "text")
    r = http.post("/v1/tables", files={"other": ("x.binary", b"1234")})
    assert_error(r, 422, "'file' field")
    # curl -F "file=<t.csv" (no @): the field is there, as text; it read "needs a 'file' field"
    r = http.post("/v1/tables", content=b'--xyz\r\nContent-Disposition: form-data; name="file"'
                  b"\r\n\r\ntheta_i_deg,phi_i_deg\r\n--xyz--\r\n",
                  headers={"Content-Type": "multipart/form-data; boundary=xyz"})
    assert_error(r, 422, "'file' field came as text, not as a file", "curl -F file=@PATH")
    r = http.post("/v1/tables", content=b"--xyz\r\ngarbage",
                  headers={"Content-Type": "multipart/form-data; boundary=xyz"})
    assert_error(r, 400, "malformed multipart")
    whole = (b'--xyz\r\nContent-Disposition: form-data; name="file"; filename="t.binary"\r\n'
             b"\r\n" + table_bytes("ggx") + b"\r\n--xyz--\r\n")
    for cut in (len(whole) - 5, 200, 60):  # a body cut short: no part is complete
        r = http.post("/v1/tables", content=whole[:cut],
                      headers={"Content-Type": "multipart/form-data; boundary=xyz"})
        assert_error(r, 400, "malformed multipart", "cut short")
    r = http.post("/v1/tables", content=b"abc", headers={"Content-Type": "multipart/form-data"})
    assert_error(r, 400, "boundary")


def test_nonfinite_values_are_masked_not_refused(http):
    raw = np.frombuffer(table_bytes("ggx")[12:], dtype="<f8").copy()
    measured = np.flatnonzero(raw >= 0)
    raw[measured[:7]] = np.nan
    raw[measured[7:10]] = np.inf
    r = http.post("/v1/tables", content=GOOD_HEADER + raw.tobytes(),
                  headers={"Content-Type": "application/octet-stream"})
    assert r.status_code == 201, r.text
    summary = r.json()["summary"]
    assert summary["nonfinite_bins"] == 10
    assert all(np.isfinite(summary["max"]))


def test_wrong_content_type_is_415(http):
    for ctype in ("application/json", "text/plain", "application/x-www-form-urlencoded"):
        r = http.post("/v1/tables", content=table_bytes("ggx"), headers={"Content-Type": ctype})
        assert_error(r, 415, "application/octet-stream")


def test_oversized_body_is_413(http):
    """A body over the cap, streamed without a length: read up to a bounded
    excess, then refused with a message naming the cap."""
    def chunks():
        piece = b"\0" * (1 << 20)
        for _ in range(CAP // len(piece) + 2):
            yield piece

    r = http.post("/v1/tables", content=chunks(),
                  headers={"Content-Type": "application/octet-stream"})
    assert_error(r, 413, "BRDFFIT_MAX_UPLOAD_BYTES", f"{CAP:,}")


def test_a_compressed_sample_list_is_weighed_as_it_is_stored(http, tmp_path):
    """A gzip-compressed HDF5 list of one value repeated is a few KB, and is stored as
    brdffit's HDF5 (float64, uncompressed): a 597 KB body was kept as 224 MB, past the
    cap. The cap holds for what is stored: 413, weighed from the datasets' declared
    shapes (before a number is read), saying how many samples fit."""
    import h5py

    n = CAP // 56 + 1  # 7 float64 a sample: one over the cap
    bomb = tmp_path / "bomb.h5"
    with h5py.File(bomb, "w") as f:
        for name in ("theta_i", "phi_i", "theta_o", "phi_o"):
            f.create_dataset(name, data=np.full(n, 0.5), compression="gzip",
                             chunks=(2**16,)).attrs["units"] = "radians"
        f.create_dataset("rgb", data=np.full((n, 3), 0.3), compression="gzip",
                         chunks=(2**16, 3))
    body = bomb.read_bytes()
    assert len(body) < CAP // 100
    r = http.post("/v1/tables", content=body, params={"name": "bomb.h5"},
                  headers={"Content-Type": "application/octet-stream"})
    assert_error(r, 413, f"bomb.h5: {n:,} samples are stored as {56 * n:,} bytes",
                 f"over the server's cap of {CAP:,} bytes (BRDFFIT_MAX_UPLOAD_BYTES)",
                 f"upload at most {CAP // 56:,} samples")
    # MATLAB's default .mat (version 5, -v7 compressed): weighed from its variables'
    # headers as well
    from scipy import io

    io.savemat(tmp_path / "bomb.mat", {**{f"{a}_rad": np.full((n, 1), 0.5) for a in (
        "theta_i", "phi_i", "theta_o", "phi_o")}, "rgb": np.full((n, 3), 0.3)},
               do_compression=True)
    body = (tmp_path / "bomb.mat").read_bytes()
    assert len(body) < CAP // 100
    r = http.post("/v1/tables", content=body, params={"name": "bomb.mat"},
                  headers={"Content-Type": "application/octet-stream"})
    assert_error(r, 413, f"bomb.mat: {n:,} samples are stored as {56 * n:,} bytes")
    # and NumPy's compressed archive, from its arrays' headers
    np.savez_compressed(tmp_path / "bomb.npz", rgb=np.full((n, 3), 0.3), **{
        f"{a}_rad": np.full(n, 0.5) for a in ("theta_i", "phi_i", "theta_o", "phi_o")})
    body = (tmp_path / "bomb.npz").read_bytes()
    assert len(body) < CAP // 100
    r = http.post("/v1/tables", content=body, params={"name": "bomb.npz"},
                  headers={"Content-Type": "application/octet-stream"})
    assert_error(r, 413, f"bomb.npz: {n:,} samples are stored as {56 * n:,} bytes")


def test_a_sample_list_named_with_a_nul_is_stored_under_a_name_it_can_hold(http):
    """A NUL in a sample list's name was a 500 (its HDF5 attributes cannot hold one):
    replaced, as an unpaired surrogate in ?name= is. A physical fit of it is a 422."""
    rows = "\n".join(f"{10 + k % 70},0,{5 + k % 80},{k * 7 % 360},0.2,0.1,0.05"
                      for k in range(200))
    body = f"theta_i_deg,phi_i_deg,theta_o_deg,phi_o_deg,r,g,b\n{rows}\n".encode()
    r = http.post("/v1/tables", content=body, params={"name": "a\x00b.csv"},
                  headers={"Content-Type": "application/octet-stream"})
    assert r.status_code in (200, 201), r.text
    assert r.json()["name"] == "a\ufffdb.csv"
    assert r.json()["size_bytes"] == len(body)  # the upload's, not the stored HDF5's
    # and the physical bounds, which a sample list has not yet, are refused before a job
    # is queued (it was accepted, then failed)
    r = http.post("/v1/fits", json={"table_id": r.json()["id"], "models": "lambert",
                                    "options": {"physical": True}})
    assert_error(r, 422, "is a sample list: the physical bounds are not available")


def test_a_text_sample_list_stored_over_the_cap_is_refused(tmp_path):
    """A text list is weighed once read (its rows are ~20 bytes of text, 56 or 80
    stored); nothing is kept."""
    from api.services import tables
    from tests.table_files import SAMPLED, write_astm

    store = Store(tmp_path / "data")
    lab = write_astm(tmp_path / "lab.astm", "ggx", SAMPLED, n=200)
    with pytest.raises(tables.StoredTooLarge, match=r"lab.astm: 200 samples are stored as "
                                                    r"11,200 bytes .* at most 178 samples"):
        tables.validate_and_store(store, lab, "0" * 64, lab.stat().st_size, "lab.astm",
                                  cap=10_000)
    assert store.get_table("0" * 64) is None
    record, created = tables.validate_and_store(store, lab, "0" * 64, lab.stat().st_size,
                                                "lab.astm", cap=11_200)
    assert created and record.summary["input"]["samples"] == 200


def test_huge_declared_length_is_refused_before_the_body(server):
    """Content-Length far past the cap: answered before a byte of body is sent
    (what curl sees, with its Expect: 100-continue)."""
    with socket.create_connection(("127.0.0.1", server.port), timeout=30) as s:
        s.sendall(b"POST /v1/tables HTTP/1.1\r\nHost: x\r\n"
                  b"Content-Type: application/octet-stream\r\nContent-Length: 10000000000\r\n"
                  b"Expect: 100-continue\r\n\r\n")
        reply = b""
        while b"\r\n\r\n" not in reply or not reply.rstrip().endswith(b"}"):
            chunk = s.recv(65536)
            if not chunk:
                break
            reply += chunk
    status_line, _, rest = reply.partition(b"\r\n")
    assert b" 413 " in status_line, reply
    assert b"BRDFFIT_MAX_UPLOAD_BYTES" in rest


# -- fits: validation before queueing ----------------------------------------------------

UNKNOWN_TABLE = "0" * 64
UNKNOWN_JOB = "f" * 32


def test_unknown_ids_are_404(http):
    assert_error(http.get(f"/v1/tables/{UNKNOWN_TABLE}"), 404, "no table")
    assert_error(http.get(f"/v1/fits/{UNKNOWN_JOB}"), 404, "no fit job")
    assert_error(http.get(f"/v1/fits/{UNKNOWN_JOB}/plots/slices.png"), 404, "no fit job")
    assert_error(http.post("/v1/fits", json={"table_id": UNKNOWN_TABLE}), 404, "no table")


def test_malformed_ids_are_422(http):
    assert_error(http.get("/v1/tables/not-a-hash"), 422, "table_id")
    assert_error(http.get("/v1/fits/x"), 422, "job_id")
    assert_error(http.post("/v1/fits", json={"table_id": "abc"}), 422, "table_id")


@pytest.mark.parametrize("model, words", [
    ("phong2", "unknown model 'phong2'; choose one of lambert, "),
    (["ggx", "nope"], "unknown model 'nope'"),
    ([], "at least one model"),
    (42, "model"),
])
def test_unknown_model_is_422(http, table_id, model, words):
    assert_error(http.post("/v1/fits", json={"table_id": table_id, "model": model}), 422, words)


def test_a_value_that_fits_no_member_of_a_union_is_one_message(http, table_id):
    # it was "models.str: Input should be a valid string; models.list[str]: ...", a
    # location that names pydantic's union members, not the request's fields
    for value in (None, 42, {"name": "ggx"}):
        r = http.post("/v1/fits", json={"table_id": table_id, "models": value})
        assert_error(r, 422, "valid string, or input should be a valid list")
        assert r.json()["detail"].startswith("models: ")
        assert [e["loc"] for e in r.json()["errors"]] == [["body", "models"]]


@pytest.mark.parametrize("options, words", [
    ({"starts": 0}, "options.starts"),
    ({"samples": 10}, "options.samples"),
    ({"samples": "many"}, "options.samples"),
    ({"solver": "newton"}, "options.solver"),
    ({"precision": "float16"}, "options.precision"),
    ({"max_steps": 0}, "options.max_steps"),
    ({"seed": -1}, "options.seed"),
    ({"init": {"alpha": 0.1}}, "options.init"),  # not an allowed key
    ({"bin_weight": [1, 2]}, "options.bin_weight"),
    ([1, 2], "options"),
    # optimistix's solvers mix float32 residuals with float64 operators: the job was
    # accepted, then failed
    ({"precision": "float32", "solver": "dogleg"}, "solves in float64 only"),
    ({"precision": "float32", "solver": "optx-lm"}, "solves in float64 only"),
])
def test_bad_options_are_422_before_queueing(http, table_id, options, words):
    r = http.post("/v1/fits", json={"table_id": table_id, "model": "lambert", "options": options})
    assert_error(r, 422, words)


def test_malformed_fit_bodies_are_422(http):
    r = http.post("/v1/fits", content=b"{not json", headers={"Content-Type": "application/json"})
    assert_error(r, 422, "json")
    assert r.json()["detail"].startswith("body: not valid JSON at character 1: Expecting")
    # Latin-1 where JSON is UTF-8: it was a bare 400 "There was an error parsing the body"
    r = http.post("/v1/fits", content=b'{"table_id": "caf\xe9"}',
                  headers={"Content-Type": "application/json"})
    assert_error(r, 422)
    assert r.json()["detail"] == ("body: not valid JSON: not UTF-8 (byte 0xe9 at byte 17); "
                                  "send JSON encoded as UTF-8")
    assert r.json()["errors"] == [{"loc": ["body"], "msg": r.json()["detail"][6:]}]
    # nested past the parser's depth, or an integer of more than 4,300 digits: the same
    # bare 400, now said as every other body that no request can be
    for content, said in ((b'{"scene": ' + b"[" * 5000 + b"]" * 5000 + b"}", "nested deeper"),
                          (b'{"options": {"samples": ' + b"9" * 5000 + b"}}", "4,300 digits")):
        r = http.post("/v1/fits", content=content, headers={"Content-Type": "application/json"})
        assert_error(r, 422, said)
    for body in ({"models": []}, {"model": []}):  # the request's form, and the earlier one
        r = http.post("/v1/fits", json={"table_id": UNKNOWN_TABLE, **body})
        assert_error(r, 422)
        assert r.json()["detail"] == "body: give at least one model, or auto"  # no "Value error"
    assert_error(http.post("/v1/fits", json=[1, 2, 3]), 422)
    assert_error(http.post("/v1/fits", json={"table_id": UNKNOWN_TABLE, "colour": "red"}), 422,
                 "colour")
    # a JSON request sent as text or a form: said so (it was 422 'Input should be a valid
    # dictionary', which names no fault the sender can see)
    for media in ("text/plain", "application/x-www-form-urlencoded", None):
        r = http.post("/v1/fits", content=b'{"table_id": "1", "model": "ggx"}',
                      headers={} if media is None else {"Content-Type": media})
        assert_error(r, 415, "a fit request is a JSON object, sent as application/json")
    # NaN and 1e999 (inf) are not finite, whatever the range says
    for number in ("NaN", "1e999"):
        r = http.post("/v1/fits", content=f'{{"table_id": "{UNKNOWN_TABLE}", "models": "auto", '
                                           f'"rule": {{"tolerance": {number}}}}}'.encode(),
                      headers={"Content-Type": "application/json"})
        assert_error(r, 422, "finite number")


def test_a_request_that_would_store_what_breaks_the_service_is_422(http, table_id):
    """Each answered 5xx, or was stored and then broke the listings: a scene of 1,000
    lights and 1,000 views (a 53 KB body) made a job record of 1M pairs, 124 MB; a scene
    named with an unpaired surrogate was a 500 beside a stored job that no listing could
    show; a cursor past int64 an OverflowError."""
    up = [[0.1, 0.0, 1.0]] * 200
    r = http.post("/v1/fits", json={"table_id": table_id, "models": "lambert",
                                    "scene": {"lights": up, "views": up}})
    assert_error(r, 422, "40,000 direction pairs", "at most 20,000")
    r = http.post("/v1/fits", json={"table_id": table_id, "model": "lambert",  # the old form
                                    "options": {"scene": {"lights": up, "views": up}}})
    assert_error(r, 422, "40,000 direction pairs", "at most 20,000")
    before = http.get("/v1/fits", params={"limit": 500}).json()
    r = http.post("/v1/fits", content=(f'{{"table_id": "{table_id}", "models": "lambert", '
                                       '"scene": {"name": "\\ud800"}}').encode(),
                  headers={"Content-Type": "application/json"})
    assert_error(r, 422, "unpaired surrogate")
    assert http.get("/v1/fits", params={"limit": 500}).json() == before
    for route in ("/v1/fits", "/v1/tables"):
        assert_error(http.get(route, params={"cursor": "9" * 19}), 422, "cursor")
    assert http.get("/v1/tables", params={"cursor": "9" * 18}).status_code == 200


def test_a_fit_is_estimated_before_it_is_queued(http, table_id):
    """``POST /v1/fits/estimate`` takes a fit's body and says what it would cost and
    whether the server takes it: over the limits is an answer there (200), where
    ``POST /v1/fits`` refuses (422, with the same words); nothing is queued."""
    before = http.get("/v1/fits", params={"limit": 500}).json()["total"]
    r = http.post("/v1/fits/estimate", json={"table_id": table_id, "models": "ggx"})
    assert r.status_code == 200, r.text
    cost = r.json()
    assert cost["accepted"] and cost["over_limits"] is None and cost["models"] == ["ggx"]
    assert 0 < cost["seconds"] <= cost["limits"]["seconds"]
    assert 0 < cost["memory_mib"] <= cost["limits"]["memory_mib"]
    assert cost["machine_factor"] >= 1.0 and "samples" in cost["detail"]
    big = {"table_id": table_id, "models": "auto",
           "options": {"samples": 1_000_000, "starts": 32, "loss": "render"}}
    r = http.post("/v1/fits/estimate", json=big)
    assert r.status_code == 200, r.text
    over = r.json()
    assert not over["accepted"] and over["seconds"] > cost["seconds"]
    assert "BRDFFIT_MAX_JOB_ESTIMATE_S" in over["over_limits"]
    assert_error(http.post("/v1/fits", json=big), 422, over["over_limits"][:60])
    assert_error(http.post("/v1/fits/estimate", json={"table_id": "b" * 64, "models": "ggx"}),
                 404, "upload it with POST /v1/tables")
    assert_error(http.post("/v1/fits/estimate", json={"table_id": table_id,
                                                       "models": "no-such-model"}),
                 422, "no-such-model")
    assert_error(http.post("/v1/fits/estimate", content=b"models=ggx",
                           headers={"Content-Type": "text/plain"}), 415, "application/json")
    assert http.get("/v1/fits", params={"limit": 500}).json()["total"] == before


def test_fit_runs_and_plots_wait_for_it(server, http, table_id):
    r = http.post("/v1/fits", json={"table_id": table_id, "model": ["lambert", "lambert"],
                                    "options": FAST})
    assert r.status_code == 202, r.text
    job = r.json()
    assert r.headers["location"] == f"/v1/fits/{job['id']}"
    assert job["status"] in ("queued", "running") and job["models"] == ["lambert"]
    plot = http.get(f"/v1/fits/{job['id']}/plots/slices.png")
    if plot.status_code != 200:  # fast machines may already be done
        assert_error(plot, 409, "plots exist once it is done")
    done = wait_status(http, job["id"], ("done", "failed"))
    assert done["status"] == "done", done
    assert done["attempts"] == 1 and done["reason"] is None
    # the worker's time on a job is stored: the cost estimate learns the machine from it
    # (not from a job that compiled: the second of two alike, in the one worker, did not)
    again = http.post("/v1/fits", json={"table_id": table_id, "model": "lambert",
                                        "options": FAST | {"seed": 7}}).json()
    again = wait_status(http, again["id"], ("done", "failed"))
    request, _, run_s = Store(server.data_dir).recent_runs(1)[0]
    assert request["options"]["seed"] == 7 and 0 < run_s < 600
    assert again["run_seconds"] == run_s and job.get("run_seconds") is None  # once done
    result = done["result"]
    assert result == done["results"][0]
    assert result["model"] == "lambert" and result["table"] == "ggx.binary"
    assert set(result) >= {"params", "error", "converged", "result", "steps", "samples"}
    assert_error(http.get(f"/v1/fits/{job['id']}/plots/spheres.png", params={"model": "ggx"}),
                 404, "no 'ggx' fit")
    assert_error(http.get(f"/v1/fits/{job['id']}/plots/histogram.png"), 422, "kind")
    # an exposure re-renders the sphere plots (a file of its own); the others have none
    plain = http.get(f"/v1/fits/{job['id']}/plots/spheres.png")
    brighter = http.get(f"/v1/fits/{job['id']}/plots/spheres.png", params={"exposure_ev": 1.5})
    assert plain.status_code == brighter.status_code == 200
    assert brighter.content != plain.content
    assert http.get(f"/v1/fits/{job['id']}/plots/spheres.png").content == plain.content
    assert_error(http.get(f"/v1/fits/{job['id']}/plots/slices.png",
                          params={"exposure_ev": 1}), 422, "no sphere renders")
    for bad in (0.3, 12.25, -6.25, "nan"):
        assert http.get(f"/v1/fits/{job['id']}/plots/spheres.png",
                        params={"exposure_ev": bad}).status_code == 422
    # within multiple_of's tolerance of the grid: the grid's own plot, not a new file
    # (1e-10 and 2.000000000000001 were each a render and a cached file of their own)
    plots = len(list(Path(server.data_dir).rglob("spheres*.png")))
    for near in (1e-10, 1e-300):
        r = http.get(f"/v1/fits/{job['id']}/plots/spheres.png", params={"exposure_ev": near})
        assert r.status_code == 200 and r.content == plain.content
    assert len(list(Path(server.data_dir).rglob("spheres*.png"))) == plots


def test_the_front_fits_and_plots_without_jax_or_matplotlib(server, http, table_id):
    """The server process checks requests, queues jobs and picks a job's chosen fit;
    its workers fit and draw. The front loads neither JAX nor matplotlib, so it
    answers a second after start instead of three; the worker loads both."""
    # a `_mono` variant too: choosing a job's result counts its parameters
    r = http.post("/v1/fits", json={"table_id": table_id,
                                    "model": ["lambert", "blinn_phong_mono"], "options": FAST})
    assert r.status_code == 202, r.text
    done = wait_status(http, r.json()["id"], ("done", "failed"))
    assert done["status"] == "done" and done["result"]["model"] in ("lambert", "blinn_phong_mono")
    assert http.get(f"/v1/fits/{done['id']}/plots/report.png").status_code == 200
    # auto's ranking is a plot of auto's choice: a job of named models has none
    assert_error(http.get(f"/v1/fits/{done['id']}/plots/ranking.png"), 422,
                 "fitted the models it named, without auto: plot one of slices")
    assert_error(http.post("/v1/fits", json={"table_id": table_id, "model": "auto", "options": {
        **FAST, "candidates": ["lambert", "no_such_model"]}}), 422, "no_such_model")
    # mono_ks, as `brdffit fit --mono-ks` and select(mono_ks=True) have it; refused, not
    # ignored, with a fixed model
    r = http.post("/v1/fits", json={"table_id": table_id, "model": "auto", "options": {
        **FAST, "candidates": ["ggx"], "mono_ks": True}})
    assert r.status_code == 202, r.text
    done = wait_status(http, r.json()["id"], ("done", "failed"))
    assert done["status"] == "done", done
    assert {x["model"] for x in done["results"]} == {"ggx", "ggx_mono"}
    ranking = http.get(f"/v1/fits/{done['id']}/plots/ranking.png")  # the chosen fit's
    assert ranking.status_code == 200 and ranking.content[:8] == b"\x89PNG\r\n\x1a\n"
    assert http.get(f"/v1/fits/{done['id']}/plots/ranking.png?model=auto").content \
        == ranking.content  # drawn once, then served from the data dir
    assert_error(http.get(f"/v1/fits/{done['id']}/plots/ranking.png?model=ggx_mono"), 422,
                 "is a candidate, not auto's choice: ask for the chosen fit's (no ?model=)")
    assert_error(http.post("/v1/fits", json={"table_id": table_id, "model": "ggx", "options": {
        **FAST, "mono_ks": True}}), 422,
        "the selection rule (mono_ks True) chooses among auto's candidates")

    def libraries(pid=None):
        return {part for f in server.mapped_files(pid) if ".so" in f for part in Path(f).parts
                if part in ("jaxlib", "matplotlib")}

    front = libraries()
    assert not {"jaxlib", "matplotlib"} & front, sorted(front)
    workers = server.worker_pids()
    assert workers, "the server has no worker process"
    worker = set().union(*(libraries(pid) for pid in workers))
    assert {"jaxlib", "matplotlib"} <= worker, sorted(worker)


def test_a_material_is_rebuilt_in_a_worker_not_in_the_front(server, http):
    """POST /v1/materials/{name} rebuilt the table from its network (JAX) in the server's
    own process: 120 -> 420 MB for one, 2 GB for six at once. A worker rebuilds it; the
    front hashes and stores it, and still maps no JAX."""
    first = http.post("/v1/materials/red-plastic")
    assert first.status_code in (200, 201), first.text
    again = http.post("/v1/materials/red-plastic")
    assert again.status_code == 200 and again.json()["id"] == first.json()["id"]
    assert first.json()["name"] == "red-plastic.binary"
    assert not {part for f in server.mapped_files() if ".so" in f
                for part in Path(f).parts if part == "jaxlib"}
    assert not list((Path(server.data_dir) / "tmp").glob("material-*"))  # nothing left


def test_the_earlier_form_keeps_or_refuses_every_key_it_is_sent(http, table_id):
    """``model`` with flat ``options`` (the form before brdffit.request/1) took only
    table_id, model and options: a top-level scene beside them was dropped without a
    word, and the job fitted the whole table; any other key was dropped too."""
    scene = {"preset": "camera-normal"}
    r = http.post("/v1/fits", json={"table_id": table_id, "model": "lambert", "options": FAST,
                                    "scene": scene})
    assert r.status_code == 202, r.text
    assert r.json()["request"]["scene"]["name"] == "camera-normal"  # not null: applied
    http.post(f"/v1/fits/{r.json()['id']}/cancel")
    assert_error(http.post("/v1/fits", json={"table_id": table_id, "model": "lambert",
                                             "options": {**FAST, "scene": scene},
                                             "scene": scene}), 422,
                 "a scene at the top level and another in `options`: give one")
    r = http.post("/v1/fits", json={"table_id": table_id, "model": "lambert",  # null: none
                                    "options": {**FAST, "scene": scene}, "scene": None})
    assert r.status_code == 202 and r.json()["request"]["scene"]["name"] == "camera-normal"
    http.post(f"/v1/fits/{r.json()['id']}/cancel")
    assert http.post("/v1/fits", json={"table_id": table_id, "model": "lambert",
                                       "options": FAST, "tolerence": 0.1}).status_code == 422


def test_a_scene_of_lights_and_views_travels_and_is_stored_as_given(server, table_id):
    """The client expanded 100 lights x 100 views into 10,000 pairs (1.3 MB): a 413 for
    a scene the service takes; the job stored 19,881 pairs for 141 x 141 (2.5 MB)."""
    from brdffit.client import Client

    rng = np.random.default_rng(5)
    d = rng.normal(size=(200, 3))
    d[:, 2] = np.abs(d[:, 2]) + 0.1
    c = Client(server.url)
    job = c.fit(table_id, "lambert", scene={"lights": d[:100].tolist(),
                                            "views": d[100:].tolist()}, **FAST)
    stored = httpx.get(f"{server.url}/v1/fits/{job.id}")
    assert stored.status_code == 200 and len(stored.content) < 30_000
    assert len(stored.json()["request"]["scene"]["lights"]) == 100
    httpx.post(f"{server.url}/v1/fits/{job.id}/cancel")  # done already, or cancelled


@pytest.mark.unit
def test_a_stored_request_is_served_as_stored(monkeypatch):
    """A job's request was checked by the library when it was posted; a GET serves it
    without checking it again (0.8 s of the server's CPU per GET of a job whose scene
    held 19,881 pairs)."""
    from api.routes import fits
    from api.store import JobRecord

    def checked_again(*a, **k):
        raise AssertionError("the library checked a stored request again")

    request = FitRequest.of("lambert", scene={"preset": "camera-normal"}).to_dict()
    job = JobRecord(**{f: None for f in JobRecord.__dataclass_fields__} | {
        "id": "a" * 32, "status": "queued", "table_id": "b" * 64, "models": ["lambert"],
        "request": request, "attempts": 0, "created_at": 0.0})
    monkeypatch.setattr(fits.FitRequest, "from_dict", checked_again)
    out = fits._out(job)
    assert out.model_dump(by_alias=True)["request"] == request
    from pydantic import ValidationError

    with pytest.raises(ValidationError, match="checked a stored request again"):
        fits.RequestBody.model_validate(request)  # what a POST is checked by


def test_a_worker_killed_mid_fit_costs_an_attempt_not_the_job(server, http, table_id):
    """A worker that dies (OOM killer, say) is replaced and its job runs again,
    saying why."""
    r = http.post("/v1/fits", json={"table_id": table_id, "model": "ggx",
                                    "options": {"samples": 8192, "starts": 2, "seed": 3}})
    job = wait_status(http, r.json()["id"], ("running", "done", "failed"), poll=0.02)
    assert job["status"] == "running", job
    workers = server.worker_pids()
    assert workers, "no worker process found"
    for pid in workers:
        os.kill(pid, signal.SIGKILL)
    done = wait_status(http, job["id"], ("done", "failed"))
    assert done["status"] == "done", done
    assert done["attempts"] == 2 and "worker process died" in done["note"], done
    assert "worker process died" in server.log()


# -- bearer token ------------------------------------------------------------------------


def test_token_guards_every_route_but_healthz(tmp_path):
    with Server(tmp_path, env={"BRDFFIT_API_TOKEN": "s3cret"}) as s, \
            httpx.Client(base_url=s.url, timeout=30) as http:
        assert http.get("/healthz").status_code == 200
        for method, path in [("GET", "/v1/models"), ("GET", f"/v1/tables/{UNKNOWN_TABLE}"),
                             ("POST", "/v1/tables"), ("POST", "/v1/fits"),
                             ("GET", f"/v1/fits/{UNKNOWN_JOB}"),
                             ("GET", f"/v1/fits/{UNKNOWN_JOB}/plots/polar.png"),
                             ("GET", "/openapi.json"), ("GET", "/docs")]:
            assert_error(http.request(method, path), 401, "bearer")
            wrong = http.request(method, path, headers={"Authorization": "Bearer guess"})
            assert_error(wrong, 401, "wrong bearer token")
        # a body is not read (nor judged) before the token is: malformed JSON, one nested
        # past the parser and an upload were each answered on their body first
        for path, content in (("/v1/fits", b"{x"), ("/v1/fits", b"[" * 5000),
                              ("/v1/tables", b"\0" * 100_000)):
            r = http.post(path, content=content, headers={"Content-Type": "application/json"})
            assert_error(r, 401, "bearer")
            assert r.headers["www-authenticate"] == "Bearer"
            wrong = http.post(path, content=content, headers={"Authorization": "bearer guess"})
            assert_error(wrong, 401, "wrong bearer token")
        ok = {"Authorization": "Bearer s3cret"}
        assert http.get("/v1/models", headers=ok).status_code == 200
        assert_error(http.get(f"/v1/fits/{UNKNOWN_JOB}", headers=ok), 404)
        assert_error(http.post("/v1/fits", content=b"{x", headers={
            **ok, "Content-Type": "application/json"}), 422, "not valid JSON")
        # read as the routes read it: the token stripped, the first of two headers
        for headers in ([("Authorization", "Bearer  s3cret")],
                        [("Authorization", "Bearer s3cret"), ("Authorization", "Bearer x")]):
            for method in ("GET", "POST"):
                r = http.request(method, "/v1/fits", headers=headers + [
                    ("Content-Type", "application/json")],
                    content=b"{x" if method == "POST" else None)
                assert r.status_code == (200 if method == "GET" else 422), (headers, r.text)
        assert http.get("/openapi.json", headers=ok).json()["info"]["title"] == "brdffit"


# -- restarts: nothing silently lost -----------------------------------------------------


def test_sigkill_with_a_job_running_and_one_queued_loses_nothing(tmp_path):
    data = tmp_path / "data"
    path = tmp_path / "ggx.binary"
    path.write_bytes(table_bytes("ggx"))
    server = Server(data, workers=1).start()
    try:
        with httpx.Client(base_url=server.url, timeout=60) as http:
            with open(path, "rb") as f:
                tid = http.post("/v1/tables", content=f).json()["id"]
            # One worker: the first job runs (long enough to be caught), the second waits.
            slow = http.post("/v1/fits", json={"table_id": tid, "model": "ggx",
                                               "options": {"samples": 8192, "starts": 2}}).json()
            quick = http.post("/v1/fits", json={"table_id": tid, "model": "lambert",
                                                "options": FAST}).json()
            wait_status(http, slow["id"], ("running",), timeout=60, poll=0.02)
            at_kill = {j: http.get(f"/v1/fits/{j}").json()["status"]
                       for j in (slow["id"], quick["id"])}
        server.kill()
        # Its worker notices the server is gone and exits by itself.
        assert server.wait_group_gone(20.0), "orphaned worker processes"
    finally:
        server.stop()

    # Same data dir, a new server: the running job runs again, the queued one runs.
    with Server(data, workers=1) as again, httpx.Client(base_url=again.url, timeout=60) as http:
        slow_done = wait_status(http, slow["id"], ("done", "failed"))
        quick_done = wait_status(http, quick["id"], ("done", "failed"))
    assert at_kill[slow["id"]] == "running", at_kill
    for job in (slow_done, quick_done):
        assert job["status"] == "done", job
        if at_kill[job["id"]] == "running":  # run again, and said so
            assert job["attempts"] == 2 and "interrupted" in job["note"], job
        else:  # still queued at the kill (unless the slow one had just ended)
            assert job["attempts"] == 1 and job["note"] is None, job
    assert "re-queued" in again.log()


def test_recovery_fails_a_job_out_of_attempts(tmp_path):
    """With BRDFFIT_MAX_ATTEMPTS=1 an interrupted job is failed, with the reason."""
    store = Store(tmp_path)
    tmp = tmp_path / "t.binary"
    merl.write(tmp, table("lambert"))
    store.add_table("a" * 64, tmp, 1, "t.binary", {})
    running = store.create_job("a" * 64, LAMBERT)
    queued = store.create_job("a" * 64, LAMBERT)
    assert store.claim_next().id == running.id
    requeued, failed = Store(tmp_path).recover(max_attempts=1)  # "the next server"
    assert (requeued, failed) == ([], [running.id])
    job = store.get_job(running.id)
    assert job.status == "failed" and "server stopped" in job.reason
    assert "BRDFFIT_MAX_ATTEMPTS=1" in job.reason
    assert store.get_job(queued.id).status == "queued"
    assert store.claim_next().id == queued.id and store.claim_next() is None


def test_a_second_server_on_a_data_directory_in_use_is_refused(server, http, table_id,
                                                                tmp_path):
    """``brdffit serve`` started again on a directory a server is serving (by mistake):
    it re-queued the first's running job as a stopped server's, spending an attempt,
    before it failed to bind the port. Now it stops first, in one line; the lock is the
    kernel's, so a second holder in one process is refused too, and freed on release."""
    from api.store import DataDirInUse, ServerLock

    job = http.post("/v1/fits", json={"table_id": table_id, "model": "lambert",
                                      "options": FAST}).json()
    r = subprocess.run([sys.executable, "-m", "brdffit.cli", "serve", "--port",
                        str(free_port()), "--data-dir", str(server.data_dir)],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 2, (r.returncode, r.stderr)
    assert r.stderr.count("\n") == 1 and "is served by another brdffit server (pid " in r.stderr
    assert str(server.proc.pid) in r.stderr, r.stderr
    done = wait_status(http, job["id"], ("done", "failed"))
    assert done["status"] == "done" and done["attempts"] == 1, done
    with ServerLock(tmp_path), pytest.raises(DataDirInUse, match=f"pid {os.getpid()}"):
        ServerLock(tmp_path).acquire()
    with ServerLock(tmp_path):  # released: free again
        pass


def test_clean_shutdown_requeues_without_spending_an_attempt(tmp_path):
    store = Store(tmp_path)
    tmp = tmp_path / "t.binary"
    merl.write(tmp, table("lambert"))
    store.add_table("b" * 64, tmp, 1, "t.binary", {})
    job = store.create_job("b" * 64, LAMBERT)
    store.claim_next()
    assert store.release_running() == 1
    again = store.get_job(job.id)
    assert again.status == "queued" and again.attempts == 0 and "shut down" in again.note


# -- fuzzing -------------------------------------------------------------------------------


def test_schemathesis_finds_no_server_error(tmp_path):
    """A bounded property-based run over every operation of the OpenAPI document, on a
    server of its own: what it uploads, queues and deletes leaves the other tests'
    server as they expect it."""
    exe = Path(sys.executable).with_name("schemathesis")
    if not exe.exists():
        pytest.skip("schemathesis is not installed (pip install -e '.[test]')")
    with Server(tmp_path / "api", workers=1,
                env={"BRDFFIT_MAX_UPLOAD_BYTES": str(CAP)}) as server:
        _fuzz(exe, server, tmp_path)
        # still serving, and no 5xx
        assert httpx.get(f"{server.url}/healthz", timeout=10).json()["status"] == "ok"
        assert '" 500 ' not in server.log() and "Traceback" not in server.log(), \
            server.log()[-5000:]


def _fuzz(exe: Path, server: Server, tmp_path: Path) -> None:
    proc = subprocess.run(
        [str(exe), "run", f"{server.url}/openapi.json", "--checks", "not_a_server_error",
         # One worker thread: with two, schemathesis's coverage phase calls compile()
         # from both and CPython 3.11 < 3.11.8 may raise "AST constructor recursion
         # depth mismatch" (python/cpython#106905), a crash of the tool, not a finding.
         # 10 generated cases per operation beside the coverage phase's edge cases: 25
         # took ~4x as long (the fuzzer reaches real fits' plots and exports, seconds
         # each) and found nothing more in its runs here
         "--max-examples", "10", "--phases", "examples,coverage,fuzzing", "--workers", "1",
         "--request-timeout", "30", "--seed", "1", "--generation-database", "none",
         "--no-color", "--suppress-health-check", "all"],
        capture_output=True, text=True, timeout=240, cwd=tmp_path,
    )
    out = proc.stdout + proc.stderr
    assert proc.returncode == 0, out[-6000:]


def test_results_are_plain_json(http, table_id):
    """NaN never reaches the wire (it is not JSON): the document parses strictly."""
    r = http.post("/v1/fits", json={"table_id": table_id, "model": "lambert", "options": FAST})
    assert r.status_code in (200, 201, 202), (r.status_code, r.text)
    done = wait_status(http, r.json()["id"], ("done", "failed"))
    text = http.get(f"/v1/fits/{done['id']}").text
    json.loads(text, parse_constant=lambda c: pytest.fail(f"{c} in JSON"))


def test_a_single_hot_bin_table_fits_to_finite_metrics(http):
    """A dim table but one hot bin: odd but physical, so fitted; every metric of the
    result is a finite number on the wire, the job done, not failed. Zeros but that bin
    are no reflectance to fit: the job fails, saying so."""
    r = http.post("/v1/tables", content=GOOD_HEADER + _with_raw(1000.0, one_bin=True, rest=0.0),
                  params={"name": "blank-but-hot.binary"},
                  headers={"Content-Type": "application/octet-stream"})
    assert r.status_code == 201, r.text
    r = http.post("/v1/fits", json={"table_id": r.json()["id"], "model": "lambert",
                                    "options": FAST})
    failed = wait_status(http, r.json()["id"], ("done", "failed"))
    assert failed["status"] == "failed" and "no reflectance to fit but 1 isolated spike" in (
        failed["reason"]), failed
    r = http.post("/v1/tables", content=GOOD_HEADER + _with_raw(1000.0, one_bin=True, rest=1.0),
                  params={"name": "hot.binary"},
                  headers={"Content-Type": "application/octet-stream"})
    assert r.status_code == 201, r.text
    r = http.post("/v1/fits", json={"table_id": r.json()["id"], "model": ["lambert", "ggx"],
                                    "options": FAST})
    done = wait_status(http, r.json()["id"], ("done", "failed"))
    assert done["status"] == "done", done["reason"]
    text = http.get(f"/v1/fits/{done['id']}").text
    job = json.loads(text, parse_constant=lambda c: pytest.fail(f"{c} in JSON"))
    for result in job["results"]:
        for name, v in result["error"].items():
            assert isinstance(v, float) and np.isfinite(v), (result["model"], name, v)


def test_worker_tasks_return_failures_as_values(tmp_path):
    """What crosses the process boundary is a value: exceptions such as
    MerlFormatError do not unpickle, and would break the worker pool."""
    from api import tasks

    missing = str(tmp_path / "gone.binary")
    out = tasks.fit_models(missing, "gone.binary", FitRequest.of("lambert", **FAST).to_dict())
    assert not out.ok and "cannot read" in out.reason and not out.internal
    out = tasks.render_plot(missing, "gone.binary", {}, "slices")
    assert not out.ok and "cannot read" in out.reason and out.error_type == "MerlFormatError"
    from brdffit.jsonout import strict

    assert strict({"a": [float("nan"), 1.0, float("inf")]}) == {"a": [None, 1.0, None]}


def test_a_jobs_worker_time_measures_the_machine_only_where_it_did_not_compile(
        tmp_path, monkeypatch):
    """The cost estimate learns the machine from a job's worker time (``run_s``); a job
    that compiled its programs ran longer than the machine's speed says, once: its time
    is kept (the job's ``run_seconds``), not learnt from."""
    import jax.monitoring

    from api import tasks
    from brdffit import request as library

    path = tmp_path / "t.binary"
    merl.write(path, table("lambert"))
    asked = FitRequest.of("lambert", **FAST).to_dict()
    warm = tasks.fit_models(str(path), "t.binary", asked)
    warm = tasks.fit_models(str(path), "t.binary", asked)  # whatever the first compiled
    assert warm.ok and warm.seconds > 0 and warm.measures_machine
    run = library.run

    def compiling_run(*args, **kwargs):
        jax.monitoring.record_event_duration_secs(tasks.COMPILE_EVENTS[-1], 1.0)
        return run(*args, **kwargs)

    monkeypatch.setattr(library, "run", compiling_run)
    cold = tasks.fit_models(str(path), "t.binary", asked)
    assert cold.ok and cold.seconds > 0 and not cold.measures_machine


def test_the_browser_finds_an_icon(http):
    for path in ("/favicon.ico", "/page/icon.svg"):
        r = http.get(path)
        assert r.status_code == 200 and r.headers["content-type"] == "image/svg+xml"
        assert r.text.startswith("<svg") and "<circle" in r.text
    assert '<link rel="icon" href="/page/icon.svg"' in http.get("/").text


def test_the_api_description_lists_every_plot_kind(http):
    from brdffit.view.kinds import KINDS, SAMPLE_KINDS

    description = http.get("/openapi.json").json()["info"]["description"]
    assert f"plots/{{kind}}.png`: {', '.join(KINDS)};" in description and "report" in KINDS
    assert f"for a sample list's fit,\n   {', '.join(SAMPLE_KINDS)}" in description


def test_the_fit_service_decides_what_a_request_means_and_costs(tmp_path):
    """``api.services.fits.create``, the one place the service checks a request: the
    library's meaning (a tolerance with a fixed model is refused, not ignored), the
    cost against the limits (saying what to ask for instead: the page has samples and
    starts), then a queued job in a real SQLite store."""
    from api.services import fits
    from api.settings import Settings
    from brdffit.errors import FitInputError

    store = Store(tmp_path)
    tmp = tmp_path / "t.binary"
    merl.write(tmp, table("lambert"))
    store.add_table("a" * 64, tmp, 1, "t.binary", {"measured_bins": 1_000_000})
    settings = Settings(data_dir=tmp_path, max_job_estimate_s=60.0)
    with pytest.raises(fits.TableNotFound, match="upload it with POST /v1/tables"):
        fits.create(store, settings, "b" * 64, {"models": "ggx"})
    with pytest.raises(FitInputError, match=r"the selection rule \(tolerance 0.02\) chooses "
                                            r"among auto's candidates"):
        fits.create(store, settings, "a" * 64, {"models": "ggx", "rule": {"tolerance": 0.02}})
    with pytest.raises(fits.OverLimits) as over:
        fits.create(store, settings, "a" * 64, {"models": "auto", "options": {
            "samples": 200_000, "starts": 16}})
    why = str(over.value)
    assert "BRDFFIT_MAX_JOB_ESTIMATE_S" in why and "the auto candidates lambert" in why
    assert why.endswith("Ask for fewer samples or starts.") and "max_steps)" not in why
    assert store.list_jobs(limit=10).total == 0  # nothing queued by a refusal
    # a server whose worker ran a fit 40x slower than the estimate's constants counts on
    # that: a fit within the limit at the constants' speed is refused, saying why
    slow = {"models": "ggx", "options": {"samples": 4096}}
    assert fits.over_limits(fits.estimate(FitRequest.from_dict(slow), 1_000_000),
                            settings) is None
    done = store.create_job("a" * 64, FitRequest.from_dict(slow).to_dict())
    store.claim_next()
    reference = fits.estimate(FitRequest.from_dict(slow), 1_000_000).reference_seconds
    store.finish(done.id, [], run_s=40 * reference, measures_machine=True)
    with pytest.raises(fits.OverLimits, match=r"time x48\.00, as this server's recent jobs "
                                              "ran slower"):
        fits.create(store, settings, "a" * 64, slow)
    # what the estimate route answers: the same decision, before anything is queued
    checked = fits.costed(store, settings, "a" * 64, slow)
    assert checked.machine == pytest.approx(48.0) and "x48.00" in checked.over
    assert checked.cost.seconds == pytest.approx(48.0 * reference)
    store.delete_job(done.id)
    assert store.list_jobs(limit=10).total == 0
    job = fits.create(store, settings, "a" * 64, {"models": ["ggx", "lambert", "ggx"],
                                                  "options": {"samples": 4096}})
    assert job.models == ["ggx", "lambert"] and job.status == "queued"
    # stored in the library's one form, and read back as it
    assert FitRequest.from_dict(store.get_job(job.id).request) == FitRequest.of(
        ["ggx", "lambert"], samples=4096)
    # the table deleted while the request was checked: its foreign key was a 503 ("try
    # again later"), where the table is simply gone
    merl.write(tmp, table("lambert"))
    store.add_table("c" * 64, tmp, 1, "t.binary", {"measured_bins": 1_000_000})
    record = store.get_table("c" * 64)
    assert store.delete_table("c" * 64, with_fits=False) == (None, 0)
    store.get_table = lambda table_id: record  # the check saw it; the insert does not
    with pytest.raises(fits.TableNotFound, match="deleted while this fit was being checked"):
        fits.create(store, settings, "c" * 64, {"models": "ggx"})


def test_a_sample_upload_is_fitted_at_its_own_directions(server, tmp_path):
    """An ASTM file uploads as a sample list (docs/measurements.md): the table's summary
    says what binning it (for the plots) did, its fits are made at the samples' own
    directions with a held-out error, and a plot of one draws; a malformed sample file
    is a 422 naming it and the row."""
    from brdffit.client import ApiError, Client
    from tests.table_files import BAD_CSV, SAMPLED, write_astm

    c = Client(server.url)
    info = c.upload_table(write_astm(tmp_path / "lab.astm", "ggx", SAMPLED, n=5000))
    assert info.name == "lab.astm" and info.summary["input"]["format"] == "astm"
    assert info.summary["measured_bins"] == info.summary["input"]["binning"]["bins"]
    job = c.wait(c.fit(info.id, "ggx", **FAST))
    assert job.status == "done", job
    r = c.result(job)
    assert r.input["fitted_at"] == "samples" and r.input["samples"] == 5000
    # the stored list is the upload's to the last bit or two (angles -> directions)
    assert r.input["binning"]["bins"] == info.summary["input"]["binning"]["bins"]
    assert "held_out_log_rmse" in r.error and r.quality["basis"] == "held_out"
    assert r.params["alpha"] == pytest.approx(SAMPLED["alpha"], rel=0.02)
    assert c.plot(job, "polar")[:8] == b"\x89PNG\r\n\x1a\n"
    # each sample, fitted against measured: a sample list's fit only
    assert c.plot(job, "samples")[:8] == b"\x89PNG\r\n\x1a\n"
    (tmp_path / "t.binary").write_bytes(table_bytes("ggx"))
    table_job = c.wait(c.fit(c.upload_table(tmp_path / "t.binary").id, "lambert", **FAST))
    with pytest.raises(ApiError, match="fitted a MERL table") as e:
        c.plot(table_job, "samples")
    assert e.value.status_code == 422
    bad = tmp_path / "bad.csv"
    bad.write_text(BAD_CSV)
    with pytest.raises(ApiError) as e:
        c.upload(bad)
    assert e.value.status_code == 422
    assert "bad.csv: theta_o_deg is below the horizon" in e.value.detail


def test_a_workbooks_sheet_is_named_on_upload(server, tmp_path):
    """A workbook of two sheets of samples: the service stored its first and the second
    could not be reached. ``?sheet=`` (the client's ``sheet=``) stores the one named, as
    a table of its own (its id is not the file's), whose fit reads that sheet; a sheet
    the workbook lacks, or named for a file with no sheets, is a 422 that says so."""
    from brdffit.client import ApiError, Client
    from tests.table_files import write_workbook

    book = write_workbook(tmp_path / "two.xlsx", {"sample A": [0.2, 0.1, 0.05],
                                                  "sample B": [0.6, 0.3, 0.15]})
    c = Client(server.url)
    first, named = c.upload_table(book), c.upload_table(book, sheet="sample B")
    assert first.summary["input"]["sheet"] == "sample A"
    assert named.summary["input"]["sheet"] == "sample B" and named.id != first.id
    assert c.upload(book, sheet="sample B") == named.id  # the same file and sheet: one id
    job = c.wait(c.fit(named.id, "lambert", **FAST))
    assert job.status == "done", job
    r = c.result(job)
    assert r.input["sheet"] == "sample B"
    assert r.params["kd"] == pytest.approx([0.6, 0.3, 0.15], rel=1e-6)
    with pytest.raises(ApiError, match="no sheet named 'sample C': the workbook's sheets "
                                       "are 'sample A', 'sample B'") as e:
        c.upload(book, sheet="sample C")
    assert e.value.status_code == 422
    (tmp_path / "t.binary").write_bytes(table_bytes("ggx"))
    with pytest.raises(ApiError, match="this is no Excel workbook") as e:
        c.upload(tmp_path / "t.binary", sheet="sample B")
    assert e.value.status_code == 422


def test_an_error_quotes_at_most_a_few_hundred_characters_of_the_input(http, table_id):
    """A 900,000-character model name was quoted whole, twice: a 1.8 MB answer."""
    r = http.post("/v1/fits", json={"table_id": table_id, "models": "g" * 900_000})
    assert_error(r, 422, "(900,000 characters); choose one of")
    assert len(r.content) < 4000
    assert all(name in r.json()["detail"] for name in models.names())  # the list is whole


def test_a_cancel_that_a_finishing_job_outran_is_a_409_not_a_200_done(tmp_path):
    """POST /v1/fits/{id}/cancel on a running job whose worker ended it as the cancel
    arrived answered 200 with the job ``done`` (the page said "Job ... is done" for a
    cancel): it is the 409 of a job that had ended; one whose worker is still being
    stopped is a 202, running. The route, on a real SQLite store; the queue's worker
    stands in by finishing the job, or by not stopping at all."""
    import asyncio

    from fastapi import HTTPException, Response

    from api.routes import fits as route

    store = Store(tmp_path)
    tmp = tmp_path / "t.binary"
    merl.write(tmp, table("lambert"))
    store.add_table("a" * 64, tmp, 1, "t.binary", {"measured_bins": 1_000_000})

    class Finishing:  # the worker stored its results as the cancel arrived
        def cancel_running(self, job_id):
            store.finish(job_id, [], run_s=1.0)

    class Stuck:  # the worker is not stopped within the route's wait
        def cancel_running(self, job_id):
            pass

    job = store.create_job("a" * 64, FitRequest.of("lambert").to_dict())
    store.claim_next()
    with pytest.raises(HTTPException) as e:
        asyncio.run(route.cancel_fit(job.id, store, Finishing(), Response()))
    assert e.value.status_code == 409 and "ended (done) before the cancel reached" in (
        e.value.detail)
    other = store.create_job("a" * 64, FitRequest.of("ggx").to_dict())
    store.claim_next()
    answer = Response()
    got = asyncio.run(route.cancel_fit(other.id, store, Stuck(), answer))
    assert answer.status_code == 202 and got.status == "running"
