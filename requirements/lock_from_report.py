"""Write requirements/service.lock from a ``pip install --dry-run --report`` file
(see the lock's header for the whole command): each resolved package but brdffit,
pinned, with the sha256 of the file pip chose. Beside it, requirements/service.requires.json:
each pinned package's own requirements (``Requires-Dist``), as that version declares them,
so that tests/test_image.py checks the lock's closure on what the lock holds, not on
whatever newer release the test environment installed (dask 2026.11.0 requires
distributed 2026.11.x; the lock's dask 2026.8.0, distributed 2026.8.x)."""

from __future__ import annotations

import json
import sys
from pathlib import Path

LOCK = Path(__file__).with_name("service.lock")
REQUIRES = Path(__file__).with_name("service.requires.json")


def main(report_path: str) -> None:
    header = [line for line in LOCK.read_text().splitlines() if line.startswith("#")]
    report = json.loads(Path(report_path).read_text())
    pins, requires = [], {}
    for item in sorted(report["install"], key=lambda i: i["metadata"]["name"].lower()):
        meta = item["metadata"]
        if meta["name"] == "brdffit":
            continue
        digest = item["download_info"]["archive_info"]["hashes"]["sha256"]
        pins.append(f"{meta['name']}=={meta['version']} \\\n    --hash=sha256:{digest}")
        requires[meta["name"]] = {"version": meta["version"],
                                  "requires_dist": meta.get("requires_dist", [])}
    REQUIRES.write_text(json.dumps(requires, indent=1, sort_keys=True) + "\n")
    sys.stdout.write("\n".join(header + [""] + pins) + "\n")


if __name__ == "__main__":
    main(sys.argv[1])
