"""``python -m data_synth SCENE [options] --rate HZ --duration S --out DIR`` (data_synth.cli)."""

import sys

from data_synth.cli import main

if __name__ == "__main__":
    sys.exit(main())
