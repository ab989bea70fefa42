"""Safety evidence: traces, conditions, use cases and coverage of recorded runs."""
