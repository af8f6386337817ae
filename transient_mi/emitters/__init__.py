"""transient-mi emitters."""
