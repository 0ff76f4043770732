"""What a batch worker keeps between its tasks: the table it read last, and its heap."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from brdffit.batch import tasks
from tests.table_files import write_tables

pytestmark = pytest.mark.unit


def test_a_worker_reads_a_table_once_while_its_file_is_unchanged(tmp_path):
    write_tables(tmp_path, {"t": ("lambert", {"kd": [0.5, 0.4, 0.3]})})
    path = str(tmp_path / "t.binary")
    first = tasks.recent_table(path)
    again = tasks.recent_table(path)
    assert again[0] is first[0] and again[1] is first[1]  # the same table object: its
    # per-table preparation is shared by the next model's fit
    # new content at the same path (as a measurement rewritten during a batch): read anew
    write_tables(tmp_path, {"t": ("lambert", {"kd": [0.2, 0.2, 0.2]})})
    st = os.stat(path)
    os.utime(path, ns=(st.st_atime_ns, st.st_mtime_ns + 1_000_000))
    changed = tasks.recent_table(path)
    assert changed[0] is not first[0] and changed[1].sha256 != first[1].sha256
    assert changed[0].rgb.max() < first[0].rgb.max()


def test_a_table_that_failed_to_read_is_read_again(tmp_path):
    path = tmp_path / "bad.binary"
    path.write_text("# not a table\n")
    table, record = tasks.recent_table(str(path))
    assert table is None and record.status == "failed" and "text file" in record.message
    assert str(path) not in tasks._RECENT_TABLES
    write_tables(tmp_path, {"bad": ("lambert", {"kd": [0.5, 0.4, 0.3]})})
    table, record = tasks.recent_table(str(path))
    assert table is not None and record.status == "ok"


def test_only_the_last_tables_are_kept(tmp_path):
    # one table under three names: what is kept is per path
    write_tables(tmp_path, {"t0": ("lambert", {"kd": [0.3, 0.3, 0.3]})})
    for i in (1, 2):
        os.link(tmp_path / "t0.binary", tmp_path / f"t{i}.binary")
    for i in range(3):
        tasks.recent_table(str(tmp_path / f"t{i}.binary"))
    kept = [p for p in tasks._RECENT_TABLES if p.startswith(str(tmp_path))]
    assert len(tasks._RECENT_TABLES) <= tasks._RECENT_KEPT
    assert kept == [str(tmp_path / "t1.binary"), str(tmp_path / "t2.binary")]


#: Run in a process of its own: the heap's policy is the whole process's, and the test
#: worker that ran it would keep every block it frees for the rest of the suite.
_HEAP_CHECK = r"""
import os, sys
import numpy as np
from brdffit import heap

def rss_mib():
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20

if heap._libc() is None:
    print("no glibc"); sys.exit(0)
assert heap.keep_freed_memory()
block = np.ones(50_000_000)  # 400 MB, a table-sized block's big sibling
before_free = rss_mib()
del block
kept = rss_mib()
assert kept > before_free - 100, (before_free, kept)  # freed, but kept: reused next pass
assert heap.give_memory_back()
given = rss_mib()
assert given < kept - 300, (kept, given)  # an idle worker hands it back
print("ok", round(before_free), round(kept), round(given))
"""


@pytest.mark.system  # a process of its own
@pytest.mark.skipif(not os.path.exists("/proc/self/statm"), reason="Linux only")
def test_freed_memory_is_kept_while_working_and_given_back_when_idle():
    out = subprocess.run([sys.executable, "-c", _HEAP_CHECK], capture_output=True, text=True,
                         cwd=Path(__file__).resolve().parents[1], timeout=120, check=False)
    assert out.returncode == 0, out.stderr
    assert out.stdout.startswith(("ok", "no glibc")), out.stdout
