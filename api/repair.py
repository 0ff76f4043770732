"""Check, back up and rebuild the service's job database (docs/service.md,
"Backup and repair"). Run it with the service stopped, except ``backup``::

    python -m api.repair check   --data-dir DIR     # what the service checks at start
    python -m api.repair backup  --data-dir DIR DEST  # consistent copy, safe while serving
    python -m api.repair rebuild --data-dir DIR     # a new database from what survives

``rebuild`` moves the old database aside (``brdffit.sqlite3.damaged-<time>``,
never deleted), copies every row of it that SQLite can still read into a new one,
and registers each table file in ``tables/`` that has no row left (named
``recovered-<id>.binary``: the uploader's name was in the lost row). It prints
what it kept and what it lost; it is refused while a server holds ``DIR``.
"""

from __future__ import annotations

import argparse
import sqlite3
import sys
import time
from pathlib import Path

from api.store import DatabaseRefused, DataDirInUse, ServerLock, Store

#: The database's companions in WAL mode: they move with it.
SIDE_FILES = ("-wal", "-shm")


def _database(data_dir: Path) -> Path:
    return data_dir / "brdffit.sqlite3"


def check(data_dir: Path) -> int:
    store_path = _database(data_dir)
    try:
        Store(data_dir, store_path)
    except DatabaseRefused as e:
        print(f"refused: {e}")
        return 1
    print(f"{store_path}: ok")
    return 0


def backup(data_dir: Path, destination: Path) -> int:
    Store(data_dir, _database(data_dir)).backup(destination)
    print(f"{_database(data_dir)} -> {destination} (the table files are in {data_dir}/tables)")
    return 0


def _salvage(old: Path, table: str) -> tuple[list[dict], str | None]:
    """The rows of ``table`` SQLite can still read from ``old``, and why it stopped."""
    rows: list[dict] = []
    try:
        con = sqlite3.connect(f"file:{old}?mode=ro", uri=True)
        con.row_factory = sqlite3.Row
        try:
            for row in con.execute(f"SELECT * FROM {table}"):
                rows.append(dict(row))
        finally:
            con.close()
    except sqlite3.DatabaseError as e:
        return rows, f"{type(e).__name__}: {e}"
    return rows, None


def rebuild(data_dir: Path) -> int:
    from brdffit.errors import MerlFormatError
    from brdffit.io import readers

    path = _database(data_dir)
    aside = None
    if path.exists():
        aside = path.with_name(f"{path.name}.damaged-{time.strftime('%Y%m%dT%H%M%S')}")
        path.rename(aside)
        for suffix in SIDE_FILES:
            side = path.with_name(path.name + suffix)
            if side.exists():
                side.rename(aside.with_name(aside.name + suffix))
        print(f"moved the old database aside: {aside}")
    # Unchecked: the start check refuses tables without a database, which is the point here.
    store = Store(data_dir, path, check=False)
    kept: dict[str, int] = {}
    with store._connect() as con:
        if aside is not None:
            for table in ("tables", "jobs"):
                rows, stopped = _salvage(aside, table)
                columns = {r[1] for r in con.execute(f"PRAGMA table_info({table})")}
                n = 0
                for row in rows:
                    if table == "tables" and not store.table_path(row.get("id", "")).exists():
                        continue  # a row without its file would serve a missing table
                    names = [c for c in row if c in columns]
                    try:
                        cur = con.execute(
                            f"INSERT OR IGNORE INTO {table} ({', '.join(names)}) "
                            f"VALUES ({', '.join('?' for _ in names)})",
                            [row[c] for c in names])
                        n += cur.rowcount
                    except sqlite3.DatabaseError as e:  # a row the new layout rejects
                        print(f"  {table}: skipped a row ({e})")
                kept[table] = n
                print(f"{table}: {n} row(s) kept" + (f"; reading stopped at {stopped}"
                                                      if stopped else ""))
        known = {r[0] for r in con.execute("SELECT id FROM tables")}
    recovered = 0
    for file in sorted(store.tables_dir.glob("*.binary")):
        if file.stem in known:
            continue
        try:  # a MERL table, or a stored sample list (HDF5, by its content)
            summary = readers.table_summary(readers.read_measured(file))
        except (MerlFormatError, OSError) as e:
            print(f"  {file}: not registered ({e})")
            continue
        store.register_table(file.stem, file.stat().st_size,
                             f"recovered-{file.stem[:12]}.binary", summary)
        recovered += 1
    print(f"tables registered again from their files: {recovered}")
    print(f"{path}: rebuilt; running jobs among the kept ones are settled at the next start")
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m api.repair", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("command", choices=("check", "backup", "rebuild"))
    parser.add_argument("destination", nargs="?", help="backup: the file to write")
    parser.add_argument("--data-dir", type=Path, required=True)
    args = parser.parse_intermixed_args(argv)
    if args.command == "check":
        return check(args.data_dir)
    if args.command == "backup":
        if args.destination is None:
            parser.error("backup needs a destination file")
        return backup(args.data_dir, Path(args.destination))
    try:  # a rebuild moves the database a running server holds open: it must be stopped
        with ServerLock(args.data_dir):
            return rebuild(args.data_dir)
    except DataDirInUse as e:
        print(f"refused: {e}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
