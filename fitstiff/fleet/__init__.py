"""Fleets of cylinders (issue 34): :func:`fit_fleet` -> a table, one row per cylinder and run.

Modules, one concept each: :mod:`~fitstiff.fleet.source` (where the logs are: a folder
``<cylinder>/[<run>/]*.csv`` or a manifest CSV), :mod:`~fitstiff.fleet.work` (what a worker
does with a chunk of units), :mod:`~fitstiff.fleet.engine` (chunks on Dask, the cache of
finished units) and :mod:`~fitstiff.fleet.population` (random-effects population, outliers,
drift).
"""

from fitstiff.fleet.engine import fit_fleet
from fitstiff.fleet.population import DEFAULT_Q, Population, population
from fitstiff.fleet.source import Unit, discover

__all__ = ["fit_fleet", "discover", "population", "Population", "Unit", "DEFAULT_Q",
           "FLEET", "POPULATION"]

#: the result files of ``fitstiff fleet``
FLEET = "fleet.parquet"
POPULATION = "population.json"
