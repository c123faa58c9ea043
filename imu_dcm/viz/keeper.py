"""Keeps a server and removes its temporary folder when it ends: ``python keeper.py FOLDER -- CMD``.

Run as a script (standard library only: the package is not imported), as the leader of the
server's session. It starts ``CMD`` as its child and waits; ``SIGTERM``, ``SIGINT`` or ``SIGHUP``
to it (``kill PID``) or to the whole group (``kill -- -PID``) ends the child (SIGTERM, then
SIGKILL after 5 s), and when the child is gone, however it ended, ``FOLDER`` is removed. This is
how a web viewer left running (``--rerun serve --keep-viewer``) stops with one ``kill`` and
leaves nothing in the temporary folder. Exit code: the child's.
"""

from __future__ import annotations

import shutil
import signal
import subprocess
import sys

STOP_SIGNALS = (signal.SIGTERM, signal.SIGINT, signal.SIGHUP)
GRACE_S = 5.0


def keep(folder: str, cmd: list[str]) -> int:
    """Run ``cmd`` until it ends or a stop signal comes; then remove ``folder``."""
    child = subprocess.Popen(cmd)

    def stop(signum, frame) -> None:
        if child.poll() is None:
            child.terminate()

    for sig in STOP_SIGNALS:
        signal.signal(sig, stop)
    try:
        try:
            code = child.wait()
        except subprocess.TimeoutExpired:  # pragma: no cover - wait() has no timeout
            code = -1
        if child.poll() is None:  # pragma: no cover - defensive
            child.kill()
            code = child.wait(GRACE_S)
    finally:
        shutil.rmtree(folder, ignore_errors=True)
    return code


def main(argv: list[str]) -> int:
    if len(argv) < 3 or argv[1] != "--":
        print("usage: keeper.py FOLDER -- CMD [ARG...]", file=sys.stderr)
        return 2
    return keep(argv[0], argv[2:])


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
