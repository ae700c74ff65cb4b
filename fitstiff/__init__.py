"""fitstiff: passive stiffness of pneumatic cylinders from force-displacement logs.

Library entry points (each also behind a ``fitstiff`` subcommand):

- :func:`fitstiff.loading.load_log` - read a CSV log (+ sidecar) into a :class:`~fitstiff.log.Log`;
- :func:`fitstiff.segmentation.segment` - reversals, loops, pauses and per-sample regions;
- :mod:`fitstiff.terms` / :func:`fitstiff.model.build_model` - JAX model terms and their sum;
- :func:`fitstiff.simulate.simulate` - synthetic logs.
"""

__version__ = "0.1.0"

from fitstiff.errors import FitstiffError, InputError  # noqa: E402
from fitstiff.log import Log, Rig  # noqa: E402

__all__ = ["FitstiffError", "InputError", "Log", "Rig", "__version__"]
