"""Files: the roadmap file, episode files, atomic writes, locks, input limits, fingerprints."""
