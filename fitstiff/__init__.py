"""fitstiff: passive stiffness of pneumatic cylinders from force-displacement logs.

The flow, each step a verb with a result noun (and a ``fitstiff`` subcommand)::

    load_logs -> segment -> build_model -> fit -> sample_posterior -> diagnose -> write_report
       Log    Segmentation    Model     FitResult    Posterior       Diagnosis    report.html

and from a diagnosis to the next rig run: ``plan(diagnosis, logs) -> Plan``.

``import fitstiff`` is cheap: the names below are imported on first use (JAX and the solvers
load only when a model, fit, posterior or diagnosis is asked for).
"""

from __future__ import annotations

import importlib

__version__ = "0.1.0"

from fitstiff.errors import FitstiffError, InputError  # noqa: E402

#: public name -> the module that defines it (``import fitstiff`` imports no NumPy either:
#: the command line's first instant, in which a Ctrl-C must end it cleanly, stays short)
_LAZY = {
    "Log": "fitstiff.io.log", "Rig": "fitstiff.io.log",
    "load_log": "fitstiff.io.loading", "load_logs": "fitstiff.io.loading",
    "segment": "fitstiff.segments.segmentation", "Segmentation": "fitstiff.segments.segmentation",
    "build_model": "fitstiff.physics.model", "Model": "fitstiff.physics.model",
    "fit": "fitstiff.inference.fitting", "FitResult": "fitstiff.inference.fitting",
    "sample_posterior": "fitstiff.inference.posterior", "Posterior": "fitstiff.inference.posterior",
    "simulate": "fitstiff.physics.simulate", "Noise": "fitstiff.physics.simulate",
    "diagnose": "fitstiff.diagnosis", "Diagnosis": "fitstiff.diagnosis",
    "plan": "fitstiff.planning", "Plan": "fitstiff.planning", "Limits": "fitstiff.planning",
    "write_report": "fitstiff.present.report",
    "fit_fleet": "fitstiff.fleet",
}

__all__ = ["FitstiffError", "InputError", "__version__", *_LAZY]


def __getattr__(name: str):
    if name in _LAZY:
        value = getattr(importlib.import_module(_LAZY[name]), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'fitstiff' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(__all__)
