"""The output-folder contract: file names and layout, folder digests, completion records, cache keys."""
