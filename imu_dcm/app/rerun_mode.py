"""The ``--rerun`` mode, parsed once for replay, live and the view: which modes exist, what a
``save:`` target looks like, and rerun's own ``RERUN`` switch (standard library only, so a
command checks its options before loading anything).

Modes (the view gives them their meaning, :func:`imu_dcm.viz.show_replay`):

* ``spawn``: start the native viewer (it needs a display);
* ``serve``: rerun's web viewer on 127.0.0.1;
* ``save:PATH.rrd``: write the recording to ``PATH.rrd``;
* ``off``: no view;
* ``None`` (the option not given): ``spawn`` with a display, else no view and no file.
"""

from __future__ import annotations

import os

from imu_dcm.errors import InputError

__all__ = [
    "RERUN_MODES",
    "RERUN_OFF_VALUES",
    "SAVE_PREFIX",
    "check_rerun_mode",
    "check_rerun_switch",
    "rerun_save_path",
    "rerun_switched_off",
]

#: The modes, as a user writes them (module doc).
RERUN_MODES = ("spawn", "serve", "save:PATH.rrd", "off")
#: The prefix of the mode that saves a recording.
SAVE_PREFIX = "save:"
#: Values of the environment variable ``RERUN`` with which rerun's SDK records nothing (its own
#: switch; compared without case: ``0``, ``false``, ``off``; any other value leaves it on).
RERUN_OFF_VALUES = ("0", "false", "off")


def rerun_save_path(mode: str | None) -> str | None:
    """The file of a ``save:PATH`` mode, else None (the mode is not checked here)."""
    if isinstance(mode, str) and mode.startswith(SAVE_PREFIX):
        return mode[len(SAVE_PREFIX) :]
    return None


def check_rerun_mode(mode: object, name: str = "--rerun") -> str | None:
    """``mode`` if it is one of :data:`RERUN_MODES` (``save:`` with a path ending in ``.rrd``)
    or None, as the environment's ``RERUN`` switch leaves it (:func:`check_rerun_switch`).

    Raises
    ------
    InputError
        Any other value (``name`` is the option or parameter named in the message), or a view
        asked for by name while ``RERUN`` turns rerun off.
    """
    target = rerun_save_path(mode)
    if target is not None and (not target.endswith(".rrd") or len(target) <= len(".rrd")):
        raise InputError(f"Expected {name} save:PATH.rrd, got {mode!r}")
    if mode is not None and target is None and mode not in ("spawn", "serve", "off"):
        raise InputError(f"Expected {name} spawn, serve, save:PATH.rrd or off, got {mode!r}")
    return check_rerun_switch(mode)


def rerun_switched_off() -> bool:
    """True when ``RERUN`` in the environment turns rerun's SDK off (:data:`RERUN_OFF_VALUES`):
    a recording would then be empty, and a viewer would get nothing."""
    return os.environ.get("RERUN", "").lower() in RERUN_OFF_VALUES


def check_rerun_switch(mode: str | None) -> str | None:
    """The ``--rerun`` mode to use under the environment's ``RERUN`` switch: ``mode`` itself
    when rerun is on; ``"off"`` for the default (None) when it is off. A view asked for by name
    (spawn, serve, save:) while it is off is refused in one line (:class:`InputError`): rerun
    would write an empty ``.rrd`` over the target, or show nothing."""
    if mode == "off" or not rerun_switched_off():
        return mode
    if mode is None:
        return "off"
    raise InputError(
        f"Expected rerun switched on for --rerun {mode}, got RERUN={os.environ['RERUN']} in "
        "the environment (rerun's own switch: unset it, or use --rerun off)"
    )
