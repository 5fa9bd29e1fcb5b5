"""Measurements that guide design choices (not needed at run time)."""
