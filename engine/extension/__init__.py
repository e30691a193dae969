"""The feature-extractor interface, the plugin hooks and the plugin registry (the plugin API
itself: `vitaplace.plugin`)."""
