"""What a batch worker keeps between its tasks: the table it read last, and its heap."""

from __future__ import annotations

import os

import numpy as np
import pytest

from brdffit import heap
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
    write_tables(tmp_path, {f"t{i}": ("lambert", {"kd": [0.1 * (i + 1)] * 3}) for i in range(3)})
    for i in range(3):
        tasks.recent_table(str(tmp_path / f"t{i}.binary"))
    kept = [p for p in tasks._RECENT_TABLES if p.startswith(str(tmp_path))]
    assert len(tasks._RECENT_TABLES) <= tasks._RECENT_KEPT
    assert kept[-1].endswith("t2.binary")


def _rss_mib() -> float:
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20


@pytest.mark.skipif(not os.path.exists("/proc/self/statm") or heap._libc() is None,
                    reason="glibc on Linux only: elsewhere the heap keeps its own policy")
def test_freed_memory_is_kept_while_working_and_given_back_when_idle():
    assert heap.keep_freed_memory()
    block = np.ones(50_000_000)  # 400 MB, a table-sized block's big sibling
    before_free = _rss_mib()
    del block
    kept = _rss_mib()
    assert kept > before_free - 100  # freed, but still the process's: reused next pass
    assert heap.give_memory_back()
    assert _rss_mib() < kept - 300  # an idle worker hands it back
