"""``python -m brdffit.models --write-catalogue``: rewrite the catalogue snapshot after
changing a built-in model (without the flag: check it, exit 1 if out of date)."""

import argparse
import sys

from brdffit.models.catalogue import SNAPSHOT, snapshot
from brdffit.models.registry import BUILTIN

parser = argparse.ArgumentParser(prog="python -m brdffit.models",
                                 description="Check or rewrite the model catalogue snapshot.")
parser.add_argument("--write-catalogue", action="store_true", help=f"rewrite {SNAPSHOT.name}")
args = parser.parse_args()
fresh = snapshot(BUILTIN)
if args.write_catalogue:
    SNAPSHOT.write_text(fresh)
    print(f"wrote {SNAPSHOT}")
elif SNAPSHOT.read_text() != fresh:
    sys.exit(f"{SNAPSHOT} is out of date: run python -m brdffit.models --write-catalogue")
