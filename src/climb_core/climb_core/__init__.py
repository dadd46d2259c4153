"""climb_core."""
