"""Configuration: the scenario schema, loading YAML files (local or shipped), overrides, generated schema docs."""
