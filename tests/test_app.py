"""What every command shares (imu_dcm.app): the exit-code wrapper, the --rerun mode, the bias
and start-attitude checks, the summary figures. The commands' own tests drive them end to end;
these state each rule once, on its own."""

from __future__ import annotations

import dataclasses
import json
import math
import sys
import threading
import warnings

import numpy as np
import pytest

from imu_dcm.app.beside import Beside
from imu_dcm.app.checks import check_bias, check_init_q_w_b
from imu_dcm.app.options import parse_init_q_w_b
from imu_dcm.app.rerun_mode import check_rerun_mode, rerun_save_path
from imu_dcm.app.run import (
    EXIT_BAD_INPUT,
    EXIT_INTERRUPTED,
    EXIT_OK,
    Terminated,
    error_line,
    run_main,
)
from imu_dcm.app.summary import RunFigures
from imu_dcm.errors import InputError
from imu_dcm.gyro.rates import MAX_RATE_RAD_S

Q_Z90 = [0.0, 0.0, math.sqrt(0.5), math.sqrt(0.5)]  # 90° about z, [x, y, z, w]


def _raises(exc: BaseException):
    def body(argv):
        raise exc

    return body


def test_run_main_turns_what_the_body_raised_into_a_code_and_one_line(capsys):
    assert run_main("tool", lambda argv: 7, ["a"]) == 7
    assert run_main("tool", _raises(InputError("Expected x, got y\nmore")), []) == EXIT_BAD_INPUT
    assert capsys.readouterr().err == "tool: error: Expected x, got y\n"
    assert run_main("tool", _raises(KeyboardInterrupt()), [], interrupted="stop") == 130
    assert capsys.readouterr().err == "tool: error: stop\n"
    assert EXIT_INTERRUPTED == 130
    assert run_main("tool", _raises(Terminated()), []) == 143  # SIGTERM
    assert capsys.readouterr().err == "tool: error: terminated\n"
    assert run_main("tool", _raises(SystemExit(0)), []) == EXIT_OK  # --help
    assert run_main("tool", _raises(BrokenPipeError()), []) == EXIT_OK
    assert capsys.readouterr().err == ""


def test_run_main_says_each_warning_once_in_one_line(capsys):
    def body(argv):
        warnings.warn("first line\nsecond line", stacklevel=1)
        return 0

    assert run_main("tool", body, []) == 0
    assert capsys.readouterr().err == "tool: warning: first line\n"


def test_an_os_error_names_its_file():
    line = error_line(PermissionError(13, "Permission denied", "/x/out.csv"))
    assert "PermissionError" in line and "Permission denied" in line and "/x/out.csv" in line


def test_rerun_modes(monkeypatch):
    monkeypatch.delenv("RERUN", raising=False)
    for mode in (None, "spawn", "serve", "off", "save:a/b.rrd"):
        assert check_rerun_mode(mode) == mode
    assert rerun_save_path("save:a/b.rrd") == "a/b.rrd" and rerun_save_path("serve") is None
    for bad in ("web", "SPAWN", "save:", "save:.rrd", "save:out.txt", 3):
        with pytest.raises(InputError, match="--rerun"):
            check_rerun_mode(bad)
    monkeypatch.setenv("RERUN", "off")  # rerun's own switch: the default shows nothing
    assert check_rerun_mode(None) == "off"
    with pytest.raises(InputError, match="RERUN=off"):
        check_rerun_mode("save:a.rrd")


def test_one_bias_check():
    assert check_bias("auto") == "auto" and check_bias("none") == "none"
    b = check_bias([0.01, -0.02, 0.0])
    assert b.dtype == np.float64 and b.tolist() == [0.01, -0.02, 0.0]
    for bad in ("sometimes", [0.1, 0.2], [0.1, np.nan, 0.0], [[0.1, 0.2, 0.3]], "1,2,3"):
        with pytest.raises(InputError, match="bias"):
            check_bias(bad)
    with pytest.raises(InputError, match=f"{MAX_RATE_RAD_S:g}"):  # no gyro's rate is larger
        check_bias([0.0, 0.0, 2 * MAX_RATE_RAD_S])


def test_one_start_attitude_check():
    assert check_init_q_w_b(None) is None
    np.testing.assert_allclose(check_init_q_w_b([0.0, 0.0, 2.0, 2.0]), Q_Z90, atol=1e-15)
    for bad in ([0.0, 0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, np.inf, 1.0]):
        with pytest.raises(InputError, match="init_q_w_b"):
            check_init_q_w_b(bad)
    assert parse_init_q_w_b("0,0,0.7071067811865476,0.7071067811865476") == pytest.approx(Q_Z90)
    with pytest.raises(InputError, match="--init-quat x,y,z,w"):
        parse_init_q_w_b("1,2")


def test_run_figures_are_a_frozen_record_and_json_ready():
    fields = {f.name: None for f in dataclasses.fields(RunFigures)}
    f = RunFigures(**{**fields, "gaps": ((1.5, 0.25),), "rate_hz": float("nan")})
    with pytest.raises(dataclasses.FrozenInstanceError):
        f.samples = 3
    d = json.loads(json.dumps(f.to_dict(), allow_nan=False))
    assert d["gaps"] == [{"t_s": 1.5, "length_s": 0.25}] and d["rate_hz"] is None
    assert set(d) == set(fields)


@pytest.mark.parametrize(
    ("env", "numpy_first", "huge"),
    [(None, False, False), (None, True, False), ("1", False, True), ("1", True, True)],
    ids=["before-numpy", "after-numpy", "env-obeyed-before", "env-obeyed-after"],
)
def test_a_commands_arrays_ask_for_ordinary_pages_unless_the_environment_says(
    env, numpy_first, huge
):
    # whether numpy still asks for huge pages, read back from its own switch in a fresh process
    import os
    import subprocess
    import sys

    code = (
        ("import numpy\n" if numpy_first else "")
        + "from imu_dcm.app.pages import numpy_small_pages\nnumpy_small_pages()\n"
        + "import numpy as np\ncore = getattr(np, '_core', None) or np.core\n"
        + "print(core.multiarray._set_madvise_hugepage(True))\n"
    )
    environ = {k: v for k, v in os.environ.items() if k != "NUMPY_MADVISE_HUGEPAGE"}
    if env is not None:
        environ["NUMPY_MADVISE_HUGEPAGE"] = env
    got = subprocess.run([sys.executable, "-c", code], env=environ, capture_output=True, text=True)
    assert got.returncode == 0, got.stderr
    assert got.stdout.strip() == str(huge)


def test_a_pass_beside_gives_its_value_and_ends_its_thread():
    before = threading.active_count()
    side = Beside(sorted, [3, 1, 2])
    assert side.then(max, 4, 5) == ([1, 2, 3], 5)
    assert threading.active_count() == before  # joined: a batch may fork after it


def test_two_passes_side_by_side_raise_as_they_would_in_order():
    def fails(what):
        raise ValueError(what)

    with pytest.raises(ValueError, match="first"):  # both fail: the first pass's error
        Beside(fails, "first").then(fails, "second")
    with pytest.raises(ValueError, match="second"):  # only the second fails
        Beside(sorted, [1]).then(fails, "second")
    with pytest.raises(ValueError, match="first"):  # only the first fails
        Beside(fails, "first").then(max, 1, 2)
    side = Beside(fails, "again")
    with pytest.raises(ValueError, match="again"):
        side.result()


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's malloc settings")
@pytest.mark.parametrize("reuse", [False, True])
def test_a_commands_freed_arrays_are_reused_without_touching_fresh_pages(reuse):
    # an array of 64 MB made, freed and made again: with the command's setting the second
    # comes from the pages the first touched (few page faults), without it from fresh ones
    # (one fault a page at least); counted by the kernel, in a fresh process
    import os
    import subprocess

    code = (
        "import resource, numpy as np\n"
        + (
            "from imu_dcm.memory import keep_freed_memory\nassert keep_freed_memory()\n"
            if reuse
            else ""
        )
        + "n = 8 << 20\na = np.ones(n); del a\n"
        + "f0 = resource.getrusage(resource.RUSAGE_SELF).ru_minflt\n"
        + "b = np.ones(n)\n"
        + "print(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - f0)\n"
    )
    environ = {
        k: v
        for k, v in os.environ.items()
        if k not in ("MALLOC_MMAP_MAX_", "MALLOC_TRIM_THRESHOLD_")
    }
    environ["NUMPY_MADVISE_HUGEPAGE"] = "0"  # 4 KiB pages: 16384 of them in 64 MB
    got = subprocess.run([sys.executable, "-c", code], env=environ, capture_output=True, text=True)
    assert got.returncode == 0, got.stderr
    faults, pages = int(got.stdout), (8 << 20) * 8 // 4096
    if reuse:
        assert faults < pages // 10
    else:
        assert faults >= pages


def test_an_interrupt_beside_a_pass_goes_up_at_once():
    # Ctrl-C (or SIGTERM's Terminated) on the caller's thread does not wait for the other pass
    import time

    release = threading.Event()
    side = Beside(release.wait, 30.0)

    def interrupted():
        raise KeyboardInterrupt

    t0 = time.perf_counter()
    with pytest.raises(KeyboardInterrupt):
        side.then(interrupted)
    assert time.perf_counter() - t0 < 5.0  # not the other pass's 30 s
    release.set()
    assert side.result() is True
