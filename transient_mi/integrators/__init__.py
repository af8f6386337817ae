"""transient-mi integrators."""
