"""Compensation methods: an optical design plus a compensation, built once from a trained run, by name.

One home for what every command compares and ships: :mod:`.catalogue` names the methods,
:mod:`.compensators` defines their compensations, :mod:`.designs` their optical designs and PSFs,
:mod:`.guard` the display guard of a safe network, and :mod:`.builder` builds a method from a run
(:func:`build_method`). ``evaluate`` scores these objects; ``compensate``, ``live``, ``bench`` and
``export`` run them.
"""

from .builder import MethodBuilder, PreparedMethod, build_method, require_trained_run
from .catalogue import METHOD_NAMES, METHODS, OURS, MethodSpec, method_spec, select_methods

__all__ = [
    "METHODS",
    "METHOD_NAMES",
    "OURS",
    "MethodBuilder",
    "MethodSpec",
    "PreparedMethod",
    "build_method",
    "method_spec",
    "require_trained_run",
    "select_methods",
]
