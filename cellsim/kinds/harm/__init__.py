"""The harm kind: what the robot does to a person's body (contact per region, its severity, clamping)."""
