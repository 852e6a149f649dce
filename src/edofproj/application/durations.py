"""The demo's time budgets and measured durations, stated once.

Every place that tells a user how long the demo takes -- ``edofproj --help``, ``edofproj demo
--help``, the report's budget line and the README -- takes its words and numbers from here, so
they cannot disagree. The measured durations come from ``edofproj demo`` on the 2-core
development machine.
"""

#: Budget of the full demo (minutes): optional baselines predicted not to fit are not trained here.
FULL_BUDGET_MIN = 10
#: Budget of ``edofproj demo --quick`` (minutes).
QUICK_BUDGET_MIN = 2
#: How long each takes, in the words every help text uses. The full demo, measured on 2 idle cores of
#: the development machine on 2026-11-28: 8.3 minutes limited to AVX2 in float32, 6.4 minutes with native
#: bfloat16 (docs/experiments/2026-11-28-two-phase-demo.md).
FULL_DURATION = "about 8 minutes on 2 CPU cores in float32 (AVX2), 6 with native bfloat16"
QUICK_DURATION = "about a minute"
