"""coarse stage."""
