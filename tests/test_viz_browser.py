"""End to end: a saved .rrd served by the ``rerun`` binary on 127.0.0.1, loaded into the web viewer
in headless Chromium (playwright-core, tests/e2e/screenshot.mjs), screenshot not blank.

Skips, with the reason, where Chromium, node or tests/e2e/node_modules/playwright-core is missing
(``.ci/run`` installs them). Every server started here is stopped in the fixture teardown.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import zlib
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from imu_dcm.metrics import attitude_error_deg
from imu_dcm.viz import ViewData, save_rrd, serve_rrd

E2E = Path(__file__).resolve().parent / "e2e"
CHROMIUM = Path("/usr/bin/chromium")

pytestmark = pytest.mark.slow


def _decode_png(data: bytes) -> np.ndarray:
    """Pixels of an 8-bit, non-interlaced RGB or RGBA PNG, (H, W, C) uint8, without an imaging
    library."""
    if data[:8] != b"\x89PNG\r\n\x1a\n":
        raise ValueError("not a PNG")
    pos, idat, header = 8, [], None
    while pos < len(data):
        n = int.from_bytes(data[pos : pos + 4], "big")
        kind, body = data[pos + 4 : pos + 8], data[pos + 8 : pos + 8 + n]
        if kind == b"IHDR":
            header = body
        elif kind == b"IDAT":
            idat.append(body)
        pos += 12 + n
    w, h = int.from_bytes(header[0:4], "big"), int.from_bytes(header[4:8], "big")
    depth, color, interlace = header[8], header[9], header[12]
    if depth != 8 or color not in (2, 6) or interlace != 0:
        raise ValueError(
            f"unsupported PNG: depth {depth}, colour type {color}, interlace {interlace}"
        )
    c = 3 if color == 2 else 4
    raw = np.frombuffer(zlib.decompress(b"".join(idat)), np.uint8).reshape(h, 1 + w * c)
    out = np.zeros((h + 1, w * c), np.int32)  # row 0: the zero row above the image
    for y in range(h):
        f, line, up = raw[y, 0], raw[y, 1:].astype(np.int32), out[y]
        if f == 0:
            row = line
        elif f == 2:
            row = line + up
        else:  # Sub, Average, Paeth depend on the pixel to the left: go pixel by pixel
            row = np.zeros(w * c, np.int32)
            for x in range(0, w * c, c):
                a = row[x - c : x] if x else np.zeros(c, np.int32)
                b = up[x : x + c]
                if f == 1:
                    pred = a
                elif f == 3:
                    pred = (a + b) // 2
                else:
                    cc = up[x - c : x] if x else np.zeros(c, np.int32)
                    p = a + b - cc
                    pa, pb, pc = np.abs(p - a), np.abs(p - b), np.abs(p - cc)
                    pred = np.where((pa <= pb) & (pa <= pc), a, np.where(pb <= pc, b, cc))
                row[x : x + c] = (line[x : x + c] + pred) & 0xFF
        out[y + 1] = row & 0xFF
    return out[1:].reshape(h, w, c).astype(np.uint8)


def test_png_decoder_on_a_known_image():
    # 2x2 RGB, rows filtered with Sub and Paeth, built by hand: the decoder is test code too.
    pixels = np.array([[[10, 20, 30], [40, 50, 60]], [[70, 80, 90], [100, 110, 120]]], np.uint8)
    row0 = bytes([1, 10, 20, 30, 30, 30, 30])  # Sub: second pixel minus first
    # Paeth on row 1: left=none for pixel 0 (pred = up), pixel 1: a=(70,80,90), b=(40,50,60),
    # c=(10,20,30) -> p = a+b-c = (100,110,120): |p-a| = 30, |p-b| = 60, |p-c| = 90 -> pred = a.
    row1 = bytes([4, 60, 60, 60, 30, 30, 30])
    ihdr = (2).to_bytes(4, "big") * 2 + bytes([8, 2, 0, 0, 0])

    def chunk(kind: bytes, body: bytes) -> bytes:
        crc = zlib.crc32(kind + body).to_bytes(4, "big")
        return len(body).to_bytes(4, "big") + kind + body + crc

    png = (
        b"\x89PNG\r\n\x1a\n"
        + chunk(b"IHDR", ihdr)
        + chunk(b"IDAT", zlib.compress(row0 + row1))
        + chunk(b"IEND", b"")
    )
    np.testing.assert_array_equal(_decode_png(png), pixels)


def _requirements() -> str | None:
    if not CHROMIUM.is_file():
        return f"Chromium not found at {CHROMIUM} (CI installs Debian's chromium)"
    if shutil.which("node") is None:
        return "node not found on PATH"
    if not (E2E / "node_modules" / "playwright-core").is_dir():
        return "tests/e2e/node_modules/playwright-core missing (run npm install in tests/e2e)"
    return None


def _demo_view() -> ViewData:
    """Coning (closed form) at 100 Hz, 3 s; the estimate drifts by a growing yaw error."""
    t_s = np.arange(300) / 100.0
    beta, w = np.radians(30.0), 2 * np.pi * 0.5
    truth = (
        Rotation.from_euler("z", (w * t_s)[:, None])
        * Rotation.from_euler("x", beta)
        * Rotation.from_euler("z", (-w * t_s)[:, None])
    )
    est = Rotation.from_euler("z", (4.0 * t_s)[:, None], degrees=True) * truth
    omega_b = w * np.stack(
        [-np.sin(beta) * np.sin(w * t_s), np.sin(beta) * np.cos(w * t_s), np.full_like(t_s, 0.0)],
        axis=1,
    )
    omega_b[:, 2] = w * (np.cos(beta) - 1.0)
    e = attitude_error_deg(est.as_quat(), truth.as_quat())
    return ViewData(
        t_s=t_s,
        q_est=est.as_quat(),
        q_truth=truth.as_quat(),
        omega_b=omega_b,
        error_total_deg=e.total_deg,
        error_inclination_deg=e.inclination_deg,
        error_heading_deg=e.heading_deg,
        title="browser_e2e",
    )


def _listening_addresses(port: int) -> set[str]:
    """Local addresses (hex, as in /proc/net/tcp*) of LISTEN sockets on ``port``."""
    found = set()
    for table in ("/proc/net/tcp", "/proc/net/tcp6"):
        try:
            lines = Path(table).read_text().splitlines()[1:]
        except OSError:
            continue
        for line in lines:
            fields = line.split()
            addr, port_hex = fields[1].rsplit(":", 1)
            if int(port_hex, 16) == port and fields[3] == "0A":  # 0A = TCP_LISTEN
                found.add(addr)
    return found


@pytest.fixture
def served(tmp_path):
    reason = _requirements()
    if reason:
        pytest.skip(reason)
    rrd = save_rrd(_demo_view(), tmp_path / "view.rrd")
    server = serve_rrd(rrd, log_path=tmp_path / "rerun.log")
    try:
        yield server
    finally:
        server.stop()
        assert server.process.poll() is not None, "the rerun server must be stopped"


def test_web_viewer_shows_the_recording(served, tmp_path):
    # The server listens on loopback only: 127.0.0.1 is 0100007F in /proc/net/tcp.
    if Path("/proc/net/tcp").exists():
        for port in (served.grpc_port, served.web_port):
            assert _listening_addresses(port) == {"0100007F"}, port
    out = tmp_path / "shot.png"
    cmd = ["node", str(E2E / "screenshot.mjs"), served.url, str(out)]
    cmd += ["--timeout-s", "120", "--chromium", str(CHROMIUM)]
    proc = subprocess.run(cmd, check=False, capture_output=True, text=True, timeout=240, cwd=E2E)
    report = json.loads(proc.stdout.strip().splitlines()[-1]) if proc.stdout.strip() else {}
    assert proc.returncode == 0, f"screenshot failed: {report} {proc.stderr[-2000:]}"
    img = _decode_png(out.read_bytes())[..., :3].astype(float)
    assert img.shape[:2] == (900, 1600)
    luma = img @ [0.299, 0.587, 0.114]
    # A blank (single-colour) page has std 0; the loaded view measured ~25-35 here. 10 leaves
    # room for font and theme differences and still fails a blank or near-blank page.
    assert luma.std() > 10.0, luma.std()
    # The view's own colours are on screen (independent of the script's in-page count): the true
    # x axis (220, 40, 40) and z axis (40, 90, 235) as drawn arrows, hundreds of pixels each (at
    # the last frame of this coning both lie across the line of sight; y points at the camera).
    for rgb in ([220, 40, 40], [40, 90, 235]):
        near = np.all(np.abs(img - rgb) < 40, axis=2).sum()
        assert near >= 100, (rgb, near)
