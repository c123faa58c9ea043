"""Every file a command writes passes through one output rule: this package.

:mod:`~imu_dcm.outputs.rule` says what may be written where (ours or new, never an input, no link
to a file, streams written directly), :mod:`~imu_dcm.outputs.write` writes a claimed output whole
or not at all, and :mod:`~imu_dcm.outputs.signatures` recognises what this tool wrote. The names
below are the whole public face; the modules' docstrings give the rule in full.
"""

from imu_dcm.outputs.write import (
    Claim,
    OutputError,
    PendingOutput,
    atomic_path,
    check_not_input,
    check_output_dir,
    check_output_file,
    check_output_folder,
    claim_output,
    claimed_path,
    ensure_parent,
    file_kind,
    is_own_bag,
    save_figure,
    write_atomic,
    write_json,
    write_text_atomic,
    writes_to_stdout,
)

__all__ = [
    "Claim",
    "OutputError",
    "PendingOutput",
    "atomic_path",
    "check_not_input",
    "check_output_dir",
    "check_output_file",
    "check_output_folder",
    "claim_output",
    "claimed_path",
    "ensure_parent",
    "file_kind",
    "is_own_bag",
    "save_figure",
    "write_atomic",
    "write_json",
    "write_text_atomic",
    "writes_to_stdout",
]
