"""Every file a command writes passes through one output rule: this package.

:mod:`~imu_dcm.outputs.rule` says what may be written where (ours or new, never an input, no link
to a file, streams written directly), :mod:`~imu_dcm.outputs.write` writes a claimed output whole
or not at all, and :mod:`~imu_dcm.outputs.signatures` recognises what this tool wrote. The names
below are the whole public face; the modules' docstrings give the rule in full.
"""

# the public face is write's __all__ (it re-exports the rule's names), listed once, there
from imu_dcm.outputs.write import *  # noqa: F403
from imu_dcm.outputs.write import __all__  # noqa: F401
