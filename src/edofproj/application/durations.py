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
#: the development machine on 2026-11-27: 10.8 minutes with native bfloat16, 17.7 minutes with the same
#: cores limited to AVX2 in float32 (docs/experiments/2026-11-27-realtime-joint-and-taught.md).
FULL_DURATION = "about 11 minutes on 2 CPU cores with native bfloat16, 18 on AVX2 in float32"
QUICK_DURATION = "about a minute"
