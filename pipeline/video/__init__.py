"""Frame-level rules shared by the synthesize and composite stages (repeated frames of a re-timed video)."""
