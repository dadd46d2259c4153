"""controller_node."""
