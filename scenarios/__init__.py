"""Scenario YAML files shipped with vitaplace (quickstart, paper studies, environments)."""
