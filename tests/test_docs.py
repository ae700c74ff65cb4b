"""The documentation site builds: ``mkdocs build --strict`` over docs/ and the API reference
made from the docstrings (issue 35). A reference that does not resolve, a docstring section
griffe cannot parse or a page missing from the nav fails here."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip("mkdocs", reason="the docs tools are in the test extra: pip install '.[test]'")
pytest.importorskip("mkdocstrings_handlers.python",
                    reason="mkdocstrings[python] is in the test extra: pip install '.[test]'")
pytest.importorskip("material", reason="mkdocs-material is in the test extra: pip install '.[test]'")

REPO = Path(__file__).resolve().parents[1]

#: objects each API page must document (their anchors are their full paths)
DOCUMENTED = {
    "fitstiff": ["fitstiff.errors.InputError", "fitstiff.units.parse_unit"],
    "io": ["fitstiff.io.loading.load_logs", "fitstiff.io.loading.load_log", "fitstiff.io.log.Log"],
    "segments": ["fitstiff.segments.segmentation.segment"],
    "physics": ["fitstiff.physics.model.build_model", "fitstiff.physics.terms.friction.Dahl"],
    "inference": ["fitstiff.inference.fitting.fit", "fitstiff.inference.fitting.FitResult",
                  "fitstiff.inference.problem.Problem",
                  "fitstiff.inference.posterior.sample_posterior"],
    "diagnosis": ["fitstiff.diagnosis.diagnose.diagnose", "fitstiff.diagnosis.result.Diagnosis"],
    "planning": ["fitstiff.planning.plan.plan", "fitstiff.planning.plan.Plan",
                 "fitstiff.planning.families.Limits"],
    "fleet": ["fitstiff.fleet.engine.fit_fleet"],
    "present": ["fitstiff.present.report.write_report", "fitstiff.present.plotting.plot_loop"],
    "signal": ["fitstiff.signal.noise.noise_floor"],
}


def test_the_docs_build_strict_with_the_api_reference(tmp_path):
    site = tmp_path / "site"
    done = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(site)],
        cwd=REPO, capture_output=True, text=True, timeout=600,
        env=os.environ | {"NO_MKDOCS_2_WARNING": "1"})
    assert done.returncode == 0, done.stderr[-4000:]
    for page, names in DOCUMENTED.items():
        html = (site / "api" / page / "index.html").read_text(encoding="utf-8")
        missing = [n for n in names if f'id="{n}"' not in html]
        assert not missing, f"api/{page}: no entry for {missing}"
    # the reST of the docstrings became Markdown (docs/_ext/rst_markup.py): no role is left as
    # text, and the public face links to where each name is defined
    pages = "".join(p.read_text(encoding="utf-8") for p in (site / "api").rglob("*.html"))
    assert not re.search(r":(func|class|meth|mod|attr|data):<code>", pages)
    face = (site / "api" / "fitstiff" / "index.html").read_text(encoding="utf-8")
    assert 'href="../inference/#fitstiff.inference.fitting.fit"' in face
