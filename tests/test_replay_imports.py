"""The replay command imports what it uses: not scipy's rotations, the viewer or the writers.

Behaviour, not speed: each case runs in a fresh interpreter and lists the modules it imported
(``python -X importtime``, or ``sys.modules`` after :func:`imu_dcm.replay.replay`). scipy's
``spatial.transform`` alone costs more start-up than reading and integrating the shipped trial;
the project's own ``so3`` does what a replay needs of it. (numba, while the kernel needs it,
imports ``scipy.linalg`` for its BLAS bindings; without numba nothing imports scipy at all.)
"""

from __future__ import annotations

import os
import re
import subprocess
import sys

import pytest
from conftest import REPO_ROOT, STRANGERS, need_data

TRIAL = REPO_ROOT / "replay" / "broad_07_undisturbed_fast_rotation_B"
ULOG = STRANGERS / "sample_log_small.ulg"
#: Imported only by paths a plain replay does not take (--rerun, --prefilter, --out, batch, a
#: summary file, --plot).
NOT_ON_THE_PATH = (
    "scipy.spatial",
    "rerun",
    "filterpy",
    "imu_dcm.viz",
    "imu_dcm.gyro.prefilter",
    "imu_dcm.logio.writers",
    "imu_dcm.outputs",
    "imu_dcm.replay.batch",
    "mcap_ros2",
    "matplotlib",
    "imu_dcm.replay.plot",
)


def _env() -> dict[str, str]:
    env = dict(os.environ, PYTHONPATH=str(REPO_ROOT), CI="true")
    env.pop("DISPLAY", None)
    return env


def _unexpected(modules: set[str]) -> list[str]:
    """The modules of :data:`NOT_ON_THE_PATH` (or their submodules) among ``modules``; any
    scipy module at all when numba was not imported."""
    banned = NOT_ON_THE_PATH if "numba" in modules else (*NOT_ON_THE_PATH, "scipy")
    return sorted(m for m in modules if any(m == b or m.startswith(b + ".") for b in banned))


def _run(args: list[str], cwd) -> subprocess.CompletedProcess:
    """Run ``args`` in ``cwd`` with this tree importable; it must succeed."""
    res = subprocess.run(args, capture_output=True, text=True, timeout=300, cwd=cwd, env=_env())
    assert res.returncode == 0, res.stderr[-2000:]
    return res


def test_the_replay_command_imports_no_scipy_rotation_viewer_or_writer(tmp_path):
    args = [sys.executable, "-X", "importtime", "-m", "imu_dcm.replay", str(TRIAL)]
    res = _run([*args, "--rerun", "off", "--quiet"], tmp_path)
    modules = set(re.findall(r"^import time:\s+\d+ \|\s+\d+ \|\s*(\S+)$", res.stderr, re.M))
    assert "imu_dcm.replay.mounting" in modules and "imu_dcm.so3" in modules  # it did parse
    assert _unexpected(modules) == []
    assert "importlib.metadata" not in modules or "numba" in modules  # --version only
    # The readers of other containers load when their row opens a log, not for a ROS bag.
    others = {
        "imu_dcm.logio.containers.ulog",
        "imu_dcm.logio.containers.ardupilot",
        "imu_dcm.logio.containers.euroc",
    }
    assert others & modules == set()


@pytest.mark.parametrize("log", [TRIAL, ULOG], ids=["shipped trial", "PX4 ULog"])
def test_replay_api_imports_no_scipy_rotation(log, tmp_path):
    need_data(log)
    code = (
        "import sys, warnings\n"
        "warnings.simplefilter('ignore')\n"
        "from imu_dcm.replay import replay\n"
        f"res = replay({str(log)!r})\n"
        "assert res.summary.samples > 0\n"
        "print('\\n'.join(sorted(sys.modules)))\n"
    )
    res = _run([sys.executable, "-c", code], tmp_path)
    modules = set(res.stdout.split())
    assert "imu_dcm.replay.mounting" in modules
    assert _unexpected(modules) == []
