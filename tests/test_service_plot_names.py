"""Any table name is safe in a plot (issue 14): matplotlib reads ``$...$`` in text
as math, and an unbalanced one used to make every plot of such a table a 500.
And a plot that fails leaves no file behind (never a 0-byte PNG)."""

from __future__ import annotations

import dataclasses

import httpx
import pytest
from matplotlib.image import imread

from brdffit.fitting.pipeline import fit
from brdffit.view import plots
from tests.api_fixtures import FAST, Server, table, table_bytes, wait_status

pytestmark = pytest.mark.system

NASTY = r"$\frac{a}{$ and $x^2$.binary"


def test_every_plot_of_a_table_with_math_in_its_name(tmp_path):
    with Server(tmp_path) as s, httpx.Client(base_url=s.url, timeout=120) as http:
        r = http.post("/v1/tables", content=table_bytes("ggx"), params={"name": NASTY},
                      headers={"Content-Type": "application/octet-stream"})
        assert r.status_code == 201 and r.json()["name"] == NASTY, r.text
        job = http.post("/v1/fits", json={"table_id": r.json()["id"], "model": "ggx",
                                          "options": FAST}).json()
        assert wait_status(http, job["id"], ("done", "failed"))["status"] == "done"
        for kind in plots.KINDS:
            r = http.get(f"/v1/fits/{job['id']}/plots/{kind}.png")
            assert r.status_code == 200, (kind, r.text)
            assert r.content.startswith(b"\x89PNG")
            (tmp_path / f"{kind}.png").write_bytes(r.content)
            assert imread(tmp_path / f"{kind}.png").shape[0] > 100
    assert " 500 " not in s.log() and "Traceback" not in s.log(), s.log()[-3000:]


def test_a_plot_that_fails_leaves_no_file(tmp_path, monkeypatch):
    t = dataclasses.replace(table("lambert"), source=NASTY)
    result = fit(t, "lambert", **FAST)
    written = plots.save_all(t, result, tmp_path / "ok", kinds=("slices",))
    assert [p.endswith("slices.png") for p in written] == [True]

    def broken(table, result):
        raise RuntimeError("renderer failed")

    monkeypatch.setitem(plots.RENDERERS, "polar", broken)
    out = tmp_path / "broken"
    with pytest.raises(RuntimeError, match="renderer failed"):
        plots.save_all(t, result, out, kinds=("slices", "polar"))
    # The finished plot is there whole; the failed one is absent, not empty; no temp left.
    assert sorted(p.name for p in out.iterdir()) == ["slices.png"]
    assert (out / "slices.png").stat().st_size > 1000
