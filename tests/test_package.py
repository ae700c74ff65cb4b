"""The package's public face."""

from __future__ import annotations

import subprocess
import sys


def test_the_public_face_is_lazy():
    """``import fitstiff`` offers the verbs and nouns of the flow without importing JAX."""
    code = ("import sys, fitstiff; assert 'jax' not in sys.modules; "
            "names = ['load_logs', 'segment', 'build_model', 'fit', 'sample_posterior', "
            "'simulate', 'write_report', 'diagnose', 'Diagnosis', 'FitResult', 'Posterior']; "
            "assert all(callable(getattr(fitstiff, n)) for n in names)")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
