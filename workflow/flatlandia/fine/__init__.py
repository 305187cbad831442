"""fine stage."""
