"""Shared test fixtures: the repository root, where the project's data is (:func:`need_data`:
the BROAD recordings, the real logs of other projects), and what on stderr is our program's
(:func:`assert_quiet`, :func:`own_stderr`), and what a message must name
(:func:`assert_names`, :func:`raises_naming`)."""

from __future__ import annotations

import contextlib
import linecache
import os
import re
from pathlib import Path

import pytest

REPO_ROOT = Path(__file__).resolve().parents[1]
#: The project's data, beside the repository (../shared/data); each folder has its override.
DATA_DIR = REPO_ROOT.parent / "shared" / "data"
#: The six BROAD bags (IMU_DCM_BROAD_DIR overrides).
BROAD_DIR = Path(os.environ.get("IMU_DCM_BROAD_DIR", DATA_DIR / "broad"))
#: Real logs of other projects: PX4, ArduPilot, x-IMU3 (IMU_DCM_STRANGERS_DIR overrides).
STRANGERS = Path(os.environ.get("IMU_DCM_STRANGERS_DIR", DATA_DIR / "strangers"))
BROAD_TRIALS = (
    "02_undisturbed_slow_rotation_B",
    "05_undisturbed_slow_rotation_with_breaks_B",
    "07_undisturbed_fast_rotation_B",
    "15_undisturbed_fast_translation_A",
    "21_undisturbed_fast_combined",
    "25_disturbed_tapping_B",
)


def need_data(*paths: Path) -> Path:
    """The first of ``paths``, files or folders of the project's data; skips the calling test,
    naming the first one absent, when any is."""
    missing = next((p for p in paths if not p.exists()), None)
    if missing is not None:
        pytest.skip(
            f"{missing} is absent (the project's data, ../shared/data beside the repository; "
            "IMU_DCM_BROAD_DIR and IMU_DCM_STRANGERS_DIR point elsewhere)"
        )
    return paths[0]


@pytest.fixture(scope="session")
def broad_dir() -> Path:
    """Folder holding the six BROAD bags; skips the test when any is absent."""
    need_data(*(BROAD_DIR / t / "metadata.yaml" for t in BROAD_TRIALS))
    return BROAD_DIR


@pytest.fixture(scope="session")
def repo_root() -> Path:
    return REPO_ROOT


#: Our packages: a warning naming a file in them is ours, unless it is a deprecation notice,
#: which a library raises naming the line that imports or calls it.
OUR_PACKAGES = ("imu_dcm", "data_synth")
#: The program's own warning classes (imu_dcm.errors); never a third party's.
OUR_WARNINGS = ("ImuDcmWarning", "GapWarning")
_WARNING = re.compile(r"^(?P<file>.+?):(?P<line>\d+): (?P<category>\w*Warning): ")


def _third_party_warning(line: str) -> re.Match | None:
    """``line`` as the first line Python prints for another module's warning
    (``FILE:LINE: CATEGORY: message``), else None."""
    m = _WARNING.match(line)
    if m is None or m["category"] in OUR_WARNINGS:
        return None
    ours = any(part in OUR_PACKAGES for part in Path(m["file"]).parts)
    return m if not ours or "Deprecation" in m["category"] else None


def own_stderr(stderr: str) -> str:
    """``stderr`` without the warnings of third-party modules: each one's first line, and,
    when its source line can be read, the lines of its message down to that source line
    (Python prints ``  <source>`` under the message). What is left is our program's."""
    lines, kept, k = stderr.splitlines(keepends=True), [], 0
    while k < len(lines):
        m = _third_party_warning(lines[k])
        if m is None:
            kept.append(lines[k])
            k += 1
            continue
        source = linecache.getline(m["file"], int(m["line"])).strip()
        end = next(
            (j for j in range(k + 1, len(lines)) if source and lines[j].strip() == source), k
        )
        k = end + 1
    return "".join(kept)


def assert_quiet(stderr: str) -> None:
    """No traceback and no line of our own program on ``stderr``; a third-party module's
    warning (a pending deprecation in numba, say) is not ours to forbid."""
    assert own_stderr(stderr) == "", stderr


def _names(message: str, fact: object) -> bool:
    if isinstance(fact, str):
        return fact in message
    # a number: as a number of its own, not as digits of another (2 is not in 0.25 or t_s[21])
    return re.search(rf"(?<![\w.]){re.escape(str(fact))}(?![\w]|\.\d)", message) is not None


def assert_names(message: str, *facts: object) -> None:
    """``message`` names each of ``facts`` (a path, a value, a limit, an option; a number as a
    number of its own): the facts it must give, not its wording, so that rewording passes and
    dropping a fact fails."""
    missing = [f for f in facts if not _names(message, f)]
    assert not missing, f"{message!r} does not name {missing}"


@contextlib.contextmanager
def raises_naming(exc_type: type[BaseException], *facts: object):
    """``pytest.raises(exc_type)``, whose message names each of ``facts`` (:func:`assert_names`)."""
    with pytest.raises(exc_type) as info:
        yield info
    assert_names(str(info.value), *facts)


def small_blocks(monkeypatch, rows: int) -> list[str]:
    """Make every whole-log step that works in blocks (``imu_dcm.arrays.BLOCK_ROWS``, bound by
    name in each module that uses it, data_synth's included) take ``rows`` rows at a time; the
    modules patched."""
    import sys

    import imu_dcm.arrays  # noqa: F401  (the constant's home, patched with its users)

    patched = []
    for name, mod in list(sys.modules.items()):
        if name.startswith(("imu_dcm", "data_synth")) and hasattr(mod, "BLOCK_ROWS"):
            monkeypatch.setattr(mod, "BLOCK_ROWS", rows)
            patched.append(name)
    return patched


def estimate_bag(out) -> tuple:
    """A replay's ``--out`` bag read back with the mcap library's own decoder: the estimate's
    quaternions ``[x, y, z, w]`` (n, 4) and header stamps (ns), in file order."""
    import numpy as np
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    from imu_dcm.logio import resolve_mcap_path

    q, t = [], []
    with open(resolve_mcap_path(out), "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for _, ch, _, m in reader.iter_decoded_messages():
            assert ch.topic == "/estimate/orientation"
            q.append([m.quaternion.x, m.quaternion.y, m.quaternion.z, m.quaternion.w])
            t.append(m.header.stamp.sec * 10**9 + m.header.stamp.nanosec)
    return np.array(q), np.array(t, np.int64)
