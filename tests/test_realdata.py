"""The real O-ring friction logs (shared/realdata, see SOURCE.md) with the bundled format."""

from __future__ import annotations

import hashlib
import importlib.util
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from fitstiff.loading import load_log

REALDATA = Path(__file__).resolve().parents[1].parent / "shared" / "realdata" / \
    "pneumatic-seal-friction"
SAMPLES = {1: 7139, 3: 7834, 5: 10321, 7: 8720}   # rows in O-ring_<bar>bar.csv
SLIDING_SPEED = 2e-3                               # m/s: well above reversal transients

pytestmark = pytest.mark.skipif(not REALDATA.is_dir(),
                                reason=f"real data not found at {REALDATA} (shared/ absent)")


def path_of(bar: int) -> Path:
    return REALDATA / f"O-ring_{bar}bar.csv"


@pytest.fixture(scope="module", params=sorted(SAMPLES), ids=lambda bar: f"{bar}bar")
def log_and_bar(request):
    bar = request.param
    path = path_of(bar)
    before = hashlib.sha256(path.read_bytes()).hexdigest()
    log = load_log(path, fmt="zillen_oring")
    assert hashlib.sha256(path.read_bytes()).hexdigest() == before == log.source["sha256"]
    return log, bar


def test_every_row_is_read(log_and_bar):
    log, bar = log_and_bar
    assert len(log) == SAMPLES[bar]
    assert log.source["ignored_columns"] == [2, 3, 4]   # raw volts
    assert np.all(np.diff(log.time) > 0)                # strictly increasing, nothing dropped
    assert 70 < log.duration < 110


def test_chamber_a_at_the_nominal_gauge_pressure(log_and_bar):
    log, bar = log_and_bar
    gauge = log.gauge("a") / 1e5
    assert np.median(gauge) == pytest.approx(bar, abs=0.1)
    assert np.ptp(gauge) < 0.2                          # regulated: nearly constant
    assert log.pressure_b is None and log.vented == {"b"} and log.notes == ()
    assert log.rig.bore == pytest.approx(0.025) and log.rig.stroke is None


def test_friction_opposes_motion_in_our_sign_convention(log_and_bar):
    """friction = external force - chamber force has the sign of the velocity when sliding."""
    log, _ = log_and_bar
    chamber = -log.rig.area_a * log.gauge("a")          # B vented: A_B * 0
    friction = log.force - chamber
    velocity = np.gradient(log.displacement, log.time)
    sliding = np.abs(velocity) > SLIDING_SPEED
    assert sliding.mean() > 0.9
    agree = np.mean(np.sign(friction[sliding]) == np.sign(velocity[sliding]))
    assert agree > 0.95
    assert 2 < np.median(np.abs(friction[sliding])) < 25    # N: seal friction, not p * A


@pytest.mark.skipif(importlib.util.find_spec("fitstiff.cli.inspect") is None,
                    reason="fitstiff.cli.inspect is not written yet")
def test_documented_command_reads_all_four_files():
    paths = [str(path_of(bar)) for bar in SAMPLES]
    result = subprocess.run([sys.executable, "-m", "fitstiff", "inspect", *paths,
                             "--format", "zillen_oring"], capture_output=True, text=True,
                            timeout=120)
    assert result.returncode == 0, result.stderr
    assert all(f"O-ring_{bar}bar" in result.stdout for bar in SAMPLES)
