"""The sim-to-real gap diagnosis (DESIGN §6): :func:`diagnose` -> :class:`Diagnosis`.

Modules, one concept each (with :mod:`fitstiff.signal.noise`, the noise floor from the data
alone): :mod:`~fitstiff.diagnosis.supermodel` (the baseline and every candidate as one
compiled model with run-time masks), :mod:`~fitstiff.diagnosis.gap` (where: held-out residuals
by region), :mod:`~fitstiff.diagnosis.screen` (which: score statistics and detectability),
:mod:`~fitstiff.diagnosis.select` (how far: held-out folds and the acceptance rule),
:mod:`~fitstiff.diagnosis.prune` (the backward check of the accepted effects),
:mod:`~fitstiff.diagnosis.structure` (what the unexplained rest follows),
:mod:`~fitstiff.diagnosis.diagnose` (the whole) and :mod:`~fitstiff.diagnosis.result`.
The underscore modules are their parts: ``_rounds`` (the greedy search), ``_refit`` (a
candidate's held-out refit), ``_choice`` (ties and pairs), ``_candidates`` (the candidate
records), ``_verdict`` (the words), ``_structure_forms``, ``_structure_basis`` and
``_structure_record`` (the descriptions' vocabulary, fit and record).
"""

from fitstiff.diagnosis.diagnose import ALPHA, MIN_SHRINK, diagnose
from fitstiff.diagnosis.result import Candidate, Diagnosis

__all__ = ["ALPHA", "HELDOUT", "MIN_SHRINK", "RESULT", "Candidate", "Diagnosis", "diagnose"]

#: the result file of ``fitstiff diagnose`` and the held-out residuals beside it
RESULT = "diagnosis.json"
HELDOUT = "heldout.npz"
