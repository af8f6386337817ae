"""transient-mi films."""
