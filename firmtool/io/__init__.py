"""Files: the roadmap file and its stored queries, episode files, figure files, atomic writes, locks, input limits, and the bounded readers of files from someone else."""
