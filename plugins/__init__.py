"""Feature-extractor plugins shipped with vitaplace."""
