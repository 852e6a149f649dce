"""Compensation methods: an optical design plus a compensation, built once from a trained run, by name.

One home for what every command compares and ships: :mod:`.catalogue` names the methods,
:mod:`.compensators` defines their compensations, :mod:`.designs` their optical designs and PSFs,
:mod:`.guard` the display guard of a safe network, and :mod:`.builder` builds a method from a run
(:func:`.builder.build_method`). ``evaluate`` scores these objects; ``compensate``, ``live``, ``bench`` and
``export`` run them.

Nothing is imported here, so that a command's ``--help`` can read :mod:`.catalogue` without torch.
"""
