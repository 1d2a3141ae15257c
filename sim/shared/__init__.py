"""What both simulators share: fault specs, who executes what, invariants, the summary."""
