"""Shared test helpers."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

# the tests compute in 64-bit floats on the CPU, as fitstiff does (it sets the same on import)
os.environ.setdefault("JAX_PLATFORMS", "cpu")
import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)

REPO = Path(__file__).resolve().parents[1]
#: the real O-ring logs (CC0; data/real/oring/SOURCE.md)
REALDATA = REPO / "data" / "real" / "oring"

#: past this many memory maps a worker drops JAX's in-memory compilation caches (the kernel
#: refuses new maps at vm.max_map_count, 65 530 by default)
_MAX_MAPS = 30_000
#: past this resident size (MB) a worker drops them too, and returns the freed heap
_MAX_RSS_MB = 1_800


def pytest_configure(config):
    """JAX's persistent compilation cache in every test process, as the ``fitstiff`` command
    uses it: a worker compiles the same functions for hundreds of problems (the suite took
    1 864 s on 2 cores without it, 1 075 s with it). ``FITSTIFF_CACHE_DIR`` moves it; empty
    turns it off."""
    path = os.environ.get("FITSTIFF_CACHE_DIR",
                          os.path.join(os.path.expanduser("~"), ".cache", "fitstiff", "jax"))
    if path:
        jax.config.update("jax_compilation_cache_dir", path)
        jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)


#: with FITSTIFF_SUITE_MEMORY: (peak MB, test) each time a test raised this process's peak
_PEAKS: list[tuple[float, str]] = []


def _peak_mb() -> float:
    import resource

    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def pytest_sessionfinish(session, exitstatus):
    """With ``FITSTIFF_SUITE_MEMORY=DIR``, each test process writes its peak resident set
    size (MB) to ``DIR/<worker>.txt``, and the tests that raised it (the suite's memory per
    pytest worker, README)."""
    folder = os.environ.get("FITSTIFF_SUITE_MEMORY")
    if folder:
        worker = os.environ.get("PYTEST_XDIST_WORKER", "main")
        Path(folder).mkdir(parents=True, exist_ok=True)
        raised = "".join(f"{mb:.0f} MB after {test}\n" for mb, test in _PEAKS)
        (Path(folder) / f"{worker}.txt").write_text(f"{_peak_mb():.0f}\n{raised}")


def pytest_runtest_teardown(item, nextitem):
    """Executables read back from the persistent cache stay in JAX's in-memory caches with
    their memory maps (measured: 19 000 maps after 7 min of tests/test_diagnosis.py, about
    4 000 without the cache; 13 528 -> 1 506 after ``jax.clear_caches()``). A worker of the
    full suite passed the kernel's limit and segfaulted in XLA while loading one more, so the
    caches are dropped past :data:`_MAX_MAPS` (the persistent cache on disk stays). They are
    dropped too, and the freed heap handed back, once the worker holds more than
    :data:`_MAX_RSS_MB` (the suite's worker peaked at 4.3 GB keeping them all, issue 35)."""
    if os.environ.get("FITSTIFF_SUITE_MEMORY") and _peak_mb() > (
            _PEAKS[-1][0] if _PEAKS else 0.0) + 100:
        _PEAKS.append((_peak_mb(), item.nodeid))
    try:
        with open("/proc/self/maps", "rb") as maps:
            count = sum(1 for _ in maps)
        with open("/proc/self/statm", "rb") as statm:
            rss_mb = int(statm.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20
    except OSError:                  # not Linux: no such limit to watch
        return
    if count > _MAX_MAPS or rss_mb > _MAX_RSS_MB:
        import gc

        from fitstiff.malloc import trim

        jax.clear_caches()
        gc.collect()
        trim()


def run_benchmark(script: str, *args, timeout: float = 900) -> str:
    """Run ``benchmarks/<script>`` with ``args`` as its own process (as a user runs it: tests
    never import ``benchmarks/``); its stdout. A failure shows the end of its stderr."""
    done = subprocess.run([sys.executable, str(REPO / "benchmarks" / script),
                           *map(str, args)], cwd=REPO, capture_output=True, text=True,
                          timeout=timeout)
    assert done.returncode == 0, f"{script} exited {done.returncode}:\n{done.stderr[-3000:]}"
    return done.stdout


def triangle(amplitudes, *, rate=1e-3, fs=1000.0):
    """Time and displacement (SI) of a triangle program: 0 -> +a1 -> -a1 -> +a2 ... -> 0."""
    points = [0.0]
    for a in amplitudes:
        points += [a, -a]
    return polyline(points + [0.0], rate=rate, fs=fs)


def polyline(points, *, rate=1e-3, fs=1000.0):
    """Piecewise-linear displacement through ``points`` (m) at ``rate`` (m/s)."""
    t = [np.zeros(1)]
    x = [np.array([points[0]], dtype=float)]
    t0 = 0.0
    for p0, p1 in zip(points[:-1], points[1:]):
        n = max(2, int(round(abs(p1 - p0) / rate * fs)))
        u = np.linspace(0, 1, n + 1)[1:]
        t.append(t0 + u * abs(p1 - p0) / rate)
        x.append(p0 + u * (p1 - p0))
        t0 = t[-1][-1]
    return np.concatenate(t), np.concatenate(x)


@pytest.fixture
def paper_rig():
    from fitstiff.data import paper_rig
    from fitstiff.io.log import Rig

    return Rig.from_mapping(paper_rig())


CHROMIUM = shutil.which("chromium")
CHROMIUM_FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic",
                  "--no-first-run", "--disable-background-networking",
                  "--disable-component-update", "--disable-sync"]
needs_chromium = pytest.mark.skipif(CHROMIUM is None, reason="chromium is not installed "
                                    "(apt-get install chromium; .ci/run installs it)")
_IMG = re.compile(r"<img\b[^>]*\bsrc=\"([^\"]*)\"")


def _chromium(*args: str, profile: Path) -> str:
    done = subprocess.run([CHROMIUM, *CHROMIUM_FLAGS, f"--user-data-dir={profile}", *args],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr[-2000:]
    return done.stdout


def check_renders_in_chromium(report: Path, tmp_path: Path) -> None:
    """A report page as a browser shows it: a screenshot that is not blank, and every image
    loaded (a script in a test copy of the page counts images with no natural width once the
    page has loaded; one deliberately broken image proves that it counts)."""
    from matplotlib.image import imread

    shot = tmp_path / "shot.png"
    _chromium(f"--screenshot={shot}", "--window-size=1200,3000", report.as_uri(),
              profile=tmp_path / "profile")
    pixels = imread(shot)[..., :3]
    assert pixels.shape[:2] == (3000, 1200)
    assert np.mean(np.any(pixels < 0.9, axis=-1)) > 0.05           # ink, not a white page
    assert np.std(pixels) > 0.1
    page = report.read_text(encoding="utf-8")
    n_images = len(_IMG.findall(page))
    assert n_images > 0
    probe = ('<img src="data:image/png;base64,AAAA"><script>window.addEventListener("load", '
             '() => { const images = Array.from(document.images); document.title = '
             '`images ${images.length} broken ${images.filter(i => !i.complete || '
             'i.naturalWidth === 0).length}`; });</script></body>')
    copy = tmp_path / "probe.html"
    copy.write_text(page.replace("</body>", probe), encoding="utf-8")
    dom = _chromium("--virtual-time-budget=20000", "--dump-dom", copy.as_uri(),
                    profile=tmp_path / "profile")
    assert f"<title>images {n_images + 1} broken 1</title>" in dom


def page_width_in_chromium(report: Path, tmp_path: Path, *, width: int = 1280) -> int:
    """The page's layout width (``scrollWidth``) in a ``width`` px wide Chromium window: at
    most ``width`` when nothing (a table) runs off the right edge."""
    probe = ('<script>window.addEventListener("load", () => { document.title = '
             '`width ${document.documentElement.scrollWidth}`; });</script></body>')
    copy = tmp_path / "width_probe.html"
    copy.write_text(report.read_text(encoding="utf-8").replace("</body>", probe),
                    encoding="utf-8")
    dom = _chromium(f"--window-size={width},1000", "--virtual-time-budget=20000",
                    "--dump-dom", copy.as_uri(), profile=tmp_path / "profile_width")
    found = re.search(r"<title>width (\d+)</title>", dom)
    assert found, dom[:500]
    return int(found.group(1))
