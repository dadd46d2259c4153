"""planner_node."""
