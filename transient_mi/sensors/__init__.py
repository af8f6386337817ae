"""transient-mi sensors."""
