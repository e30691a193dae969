"""The scenario pipeline: stages and their cache keys, seals, output-folder layout, manifest,
provenance, completion record, worker processes."""
