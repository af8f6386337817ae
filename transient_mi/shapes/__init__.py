"""transient-mi shapes."""
