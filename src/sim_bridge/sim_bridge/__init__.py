"""sim_bridge."""
