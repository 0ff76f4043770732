"""Write requirements/service.lock from a ``pip install --dry-run --report`` file
(see the lock's header for the whole command): each resolved package but brdffit,
pinned, with the sha256 of the file pip chose."""

from __future__ import annotations

import json
import sys
from pathlib import Path

LOCK = Path(__file__).with_name("service.lock")


def main(report_path: str) -> None:
    header = [line for line in LOCK.read_text().splitlines() if line.startswith("#")]
    report = json.loads(Path(report_path).read_text())
    pins = []
    for item in sorted(report["install"], key=lambda i: i["metadata"]["name"].lower()):
        meta = item["metadata"]
        if meta["name"] == "brdffit":
            continue
        digest = item["download_info"]["archive_info"]["hashes"]["sha256"]
        pins.append(f"{meta['name']}=={meta['version']} \\\n    --hash=sha256:{digest}")
    sys.stdout.write("\n".join(header + [""] + pins) + "\n")


if __name__ == "__main__":
    main(sys.argv[1])
