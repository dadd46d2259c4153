"""msgs_py."""
