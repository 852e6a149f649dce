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
#: How long each takes, in the words every help text uses. The full demo, measured on 2 idle cores on
#: 2026-11-28: 8.3 minutes on the development machine's Intel Xeon limited to AVX2 in float32
#: (docs/experiments/2026-11-28-two-phase-demo.md), 14.0 minutes on an AMD EPYC with AVX2 only
#: (docs/experiments/2026-11-28-demo-later-stages.md; 14.8 and 15.5 before the timing stage's budget and the
#: report's one-pass tables, 17.8 before the evaluation ran on every core); 6.4
#: minutes with the Xeon's native bfloat16 when the plan left ``cubic+net`` to its shipped run there. The
#: Xeon's figures predate the evaluation on every core; its plan may now train ``cubic+net`` within the budget.
FULL_DURATION = "8 to 15 minutes on 2 CPU cores in float32 (AVX2; by the CPU's speed), 6 to 8 with native bfloat16"
QUICK_DURATION = "about a minute"
