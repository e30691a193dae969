"""The bottom floor: errors, atomic writes, the CPUs a process may use, YAML files with key paths, shipped files."""
