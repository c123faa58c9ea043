"""Tests of ``--plot`` (imu_dcm.replay.plot): the figure is written whole, at its size, in the
format its suffix names, with the title naming the log and the truth; bad paths are refused
before the log is read; the envelope that thins long series keeps every extreme.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET

import numpy as np
import pytest
from conftest import assert_names

pytest.importorskip("matplotlib")

from imu_dcm.replay.__main__ import main
from imu_dcm.replay.plot import envelope


@pytest.fixture(scope="module")
def top_log(tmp_path_factory):
    """A sleeping top with a z bias (an error that grows, a rest-free log), 10 s at 200 Hz."""
    from data_synth.cli import main as synth_main

    out = tmp_path_factory.mktemp("synth") / "sleeping"
    args = ["heavy-top", "--motion", "sleeping", "--rate", "200", "--duration", "10"]
    assert synth_main([*args, "--gyro-bias", "0,0,0.002", "--out", str(out)]) == 0
    return out


def test_plot_png_is_written_at_its_size(top_log, tmp_path, capsys):
    from matplotlib.image import imread

    out = tmp_path / "figs" / "run.png"  # a missing parent folder is created
    assert main([str(top_log), "--rerun", "off", "--bias", "none", "--plot", str(out)]) == 0
    written = [x for x in capsys.readouterr().out.splitlines() if x.startswith("written ")]
    assert written and str(out) in written[0]  # named among what the command wrote
    img = imread(out)
    assert img.shape[:2] == (770, 1320)  # 12 x 7 in at 110 dpi
    assert [p.name for p in out.parent.iterdir()] == ["run.png"]  # no temporary file left


def test_plot_svg_names_the_log_and_the_truth(top_log, tmp_path):
    out = tmp_path / "run.svg"
    assert main([str(top_log), "--rerun", "off", "--plot", str(out)]) == 0
    ET.parse(out)  # whole, well-formed XML
    # matplotlib draws text as paths and writes each text beside it as an XML comment
    raw = out.read_text()
    assert "<!-- sleeping/sleeping.mcap: magnus4 against /ground_truth/orientation -->" in raw
    assert "<!-- attitude error (°) -->" in raw
    assert "<!-- gyro rate as read (rad/s) -->" in raw


@pytest.mark.parametrize("name", ["run.jpg", "run"])
def test_plot_other_suffixes_are_refused_before_reading(top_log, tmp_path, capsys, name):
    code = main([str(top_log), "--rerun", "off", "--plot", str(tmp_path / name)])
    err = capsys.readouterr().err
    assert code == 2
    assert_names(err, "--plot", ".png", ".svg", str(tmp_path / name))
    assert list(tmp_path.iterdir()) == []


def test_envelope_keeps_every_extreme():
    rng = np.random.default_rng(5)
    t = np.arange(100_000) * 1e-3
    y = rng.normal(size=t.size)
    y[12_345] = 40.0  # one spike
    y[50_000:50_100] = np.nan  # a break
    tt, yy = envelope(t, y, bins=500)
    assert len(tt) == len(yy) == 1000
    assert np.nanmax(yy) == 40.0 and np.nanmin(yy) == np.nanmin(y)
    assert np.all(np.diff(tt) >= 0)
    t900, y900 = t[:900], y[:900]
    assert all(a is b for a, b in zip(envelope(t900, y900, bins=500), (t900, y900), strict=True))
