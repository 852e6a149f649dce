"""The demo's time budgets and measured durations, stated once.

Every place that tells a user how long the demo takes -- ``edofproj --help``, ``edofproj demo
--help``, the report's budget line and the README -- takes its words and numbers from here, so
they cannot disagree. The measured durations come from ``edofproj demo`` on the 2-core
development machine (``docs/experiments/2026-11-25-training-speed.md``).
"""

#: Budget of the full demo (minutes): optional baselines predicted not to fit are not trained here.
FULL_BUDGET_MIN = 10
#: Budget of ``edofproj demo --quick`` (minutes).
QUICK_BUDGET_MIN = 2
#: How long each takes, in the words every help text uses. The full demo: 7.5 minutes measured on 2 idle
#: cores with native bfloat16 on 2026-11-25, plus about 2 minutes of evaluation that the classic elements'
#: linear baselines added since (measured one at a time); on an AVX2-only CPU it takes longer.
FULL_DURATION = "about 10 minutes on 2 CPU cores with native bfloat16"
QUICK_DURATION = "about a minute"
