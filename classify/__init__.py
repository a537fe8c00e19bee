"""classify: per-point features, random-forest classification of collaborative / non-collaborative regions, masks."""
