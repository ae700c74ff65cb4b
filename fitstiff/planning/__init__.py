"""What to record next (issue 33): :func:`plan` -> :class:`Plan`, the rig programs that settle
what a diagnosis could not.

Modules, one concept each: :mod:`~fitstiff.planning.rivals` (the confusions of a diagnosis and
their rival models fitted to the logs), :mod:`~fitstiff.planning.separation` (how far a program
separates two rivals once they refit), :mod:`~fitstiff.planning.families` (the programs a plan
chooses from, and the rig's limits) and :mod:`~fitstiff.planning.plan` (the search and the
result).
"""

from fitstiff.planning.families import Limits
from fitstiff.planning.plan import Plan, PlannedProgram, plan

__all__ = ["Limits", "Plan", "PlannedProgram", "plan", "PLAN", "PLAN_DIR"]

#: the result file of ``fitstiff plan``
PLAN = "plan.json"
#: where ``fitstiff plan`` and ``fitstiff diagnose`` put a plan inside a diagnosis directory
#: (the diagnosis report draws it from there)
PLAN_DIR = "plan"
