"""The live view in the web viewer: a live run from the Foxglove WebSocket server (BROAD trial 07
at 5x speed) with ``rerun="serve"`` (the ``rerun`` binary bound to 127.0.0.1), then the served
recording loaded in headless Chromium (tests/e2e/screenshot.mjs) and checked from its pixels.

Skips where Chromium, node or tests/e2e/node_modules/playwright-core is missing.
"""

from __future__ import annotations

import contextlib
import json
import os
import re
import shutil
import signal
import subprocess
import threading
from pathlib import Path

import numpy as np
import pytest
from test_live_ws import TRIAL, Publisher, read_slice
from test_viz_browser import CHROMIUM, E2E, _decode_png, _listening_addresses

from imu_dcm.live import run

pytestmark = pytest.mark.slow


def _requirements() -> str | None:
    if not CHROMIUM.is_file():
        return f"Chromium not found at {CHROMIUM}"
    if shutil.which("node") is None:
        return "node not found on PATH"
    if not (E2E / "node_modules" / "playwright-core").is_dir():
        return "tests/e2e/node_modules/playwright-core missing (run npm install in tests/e2e)"
    return None


def test_web_viewer_shows_the_live_run(tmp_path):
    reason = _requirements()
    if reason:
        pytest.skip(reason)
    if not TRIAL.is_dir():
        pytest.skip("shipped trial missing")
    trial = read_slice(9000, 12000)
    pub = Publisher(trial["schemas"])
    pid = None
    said2: list[str] = []
    try:
        res: dict = {}
        th = threading.Thread(
            target=lambda: res.update(
                r=run(
                    f"ws://127.0.0.1:{pub.port}",
                    rerun="serve",
                    bias="none",
                    status=False,
                    say=said2.append,
                    idle_stop_s=1.0,
                )
            ),
            daemon=True,
        )
        th.start()
        pub.wait_subscribed()
        pub.publish(trial["messages"])
        th.join(60)
        assert not th.is_alive()
        line = next(s for s in said2 if "stays at" in s)
        url = re.search(r"(http://127\.0\.0\.1:\d+/\S+)", line).group(1)
        pid = int(re.search(r"kill (\d+)", line).group(1))
        ports = [int(p) for p in re.findall(r"127\.0\.0\.1(?::|%3A)(\d+)", line)]
        if Path("/proc/net/tcp").exists():
            for port in ports:
                assert _listening_addresses(port) == {"0100007F"}, port
        shot = tmp_path / "live_view.png"
        for _attempt in range(2):  # a loaded machine can time out Chromium's own screenshot
            proc = subprocess.run(
                [
                    "node",
                    str(E2E / "screenshot.mjs"),
                    url,
                    str(shot),
                    "--timeout-s",
                    "150",
                    "--chromium",
                    str(CHROMIUM),
                ],
                check=False,
                capture_output=True,
                text=True,
                timeout=240,
                cwd=E2E,
            )
            out = proc.stdout.strip()
            report = json.loads(out.splitlines()[-1]) if out else {}
            if report:
                break
        # A served live recording opens playing (following the stream), so its pixels may never
        # settle as the script waits for; a "timeout" with every view colour already on screen
        # is a drawn view (the last capture is written either way and checked below).
        drawn = report.get("reason") == "timeout" and all(c > 0 for c in report.get("counts", []))
        assert proc.returncode == 0 or drawn, f"screenshot failed: {report} {proc.stderr[-2000:]}"
        if os.environ.get("IMU_DCM_LIVE_SHOT"):
            shutil.copy(shot, os.environ["IMU_DCM_LIVE_SHOT"])
        img = _decode_png(shot.read_bytes())[..., :3].astype(float)
        luma = img @ [0.299, 0.587, 0.114]
        assert luma.std() > 10.0, luma.std()  # not a blank page
        # the live view's own colours: true x axis red, gyro z blue
        for rgb in ([220, 40, 40], [80, 130, 255]):
            assert np.all(np.abs(img - rgb) < 40, axis=2).sum() >= 100, rgb
        assert res["r"].summary["samples"] == 3000
    finally:
        pub.stop()
        if pid is not None:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(pid, signal.SIGTERM)
