"""``python -m imu_dcm``: the commands of the project, and how to start each.

The package itself is a library; its commands live in sub-packages. Standard library only, so
that listing them loads nothing else. Exit code 0 (the list asked for), 2 for any argument (there
is no command of that name here: the list says which to run instead).
"""

from __future__ import annotations

import sys

COMMANDS = (
    (
        "python -m imu_dcm.replay LOG",
        "imu-dcm-replay",
        "replay a recorded gyro log against its truth",
    ),
    (
        "python -m imu_dcm.replay info LOG",
        "imu-dcm-replay info",
        "what a log holds: channels, gyro, truth",
    ),
    (
        "python -m imu_dcm.replay batch PATH... --table OUT.csv",
        "imu-dcm-replay batch",
        "many logs at once, one row each",
    ),
    (
        "python -m imu_dcm.replay convert-csv CSV OUT",
        "imu-dcm-replay convert-csv",
        "a CSV log into a bag",
    ),
    (
        "python -m imu_dcm.live SOURCE",
        "imu-dcm-live",
        "integrate a running source (ws://, udp://, stdin, mavlink:)",
    ),
    ("python -m data_synth KIND --out DIR", "data-synth", "write a log whose truth is exact"),
)


def usage() -> str:
    """The list of commands, one a line, with their console scripts."""
    width = max(len(c) for c, _, _ in COMMANDS)
    lines = ["imu_dcm: strapdown attitude from gyro rates. Commands (each has --help):", ""]
    lines += [f"  {c:<{width}}  {what} (also: {script})" for c, script, what in COMMANDS]
    lines += [
        "",
        "Docs: README.md and docs/ (replay.md, batch.md, live.md, formats.md, commands.md).",
    ]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv and argv[0] not in ("-h", "--help"):
        print(
            f"python -m imu_dcm: error: Expected one of the commands below, got {argv[0]!r}",
            file=sys.stderr,
        )
        print(usage(), file=sys.stderr)
        return 2
    print(usage())
    return 0


if __name__ == "__main__":
    sys.exit(main())
