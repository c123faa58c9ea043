"""Command-line plumbing shared by ``python -m imu_dcm.replay`` and ``python -m data_synth``."""

from __future__ import annotations

import argparse
from typing import NoReturn


class OneLineArgumentParser(argparse.ArgumentParser):
    """argparse that reports a bad option in one line (no usage dump) and exits with status 2.

    Sub-command parsers made by ``add_subparsers`` inherit the class.
    """

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {message}\n")
