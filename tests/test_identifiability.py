"""Identifiability: fits that never claim what the data cannot show (issue 16).

A single 2 mm ramp (no reversal) is matched as well by (sigma0, Fc) = (40 N/mm, 18 N) starting
at rest as by (20 N/mm, 9 N) starting from the opposite saturation; a one-amplitude log inside
the pre-sliding range never shows the breakaway. Both must say ``identifiable: false`` with
the reason, give no standard error for what they cannot determine (JSON null), say so on
stdout and in red at the top of the report. The bundled multi-amplitude logs stay identifiable.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from fitstiff.cli import main
from fitstiff.data import fig4_logs, paper_rig
from fitstiff.inference.fitting import fit
from fitstiff.inference.identifiability import assess_identifiability, reversal_travel
from fitstiff.io.loading import load_logs
from fitstiff.physics.programs import Ramp, TriangleCycles
from fitstiff.physics.simulate import simulate, write_log
from fitstiff.present.report import write_report


def _simulate(program, rig, seed=1):
    return simulate("chamber+dahl", program, rig=rig, params={"sigma0": 40, "Fc": 18},
                    seed=seed, name="log")


@pytest.fixture(scope="module")
def ramp_run(tmp_path_factory):
    """``fitstiff fit`` on one 2 mm ramp, and the report of it: (fit.json, stdout, page)."""
    from fitstiff.io.log import Rig

    rig = Rig.from_mapping(paper_rig())
    root = tmp_path_factory.mktemp("ramp")
    sim = _simulate(Ramp(distance_mm=2.0, rate_mm_s=1.0), rig)
    log = root / "ramp.csv"
    write_log(sim.log, log, truth=sim.truth)
    out = root / "fit"
    import contextlib
    import io

    stdout = io.StringIO()
    with contextlib.redirect_stdout(stdout):
        assert main(["fit", str(log), "--out", str(out)]) == 0
    page = write_report(out).read_text(encoding="utf-8")
    return json.loads((out / "fit.json").read_text()), stdout.getvalue(), page


def test_ramp_is_not_identifiable(ramp_run):
    result, _, _ = ramp_run
    assert result["converged"] is True              # the solver is happy; the data are not
    assert result["identifiable"] is False
    assert result["identifiable_reason"].startswith("no log reverses direction")
    details = result["identifiability"]
    assert details["reversals"] == 0
    assert set(details["parameters"]) == {"sigma0", "Fc"}
    # the Jacobian check finds the same trade-off on its own
    assert any("sigma0" in d and "Fc" in d and "friction_state0" in d
               for d in details["null_directions"])


def test_ramp_withholds_the_affected_standard_errors(ramp_run):
    result, _, _ = ramp_run
    for name in ("sigma0", "Fc"):
        assert result["parameters"][name]["stderr"] is None
    for name in ("presliding_slope_N_per_mm", "breakaway_N", "total_stiffness_N_per_mm"):
        assert result["derived"][name]["stderr"] is None
    # what the data do determine keeps its error
    assert result["parameters"]["n"]["stderr"] > 0
    assert result["derived"]["chamber_stiffness_N_per_mm"]["stderr"] > 0


def test_ramp_says_so_on_stdout_in_one_line(ramp_run):
    _, stdout, _ = ramp_run
    lines = [ln for ln in stdout.splitlines() if ln.startswith("identifiable:")]
    assert len(lines) == 1
    assert lines[0].startswith("identifiable: NO - no log reverses direction")


def test_ramp_report_shows_it_in_red(ramp_run):
    _, _, page = ramp_run
    verdict = page[page.index('<div class="verdict'):]
    verdict = verdict[:verdict.index("</div>")]
    assert verdict.startswith('<div class="verdict bad">')
    assert "The data do NOT identify the seal parameters: no log reverses direction" in verdict
    assert "The fit converged" in verdict           # still said, below the headline


def test_one_amplitude_inside_the_presliding_range_is_not_identifiable(paper_rig):
    sim = _simulate(TriangleCycles(amplitudes_mm=(0.1,), cycles=3, rate_mm_s=1.0), paper_rig)
    result = fit([sim.log], "chamber+dahl")
    ident = result.identifiability
    assert not ident.identifiable
    assert ident.reason.startswith("the seal never saturates")
    assert ident.longest_travel_mm == pytest.approx(0.2, abs=0.01)
    doc = result.to_dict()
    assert doc["identifiable"] is False
    assert doc["parameters"]["Fc"]["stderr"] is None
    assert doc["derived"]["breakaway_N"]["stderr"] is None
    assert doc["derived"]["presliding_range_mm"]["stderr"] is None
    # the slope right after a reversal is measured
    assert doc["derived"]["presliding_slope_N_per_mm"]["stderr"] > 0


def test_bundled_multi_amplitude_logs_are_identifiable():
    logs = load_logs(fig4_logs())
    result = fit(logs, "chamber+dahl")
    doc = result.to_dict()
    assert doc["identifiable"] is True and doc["identifiable_reason"] is None
    assert doc["identifiability"]["null_directions"] == []
    for name in ("presliding_slope_N_per_mm", "breakaway_N"):
        assert doc["derived"][name]["stderr"] > 0
    assert result.table().splitlines()[1].startswith("identifiable: yes (40 reversals")


def test_travel_counts_only_samples_the_fit_uses():
    x = np.concatenate([np.linspace(0, 1e-3, 11), np.linspace(1e-3, -1e-3, 21)[1:]])
    assert reversal_travel([x], [np.array([10])]) == (1, pytest.approx(2e-3))
    w = np.ones_like(x)
    w[15:] = 0
    assert reversal_travel([x], [np.array([10])], [w]) == (1, pytest.approx(0.4e-3))


def test_a_model_without_a_seal_is_identifiable():
    ident = assess_identifiability(names=["n"], seal=[], levels=[], reversals=0,
                                   longest_travel_m=None, derived={})
    assert ident.identifiable and ident.reason is None
