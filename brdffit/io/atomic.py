"""Files written whole or not at all, with the permissions a plain ``open`` gives.

A reader (a viewer refreshing a plot, a cluster worker reading a table) sees either
the old file or the complete new one: the bytes go to a temporary file beside the
target, which is then renamed over it. ``tempfile.mkstemp`` creates that file 0600,
which would hide a plot or a table from everyone else whatever the umask says, so it
is given ``0666 & ~umask``, as ``open(path, "wb")`` would.
"""

from __future__ import annotations

import contextlib
import os
import tempfile


def write_bytes(path: str | os.PathLike, data: bytes, prefix: str = ".part-") -> None:
    """Write ``data`` to ``path`` atomically (temp file + rename)."""
    path = os.fspath(path)
    fd, tmp = tempfile.mkstemp(prefix=prefix, dir=os.path.dirname(os.path.abspath(path)))
    try:
        os.fchmod(fd, 0o666 & ~_umask())
        with os.fdopen(fd, "wb") as f:
            f.write(data)
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise


def _umask() -> int:
    # reading the umask means setting it; no thread of brdffit creates files meanwhile
    mask = os.umask(0)
    os.umask(mask)
    return mask
